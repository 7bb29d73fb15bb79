//! The blueprint messages a [`StoreHub`](super::StoreHub) keeps (a viewer's layouts: their
//! store infos, chunks and activation commands), as they came until they take more than a
//! bound, then brought down to what a viewer needs now:
//!
//! - of each application, the [`PER_APPLICATION`] blueprints that were sent to last (an SDK
//!   makes a new blueprint a session, a viewer one a recording: over days they pile up);
//! - of each blueprint, its latest state: its chunks in a store of their own, collected
//!   with `protect_latest = 1` (the latest chunk of every entity, timeline and component,
//!   and all static data stay), so that latest-at at the newest time answers as before.
//!   Undo history older than that goes, as in Rerun's viewer, which collects its own
//!   blueprints the same way;
//! - one of each activation command (the SDK sends the same one every session), and only
//!   those that name a blueprint kept.
//!
//! A blueprint whose chunks do not decode (blueprint chunks are not checked on arrival:
//! they are never data) keeps its messages as they came. The bound doubles past what a
//! compaction leaves, so that a hub whose latest state is large does not compact on every
//! message.

use std::sync::Arc;

use crate::rrd::{LogMsg, LogMsgKind, StoreId};
use crate::{ChunkStore, GcOptions};

/// Bytes of blueprint messages under which nothing is compacted.
pub const COMPACT_FLOOR: u64 = 4 << 20;

/// Blueprints kept of each application once the messages pass the bound.
pub const PER_APPLICATION: usize = 4;

/// See the module docs.
pub(super) struct Blueprints {
    /// In order of arrival, each with the blueprint it belongs to (`None`: an activation
    /// command whose blueprint id does not read).
    messages: Vec<(Option<StoreId>, LogMsg)>,
    bytes: u64,
    /// Compaction starts when `bytes` passes this.
    compact_above: u64,
    floor: u64,
}

impl Default for Blueprints {
    fn default() -> Self {
        Self::with_floor(COMPACT_FLOOR)
    }
}

impl Blueprints {
    pub(super) fn with_floor(floor: u64) -> Self {
        Self {
            messages: Vec::new(),
            bytes: 0,
            compact_above: floor,
            floor,
        }
    }

    /// Keeps `msg` of `blueprint`, compacting everything kept once past the bound.
    pub(super) fn keep(&mut self, blueprint: Option<StoreId>, msg: &LogMsg) {
        self.bytes += msg.body().len() as u64;
        self.messages.push((blueprint, msg.clone()));
        if self.bytes > self.compact_above {
            self.compact();
        }
    }

    /// Bytes of the message bodies kept.
    pub(super) fn bytes(&self) -> u64 {
        self.bytes
    }

    /// The messages kept, in order.
    pub(super) fn messages(&self) -> impl Iterator<Item = &LogMsg> {
        self.messages.iter().map(|(_, msg)| msg)
    }

    /// Whether `bytes` is the sum of the bodies kept.
    pub(super) fn bytes_add_up(&self) -> bool {
        self.bytes == self.summed_bytes()
    }

    fn summed_bytes(&self) -> u64 {
        self.messages
            .iter()
            .map(|(_, msg)| msg.body().len() as u64)
            .sum()
    }

    /// See the module docs.
    fn compact(&mut self) {
        let kept = self.newest_per_application();
        // Each kept blueprint's chunk messages, gathered in one pass.
        let mut chunks_of: ahash::HashMap<&StoreId, Vec<&LogMsg>> = ahash::HashMap::default();
        for (of, msg) in &self.messages {
            if let Some(id) = of.as_ref().filter(|id| kept.contains(*id))
                && msg.kind() == LogMsgKind::ArrowMsg
            {
                chunks_of.entry(id).or_default().push(msg);
            }
        }
        let mut latest: ahash::HashMap<StoreId, Option<Vec<LogMsg>>> = chunks_of
            .into_iter()
            .map(|(id, chunks)| (id.clone(), latest_state(id, chunks.into_iter())))
            .collect();
        // The last of each activation command's bytes.
        let mut last_of_body: ahash::HashMap<&[u8], usize> = ahash::HashMap::default();
        for (index, (_, msg)) in self.messages.iter().enumerate() {
            if msg.kind() == LogMsgKind::BlueprintActivationCommand {
                last_of_body.insert(msg.body().as_slice(), index);
            }
        }
        let last_activations: ahash::HashSet<usize> = last_of_body.into_values().collect();
        let mut infos_seen: ahash::HashSet<StoreId> = ahash::HashSet::default();
        let mut compacted = Vec::new();
        for (index, (of, msg)) in std::mem::take(&mut self.messages).into_iter().enumerate() {
            let is_kept = of.as_ref().is_none_or(|id| kept.contains(id));
            if !is_kept {
                continue;
            }
            match msg.kind() {
                LogMsgKind::SetStoreInfo => {
                    // Rerun's SDK sends a store info twice; the first is the one replayed.
                    if of.as_ref().is_none_or(|id| infos_seen.insert(id.clone())) {
                        compacted.push((of, msg));
                    }
                }
                LogMsgKind::BlueprintActivationCommand => {
                    if last_activations.contains(&index) {
                        compacted.push((of, msg));
                    }
                }
                LogMsgKind::ArrowMsg => match of.as_ref().and_then(|id| latest.get_mut(id)) {
                    // Its latest state goes where its first chunk was, so before any
                    // activation that came after it; its later chunks are in it.
                    Some(Some(chunks)) => {
                        let chunks = std::mem::take(chunks);
                        compacted.extend(chunks.into_iter().map(|m| (of.clone(), m)));
                    }
                    // A blueprint that does not decode keeps its messages.
                    Some(None) => compacted.push((of, msg)),
                    None => {}
                },
            }
        }
        self.messages = compacted;
        self.bytes = self.summed_bytes();
        self.compact_above = self.bytes.saturating_mul(2).max(self.floor);
    }

    /// The blueprints that stay: of each application, the [`PER_APPLICATION`] whose last
    /// message came last.
    fn newest_per_application(&self) -> ahash::HashSet<StoreId> {
        let mut last_message: ahash::HashMap<&StoreId, usize> = ahash::HashMap::default();
        for (index, (of, _)) in self.messages.iter().enumerate() {
            if let Some(id) = of {
                last_message.insert(id, index);
            }
        }
        let mut by_application: ahash::HashMap<&Arc<str>, Vec<(usize, &StoreId)>> =
            ahash::HashMap::default();
        for (id, last) in last_message {
            by_application
                .entry(&id.application_id)
                .or_default()
                .push((last, id));
        }
        by_application
            .into_values()
            .flat_map(|mut blueprints| {
                blueprints.sort_unstable_by_key(|&(last, _)| std::cmp::Reverse(last));
                blueprints.truncate(PER_APPLICATION);
                blueprints.into_iter().map(|(_, id)| id.clone())
            })
            .collect()
    }
}

/// The latest state of blueprint `id` whose chunk messages are `messages`, as messages
/// (static chunks first, then by chunk id); `None` if one of them does not decode or its
/// chunks do not make a store.
fn latest_state<'a>(
    id: &StoreId,
    messages: impl Iterator<Item = &'a LogMsg>,
) -> Option<Vec<LogMsg>> {
    let mut store = ChunkStore::new();
    for msg in messages {
        let (_, chunk) = msg.decode_any_chunk().ok()?;
        store.insert(Arc::new(chunk)).ok()?;
    }
    store.gc(&GcOptions::everything().with_protect_latest(1));
    let mut chunks: Vec<_> = store.chunks_unordered().collect();
    chunks.sort_by_key(|chunk| (!chunk.is_static(), chunk.id()));
    chunks
        .into_iter()
        .map(|chunk| LogMsg::from_chunk(id, chunk, true).ok())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rrd::{StoreInfo, StoreKind};
    use crate::{ChunkBuilder, ChunkId, EntityPath, LatestAtQuery, RowId, TimeInt, Timeline};
    use arrow_array::{ArrayRef, Int64Array};
    use arrow_buffer::Buffer;

    fn blueprint(app: &str, id: &str) -> StoreId {
        let mut blueprint = StoreId::recording(app, id);
        blueprint.kind = StoreKind::Blueprint;
        blueprint
    }

    /// A layout edit: `entity`'s `width` set to `value` at blueprint time `time`.
    fn edit(id: &StoreId, entity: &str, time: i64, value: i64) -> LogMsg {
        let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse(entity).unwrap())
            .with_row(
                RowId::new(),
                [(Timeline::sequence("blueprint"), time)],
                [("width", Arc::new(Int64Array::from(vec![value])) as ArrayRef)],
            )
            .build()
            .unwrap();
        LogMsg::from_chunk(id, &chunk, true).unwrap()
    }

    fn activation(id: &StoreId, make_default: bool) -> LogMsg {
        let mut body = crate::rrd::protobuf::FieldWriter::default();
        body.message(1, |out| id.encode(out))
            .varint(2, 1)
            .varint(3, u64::from(make_default));
        LogMsg::new(
            LogMsgKind::BlueprintActivationCommand,
            Buffer::from(body.bytes),
        )
    }

    fn keep(blueprints: &mut Blueprints, msg: &LogMsg) {
        let of = match msg.kind() {
            LogMsgKind::BlueprintActivationCommand => msg.activated_blueprint(),
            _ => msg.store_id().unwrap(),
        };
        blueprints.keep(of, msg);
    }

    /// What a viewer sees of `entity` at the newest blueprint time, from `messages`.
    fn width_now<'a>(messages: impl Iterator<Item = &'a LogMsg>, entity: &str) -> Option<i64> {
        let mut store = ChunkStore::new();
        for msg in messages.filter(|m| m.kind() == LogMsgKind::ArrowMsg) {
            store
                .insert(Arc::new(msg.decode_any_chunk().unwrap().1))
                .unwrap();
        }
        let query = LatestAtQuery::new("blueprint", TimeInt::MAX);
        let cell = store.snapshot().view().latest_at(
            &query,
            &EntityPath::parse(entity).unwrap(),
            "width",
        )?;
        let values = cell.cell();
        Some(values.as_any().downcast_ref::<Int64Array>()?.value(0))
    }

    /// Days of edits to one layout stay within twice what its latest state takes (and the
    /// floor), and the latest state is what all the edits make.
    #[test]
    fn a_layout_edited_for_days_keeps_its_latest_state_in_bounded_bytes() {
        let id = blueprint("app", "layout");
        let mut blueprints = Blueprints::with_floor(64 << 10);
        let mut all = vec![LogMsg::from_store_info(&StoreInfo::new(id.clone()))];
        keep(&mut blueprints, &all[0]);
        let mut peak = 0;
        for (time, entity) in (0..3_000).zip(["/view/a", "/view/b", "/view/c"].iter().cycle()) {
            let msg = edit(&id, entity, time, time * 10);
            keep(&mut blueprints, &msg);
            all.push(msg);
            peak = peak.max(blueprints.bytes());
            assert!(blueprints.bytes_add_up());
        }
        let all_bytes: u64 = all.iter().map(|m| m.body().len() as u64).sum();
        assert!(
            all_bytes > 10 * (64 << 10),
            "the edits pass the floor many times"
        );
        assert!(peak <= (64 << 10) + 4096, "peak {peak} bytes");
        for entity in ["/view/a", "/view/b", "/view/c"] {
            assert_eq!(
                width_now(blueprints.messages(), entity),
                width_now(all.iter(), entity),
                "{entity}"
            );
        }
        // The store info stays, first.
        assert_eq!(
            blueprints.messages().next().map(LogMsg::kind),
            Some(LogMsgKind::SetStoreInfo)
        );
    }

    /// An application's old sessions go with their activation commands; another
    /// application's blueprint stays; an activation repeated every session is kept once,
    /// after its blueprint's chunks.
    #[test]
    fn old_sessions_go_and_activations_are_kept_once() {
        let mut blueprints = Blueprints::with_floor(u64::MAX);
        let other = blueprint("other_app", "its_layout");
        for msg in [
            LogMsg::from_store_info(&StoreInfo::new(other.clone())),
            edit(&other, "/v", 0, 1),
            activation(&other, true),
        ] {
            keep(&mut blueprints, &msg);
        }
        let sessions: Vec<StoreId> = (0..7_i64)
            .map(|i| blueprint("app", &format!("s{i}")))
            .collect();
        for (i, id) in (0_i64..).zip(&sessions) {
            let info = LogMsg::from_store_info(&StoreInfo::new(id.clone()));
            for msg in [
                info.clone(),
                info,
                edit(id, "/v", 0, i),
                activation(id, true),
            ] {
                keep(&mut blueprints, &msg);
            }
        }
        // The last session's blueprint activated again, with the same bytes.
        let last = sessions.last().unwrap();
        keep(&mut blueprints, &activation(last, true));
        blueprints.compact();
        assert!(blueprints.bytes_add_up());

        let kept: Vec<(LogMsgKind, Option<StoreId>)> = blueprints
            .messages
            .iter()
            .map(|(of, msg)| (msg.kind(), of.clone()))
            .collect();
        let mut expected = vec![
            (LogMsgKind::SetStoreInfo, Some(other.clone())),
            (LogMsgKind::ArrowMsg, Some(other.clone())),
            (LogMsgKind::BlueprintActivationCommand, Some(other)),
        ];
        for id in &sessions[3..] {
            expected.push((LogMsgKind::SetStoreInfo, Some(id.clone())));
            expected.push((LogMsgKind::ArrowMsg, Some(id.clone())));
            if id != last {
                expected.push((LogMsgKind::BlueprintActivationCommand, Some(id.clone())));
            }
        }
        expected.push((LogMsgKind::BlueprintActivationCommand, Some(last.clone())));
        assert_eq!(kept, expected);
        assert_eq!(width_now(blueprints.messages(), "/v"), Some(6));
    }

    /// A blueprint chunk that does not decode (blueprints are not checked on arrival) is
    /// kept as it came; the other blueprint is still compacted.
    #[test]
    fn a_blueprint_that_does_not_decode_keeps_its_messages() {
        let mut blueprints = Blueprints::with_floor(u64::MAX);
        let good = blueprint("app", "good");
        let bad = blueprint("app", "bad");
        let mut body = crate::rrd::protobuf::FieldWriter::default();
        // An Arrow IPC payload (encoding 1) that is not Arrow IPC.
        body.message(1, |out| bad.encode(out))
            .varint(4, 1)
            .bytes(5, b"not arrow");
        let broken = LogMsg::new(LogMsgKind::ArrowMsg, Buffer::from(body.bytes));
        assert_eq!(broken.store_id().unwrap(), Some(bad.clone()));
        for msg in [
            edit(&good, "/v", 0, 1),
            broken.clone(),
            edit(&good, "/v", 1, 2),
            broken,
            edit(&good, "/v", 2, 3),
        ] {
            keep(&mut blueprints, &msg);
        }
        blueprints.compact();
        let of: Vec<&StoreId> = blueprints
            .messages
            .iter()
            .filter_map(|(of, _)| of.as_ref())
            .collect();
        assert_eq!(of, [&good, &bad, &bad]);
        assert_eq!(width_now(blueprints.messages().take(1), "/v"), Some(3));
    }
}
