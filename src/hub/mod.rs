//! [`StoreHub`]: several stores side by side, keyed by store id, fed one Rerun log message
//! ([`LogMsg`]) at a time, and replayed as log messages: what a server that SDKs log into
//! needs, with no I/O of its own (the server in `src/bin/chunkstore/commands/serve/`
//! brings the network and the disk).
//!
//! - Each recording (a `StoreKind::Recording` store id) gets its own [`SharedStore`], so
//!   readers query snapshots while writers go on.
//! - Blueprint messages (a viewer's layout) are kept apart, as they came, and never enter a
//!   recording's store: they are replayed, never queried. Past a bound they are brought
//!   down to each blueprint's latest state (see [`BLUEPRINT_COMPACT_FLOOR`]), so that a
//!   hub that runs for days does not keep every layout edit of every session.
//! - Every accepted message gets the next sequence number, and the hub's listener sees it
//!   under the hub's lock, so whoever listens (a log file, live readers) sees messages in
//!   one order; [`StoreHub::replay`] says up to which number its history goes, so that a
//!   reader can join history and live messages without a gap or a repeat.

mod blueprints;

use std::sync::Arc;

use arc_swap::ArcSwap;
use parking_lot::Mutex;

pub use blueprints::{
    COMPACT_FLOOR as BLUEPRINT_COMPACT_FLOOR, PER_APPLICATION as BLUEPRINTS_PER_APPLICATION,
};

use crate::rrd::{DecodedLogMsg, LogMsg, RrdError, StoreId, StoreInfo, StoreKind};
use crate::sanity::{Structure, ensure};
use crate::{
    Chunk, ChunkStore, ConfigError, GcOptions, InsertError, SanityError, SharedStore, Snapshot,
    StoreConfig, Timeline,
};

/// What the hub's listener is told of each accepted message: its sequence number and the
/// message. An error refuses to acknowledge the message (the caller's
/// [`StoreHub::ingest`] returns it), though the store already holds it.
pub type HubListener = Box<dyn Fn(u64, &LogMsg) -> Result<(), String> + Send + Sync>;

/// Several recordings and their blueprints, fed log messages. See the module docs.
///
/// ```
/// # use std::sync::Arc;
/// # use arrow_array::{ArrayRef, Float64Array};
/// use chunkstore::*;
/// use chunkstore::hub::StoreHub;
/// use chunkstore::rrd::{LogMsg, StoreId, StoreInfo};
/// let hub = StoreHub::new(StoreConfig::DEFAULT)?;
/// let id = StoreId::recording("app", "run-1");
/// hub.ingest(&LogMsg::from_store_info(&StoreInfo::new(id.clone())))?;
/// let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/arm")?)
///     .with_row(RowId::new(), [(Timeline::sequence("frame"), 1)],
///               [("torque", Arc::new(Float64Array::from(vec![0.5])) as ArrayRef)])
///     .build()?;
/// hub.ingest(&LogMsg::from_chunk(&id, &chunk, true)?)?;
///
/// let recordings = hub.recordings();
/// assert_eq!(recordings.len(), 1);
/// assert_eq!(recordings[0].snapshot.stats().num_rows(), 1);
/// // The history as messages: the store info, then the chunk.
/// let replay: Vec<LogMsg> = hub.replay().into_messages().collect::<Result<_, _>>()?;
/// assert_eq!(replay.len(), 2);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct StoreHub {
    config: StoreConfig,
    state: Mutex<HubState>,
    /// The recordings as [`HubState::recordings`] has them, republished under the lock
    /// whenever one opens or goes: readers ([`StoreHub::recordings`], a query's tables)
    /// take it without the lock, which a writer holds while its chunk goes in (a merge of
    /// large chunks, milliseconds).
    listed: ArcSwap<Vec<Arc<Listed>>>,
    listener: Option<HubListener>,
}

/// A recording as readers find it: [`HubEntry`] without the message that announced it.
/// Shared by the entry and every listing it is in, so that republishing the list on each
/// new recording copies a pointer per recording, not its store info.
struct Listed {
    info: StoreInfo,
    store: SharedStore,
}

#[derive(Default)]
struct HubState {
    /// In order of arrival.
    recordings: Vec<HubEntry>,
    by_id: ahash::HashMap<StoreId, usize>,
    /// The blueprint messages, bounded.
    blueprints: blueprints::Blueprints,
    /// The last sequence number given out.
    seq: u64,
}

struct HubEntry {
    /// Its store info and store, as readers find them ([`StoreHub::recordings`]).
    recording: Arc<Listed>,
    /// The `SetStoreInfo` that announced it (replayed as it came), or one made up when a
    /// chunk came first.
    info_msg: LogMsg,
}

/// One recording the hub holds, as of a moment.
#[derive(Clone)]
#[non_exhaustive]
pub struct HubRecording {
    /// Its store info.
    pub info: StoreInfo,
    /// Its contents, as of the call.
    pub snapshot: Snapshot,
}

/// Why a message was not accepted. The hub is unchanged, except for
/// [`IngestError::Listener`].
#[derive(Debug)]
#[non_exhaustive]
pub enum IngestError {
    /// The message does not decode (malformed protobuf, a corrupt payload, a batch that
    /// is not a valid chunk).
    Decode(RrdError),
    /// The store refused the chunk (a timeline or component type conflict).
    Insert(Box<InsertError>),
    /// The message was stored, but the listener failed (a log file could not be written):
    /// it must not be acknowledged.
    Listener(String),
}

impl std::fmt::Display for IngestError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Decode(e) => write!(f, "message does not decode: {e}"),
            Self::Insert(e) => write!(f, "chunk refused: {e}"),
            Self::Listener(e) => write!(f, "message stored but not persisted: {e}"),
        }
    }
}

impl std::error::Error for IngestError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Decode(e) => Some(e),
            Self::Insert(e) => Some(e.as_ref()),
            Self::Listener(_) => None,
        }
    }
}

/// What one garbage collection across the hub did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct HubGcOutcome {
    /// Heap bytes of the stores before.
    pub bytes_before: u64,
    /// Heap bytes of the stores after.
    pub bytes_after: u64,
    /// Chunks dropped.
    pub chunks_dropped: usize,
}

impl StoreHub {
    /// An empty hub whose stores use `config`.
    ///
    /// # Errors
    /// If `config` is not one a store takes.
    pub fn new(config: StoreConfig) -> Result<Self, ConfigError> {
        ChunkStore::with_config(config)?;
        Ok(Self {
            config,
            state: Mutex::new(HubState::default()),
            listed: ArcSwap::default(),
            listener: None,
        })
    }

    /// An empty hub that calls `listener` with every accepted message, in order, under
    /// the hub's lock (keep it quick: a buffered write, a channel send).
    ///
    /// # Errors
    /// If `config` is not one a store takes.
    pub fn with_listener(config: StoreConfig, listener: HubListener) -> Result<Self, ConfigError> {
        Ok(Self {
            listener: Some(listener),
            ..Self::new(config)?
        })
    }

    /// Decodes `msg` (outside the hub's lock: several callers decode at once), then
    /// applies it: a store info opens a recording (a second one for the same store is
    /// accepted and changes nothing: Rerun's SDK sends it twice), a chunk goes into its
    /// recording's store (opened with a default store info if the chunk came first),
    /// blueprint messages are kept apart. Returns the message's sequence number.
    ///
    /// # Errors
    /// See [`IngestError`]; the hub is then unchanged, but for a listener's failure.
    pub fn ingest(&self, msg: &LogMsg) -> Result<u64, IngestError> {
        let decoded = msg.decode().map_err(IngestError::Decode)?;
        self.apply(msg, decoded)
    }

    /// Applies `msg` without telling the listener: for history the listener has already
    /// (a log read back at start) or must not get (files loaded before serving).
    ///
    /// # Errors
    /// As [`StoreHub::ingest`].
    pub fn restore(&self, msg: &LogMsg) -> Result<u64, IngestError> {
        let decoded = msg.decode().map_err(IngestError::Decode)?;
        self.apply_inner(msg, decoded, false)
    }

    /// Adds a whole loaded recording (say, from a chunk directory), without telling the
    /// listener. A recording of the same id gets `store`'s chunks inserted.
    ///
    /// # Errors
    /// As [`ChunkStore::insert`], for a recording of the same id; the hub's earlier
    /// chunks stay.
    pub fn adopt(&self, info: StoreInfo, store: ChunkStore) -> Result<(), IngestError> {
        let mut state = self.state.lock();
        if let Some(&index) = state.by_id.get(&info.store_id) {
            let chunks: Vec<Arc<Chunk>> = store.chunks_unordered().cloned().collect();
            state.recordings[index]
                .recording
                .store
                .insert_batch(chunks)
                .map_err(|e| IngestError::Insert(Box::new(e)))?;
            return Ok(());
        }
        let info_msg = LogMsg::from_store_info(&info);
        state.open(info, info_msg, store);
        self.publish_listing(&state);
        Ok(())
    }

    /// Applies a message decoded by the caller ([`LogMsg::decode`] of `msg`), for a caller
    /// that decodes on threads of its own. As [`StoreHub::ingest`] otherwise.
    ///
    /// # Errors
    /// See [`IngestError`].
    pub fn apply(&self, msg: &LogMsg, decoded: DecodedLogMsg) -> Result<u64, IngestError> {
        self.apply_inner(msg, decoded, true)
    }

    fn apply_inner(
        &self,
        msg: &LogMsg,
        decoded: DecodedLogMsg,
        announce: bool,
    ) -> Result<u64, IngestError> {
        let mut state = self.state.lock();
        match decoded {
            DecodedLogMsg::StoreInfo(info) => {
                if info.store_id.kind == StoreKind::Recording {
                    if !state.by_id.contains_key(&info.store_id) {
                        state.open(info, msg.clone(), self.empty_store());
                        self.publish_listing(&state);
                    }
                } else {
                    state.blueprints.keep(Some(info.store_id), msg);
                }
            }
            DecodedLogMsg::Chunk { store_id, chunk } => {
                if let Some(&index) = state.by_id.get(&store_id) {
                    state.recordings[index]
                        .recording
                        .store
                        .insert(Arc::new(chunk))
                        .map_err(|e| IngestError::Insert(Box::new(e)))?;
                } else {
                    // The first chunk of a recording without a store info: the recording
                    // opens only once the chunk is in, so a refused chunk leaves no trace.
                    let mut store = self.empty_store();
                    store
                        .insert(Arc::new(chunk))
                        .map_err(|e| IngestError::Insert(Box::new(e)))?;
                    let info = StoreInfo::new(store_id);
                    let info_msg = LogMsg::from_store_info(&info);
                    state.open(info, info_msg, store);
                    self.publish_listing(&state);
                }
            }
            DecodedLogMsg::BlueprintChunk { store_id } => {
                state.blueprints.keep(Some(store_id), msg);
            }
            DecodedLogMsg::BlueprintActivation => {
                state.blueprints.keep(msg.activated_blueprint(), msg);
            }
        }
        state.seq += 1;
        let seq = state.seq;
        if let Some(listener) = self.listener.as_ref().filter(|_| announce) {
            listener(seq, msg).map_err(IngestError::Listener)?;
        }
        Ok(seq)
    }

    /// Drops every recording and blueprint; sequence numbers go on from where they were
    /// (a listener never sees one twice). For a server whose log could not keep what it
    /// was told, to rebuild what it holds from what the log kept.
    pub fn clear(&self) {
        let mut state = self.state.lock();
        let seq = state.seq;
        *state = HubState {
            seq,
            ..HubState::default()
        };
        self.publish_listing(&state);
    }

    /// Republishes [`StoreHub::listed`] from `state` (under its lock, so that two
    /// publications cannot cross).
    fn publish_listing(&self, state: &HubState) {
        let listed = state
            .recordings
            .iter()
            .map(|entry| Arc::clone(&entry.recording))
            .collect();
        self.listed.store(Arc::new(listed));
    }

    /// A store for a new recording (`StoreHub::new` checked the configuration).
    fn empty_store(&self) -> ChunkStore {
        ChunkStore::with_config(self.config).unwrap_or_else(|_| ChunkStore::new())
    }

    /// Every recording, in order of arrival, each as a snapshot of now. Never waits for a
    /// writer.
    pub fn recordings(&self) -> Vec<HubRecording> {
        self.listed
            .load()
            .iter()
            .map(|entry| HubRecording {
                info: entry.info.clone(),
                snapshot: entry.store.snapshot(),
            })
            .collect()
    }

    /// Every recording's store, in order of arrival.
    fn stores(&self) -> Vec<SharedStore> {
        self.listed.load().iter().map(|e| e.store.clone()).collect()
    }

    /// Drops every recording whose recording id is `recording_id` (of any application),
    /// its store info included; returns their store ids (none if it held no such
    /// recording). The listener is not told: nothing is logged. A later chunk of the same
    /// recording opens it anew.
    pub fn drop_recording(&self, recording_id: &str) -> Vec<StoreId> {
        let mut state = self.state.lock();
        let (dropped, kept): (Vec<HubEntry>, Vec<HubEntry>) = std::mem::take(&mut state.recordings)
            .into_iter()
            .partition(|entry| &*entry.recording.info.store_id.recording_id == recording_id);
        state.recordings = kept;
        let by_id = state
            .recordings
            .iter()
            .enumerate()
            .map(|(index, entry)| (entry.recording.info.store_id.clone(), index))
            .collect();
        state.by_id = by_id;
        self.publish_listing(&state);
        dropped
            .into_iter()
            .map(|entry| entry.recording.info.store_id.clone())
            .collect()
    }

    /// How many recordings the hub holds (blueprints aside).
    pub fn recording_count(&self) -> usize {
        self.listed.load().len()
    }

    /// The sequence number of the last accepted message (0 before the first).
    pub fn last_seq(&self) -> u64 {
        self.state.lock().seq
    }

    /// Everything held, as of now: see [`HubReplay`].
    pub fn replay(&self) -> HubReplay {
        let state = self.state.lock();
        let mut infos = Vec::new();
        let mut static_chunks = Vec::new();
        let mut temporal_chunks = Vec::new();
        for entry in &state.recordings {
            infos.push(entry.info_msg.clone());
            let snapshot = entry.recording.store.snapshot();
            for chunk in snapshot.view().chunks() {
                let chunks = if chunk.is_static() {
                    &mut static_chunks
                } else {
                    &mut temporal_chunks
                };
                chunks.push((entry.recording.info.store_id.clone(), chunk));
            }
        }
        HubReplay {
            seq: state.seq,
            infos,
            blueprints: state.blueprints.messages().cloned().collect(),
            chunks: static_chunks.into_iter().chain(temporal_chunks).collect(),
        }
    }

    /// Heap bytes held: every recording's store, and the blueprint messages.
    pub fn heap_bytes(&self) -> u64 {
        let state = self.state.lock();
        state.blueprints.bytes()
            + state
                .recordings
                .iter()
                .map(|entry| entry.recording.store.snapshot().stats().heap_bytes)
                .sum::<u64>()
    }

    /// Brings the recordings' heap under `limit` bytes if it is over: every recording
    /// gives up the same fraction of its heap, oldest rows first (in a live stream, the
    /// data furthest from the newest), keeping the latest chunk of every (entity,
    /// timeline, component) and all static data, so that latest-at at the newest time
    /// answers as before. It aims a tenth under the limit, so that a stream just over it
    /// does not collect on every message. Blueprints are bounded on their own (module
    /// docs), not here.
    pub fn collect_garbage(&self, limit: u64) -> HubGcOutcome {
        let stores = self.stores();
        let bytes_of = |stores: &[SharedStore]| {
            stores
                .iter()
                .map(|s| s.snapshot().stats().heap_bytes)
                .sum::<u64>()
        };
        let before = bytes_of(&stores);
        let mut outcome = HubGcOutcome {
            bytes_before: before,
            bytes_after: before,
            chunks_dropped: 0,
        };
        if before <= limit || before == 0 {
            return outcome;
        }
        let target = limit - limit / 10;
        #[expect(clippy::cast_precision_loss, reason = "a fraction of heap bytes")]
        let fraction = ((before - target) as f64 / before as f64).clamp(f64::MIN_POSITIVE, 1.0);
        let Ok(options) = GcOptions::drop_at_least_fraction(fraction) else {
            return outcome;
        };
        for store in &stores {
            let events = store.write(|s: &mut ChunkStore| s.gc(&options));
            outcome.chunks_dropped += events.len();
        }
        outcome.bytes_after = bytes_of(&stores);
        outcome
    }

    /// Retention across the hub: every recording's timeline for which `span_of` gives a
    /// span keeps only its last span of data ([`ChunkStore::retain_recent_on`], measured
    /// from that recording's own newest times, all taken before anything is removed). Blueprints are not touched. Returns the
    /// chunks removed (a chunk partly kept counts, and is replaced by its kept rows).
    pub fn retain_recent(&self, span_of: impl Fn(&Timeline) -> Option<u64>) -> usize {
        let stores = self.stores();
        let mut removed = 0;
        for store in &stores {
            let rules: Vec<(Timeline, u64)> = store
                .snapshot()
                .view()
                .timelines()
                .into_iter()
                .filter_map(|timeline| span_of(&timeline).map(|span| (timeline, span)))
                .collect();
            if rules.is_empty() {
                continue;
            }
            let rules: Vec<(&str, u64)> = rules.iter().map(|(t, span)| (t.name(), *span)).collect();
            let events = store.write(|s: &mut ChunkStore| s.retain_recent_on(&rules));
            removed += events
                .iter()
                .filter(|e| matches!(e, crate::StoreEvent::Deletion { .. }))
                .count();
        }
        removed
    }

    /// Checks the hub's own invariants (its index of recordings, its blueprint figure)
    /// and every recording's store.
    ///
    /// # Errors
    /// The first broken invariant: a bug in this crate.
    pub fn sanity_check(&self) -> Result<(), SanityError> {
        let state = self.state.lock();
        ensure(
            state.by_id.len() == state.recordings.len(),
            Structure::Store,
            "the hub indexes each recording once",
        )?;
        let listed = self.listed.load();
        ensure(
            listed.len() == state.recordings.len()
                && listed
                    .iter()
                    .zip(&state.recordings)
                    .all(|(listed, entry)| Arc::ptr_eq(listed, &entry.recording)),
            Structure::Store,
            "readers find the hub's recordings as it holds them",
        )?;
        for (index, entry) in state.recordings.iter().enumerate() {
            ensure(
                state.by_id.get(&entry.recording.info.store_id) == Some(&index),
                Structure::Store,
                "the hub's index points at the recording of that id",
            )?;
            ensure(
                entry.recording.info.store_id.kind == StoreKind::Recording,
                Structure::Store,
                "the hub's stores are recordings",
            )?;
            entry
                .recording
                .store
                .write(|s: &mut ChunkStore| s.sanity_check())?;
        }
        ensure(
            state.blueprints.bytes_add_up(),
            Structure::Stats,
            "the hub's blueprint bytes are the sum of its blueprint messages",
        )
    }
}

impl HubState {
    /// Adds a recording holding `store`; returns its index.
    fn open(&mut self, info: StoreInfo, info_msg: LogMsg, store: ChunkStore) -> usize {
        let index = self.recordings.len();
        self.by_id.insert(info.store_id.clone(), index);
        self.recordings.push(HubEntry {
            recording: Arc::new(Listed {
                info,
                store: SharedStore::new(store),
            }),
            info_msg,
        });
        index
    }
}

/// Everything a hub held at one moment, to send as log messages: each recording's store
/// info, then the blueprint messages as they came, then every static chunk, then every
/// temporal chunk (a reader that shows data as it arrives has static data before it is
/// needed). Chunks are those of the stores as they are, compacted and collected, not the
/// messages that brought them.
pub struct HubReplay {
    /// The sequence number of the last message the history includes: a live message with
    /// a greater number comes after it.
    pub seq: u64,
    infos: Vec<LogMsg>,
    blueprints: Vec<LogMsg>,
    chunks: Vec<(StoreId, Arc<Chunk>)>,
}

impl HubReplay {
    /// The number of messages [`HubReplay::into_messages`] yields.
    pub fn len(&self) -> usize {
        self.infos.len() + self.blueprints.len() + self.chunks.len()
    }

    /// Whether there is nothing to replay.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The messages, chunks encoded (LZ4-compressed, as the SDK sends them) one at a time
    /// as the iterator is advanced.
    pub fn into_messages(self) -> impl Iterator<Item = Result<LogMsg, RrdError>> + Send {
        self.infos.into_iter().chain(self.blueprints).map(Ok).chain(
            self.chunks
                .into_iter()
                .map(|(store_id, chunk)| LogMsg::from_chunk(&store_id, &chunk, true)),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rrd::LogMsgKind;
    use crate::{ChunkBuilder, ChunkId, EntityPath, RowId, Timeline};
    use arrow_array::{ArrayRef, Float64Array};

    fn chunk(entity: &str, frame: i64, value: f64) -> Chunk {
        ChunkBuilder::new(ChunkId::new(), EntityPath::parse(entity).unwrap())
            .with_row(
                RowId::new(),
                [(Timeline::sequence("frame"), frame)],
                [("x", Arc::new(Float64Array::from(vec![value])) as ArrayRef)],
            )
            .build()
            .unwrap()
    }

    #[test]
    fn readers_list_recordings_while_a_writer_holds_the_hub() {
        // The listener runs under the hub's lock: it holds it until the reader is done.
        let (entered, wait_entered) = std::sync::mpsc::channel();
        let (release, wait_release) = std::sync::mpsc::channel::<()>();
        let wait_release = Mutex::new(wait_release);
        let hub = Arc::new(
            StoreHub::with_listener(
                StoreConfig::DEFAULT,
                Box::new(move |seq, _: &LogMsg| {
                    if seq == 3 {
                        entered.send(()).unwrap();
                        wait_release.lock().recv().unwrap();
                    }
                    Ok(())
                }),
            )
            .unwrap(),
        );
        let a = StoreId::recording("app", "a");
        hub.ingest(&LogMsg::from_store_info(&StoreInfo::new(a.clone())))
            .unwrap();
        hub.ingest(&LogMsg::from_chunk(&a, &chunk("/x", 1, 1.0), true).unwrap())
            .unwrap();
        let writer = {
            let hub = Arc::clone(&hub);
            let a = a.clone();
            std::thread::spawn(move || {
                hub.ingest(&LogMsg::from_chunk(&a, &chunk("/x", 2, 2.0), true).unwrap())
            })
        };
        wait_entered.recv().unwrap();
        // The writer is inside the hub, its chunk stored (and published) but not yet
        // acknowledged.
        let (listed, wait_listed) = std::sync::mpsc::channel();
        let reader = Arc::clone(&hub);
        std::thread::spawn(move || {
            let recordings = reader.recordings();
            let _ = listed.send((recordings, reader.recording_count()));
        });
        let answer = wait_listed.recv_timeout(std::time::Duration::from_secs(20));
        release.send(()).unwrap();
        let (listed, count) = answer.expect("the reader waited for the writer");
        assert_eq!((listed.len(), count), (1, 1));
        assert!(listed[0].snapshot.stats().num_rows() >= 1);
        assert_eq!(writer.join().unwrap().unwrap(), 3);
        assert_eq!(hub.recordings()[0].snapshot.stats().num_rows(), 2);
        hub.sanity_check().unwrap();
    }

    #[test]
    fn recordings_stay_apart_and_blueprints_never_become_data() {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let listener_seen = Arc::clone(&seen);
        let hub = StoreHub::with_listener(
            StoreConfig::DEFAULT,
            Box::new(move |seq, msg: &LogMsg| {
                listener_seen.lock().push((seq, msg.kind()));
                Ok(())
            }),
        )
        .unwrap();
        let a = StoreId::recording("app", "a");
        let b = StoreId::recording("app", "b");
        let mut bp = StoreId::recording("app", "layout");
        bp.kind = StoreKind::Blueprint;
        for id in [&a, &a, &b, &bp] {
            hub.ingest(&LogMsg::from_store_info(&StoreInfo::new(id.clone())))
                .unwrap();
        }
        hub.ingest(&LogMsg::from_chunk(&a, &chunk("/x", 1, 1.0), true).unwrap())
            .unwrap();
        hub.ingest(&LogMsg::from_chunk(&b, &chunk("/y", 1, 2.0), false).unwrap())
            .unwrap();
        hub.ingest(&LogMsg::from_chunk(&bp, &chunk("/view", 1, 3.0), true).unwrap())
            .unwrap();
        // A chunk before its store info opens the recording.
        let c = StoreId::recording("app", "c");
        hub.ingest(&LogMsg::from_chunk(&c, &chunk("/z", 5, 4.0), true).unwrap())
            .unwrap();

        let recordings = hub.recordings();
        let ids: Vec<_> = recordings
            .iter()
            .map(|r| &*r.info.store_id.recording_id)
            .collect();
        assert_eq!(ids, ["a", "b", "c"]);
        assert!(
            recordings
                .iter()
                .all(|r| r.snapshot.stats().num_rows() == 1)
        );
        assert_eq!(hub.last_seq(), 8);
        let seqs: Vec<u64> = seen.lock().iter().map(|(s, _)| *s).collect();
        assert_eq!(seqs, (1..=8).collect::<Vec<_>>());
        hub.sanity_check().unwrap();

        // Replay: 3 store infos, 2 blueprint messages, 3 chunks; the blueprint chunk as
        // it came.
        let replay = hub.replay();
        assert_eq!(replay.seq, 8);
        assert_eq!(replay.len(), 8);
        let kinds: Vec<LogMsgKind> = replay.into_messages().map(|m| m.unwrap().kind()).collect();
        assert_eq!(
            kinds,
            [
                LogMsgKind::SetStoreInfo,
                LogMsgKind::SetStoreInfo,
                LogMsgKind::SetStoreInfo,
                LogMsgKind::SetStoreInfo,
                LogMsgKind::ArrowMsg,
                LogMsgKind::ArrowMsg,
                LogMsgKind::ArrowMsg,
                LogMsgKind::ArrowMsg,
            ]
        );
    }

    #[test]
    fn a_refused_message_changes_nothing_and_a_replay_rebuilds_the_hub() {
        let hub = StoreHub::new(StoreConfig::DEFAULT).unwrap();
        let a = StoreId::recording("app", "a");
        hub.ingest(&LogMsg::from_chunk(&a, &chunk("/x", 1, 1.0), true).unwrap())
            .unwrap();
        // The same component as another type: refused by the store.
        let strings = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/x").unwrap())
            .with_row(
                RowId::new(),
                [(Timeline::sequence("frame"), 2)],
                [(
                    "x",
                    Arc::new(arrow_array::StringArray::from(vec!["no"])) as ArrayRef,
                )],
            )
            .build()
            .unwrap();
        let err = hub
            .ingest(&LogMsg::from_chunk(&a, &strings, true).unwrap())
            .unwrap_err();
        assert!(matches!(err, IngestError::Insert(_)), "{err}");
        // Garbage.
        let err = hub
            .ingest(&LogMsg::new(
                LogMsgKind::ArrowMsg,
                arrow_buffer::Buffer::from(vec![0xff, 0xff]),
            ))
            .unwrap_err();
        assert!(matches!(err, IngestError::Decode(_)), "{err}");
        // The first chunk of an unknown recording, refused: no recording opens (a fuzz
        // crash: it used to open, empty, before the insert failed).
        let not_a_clear = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/x").unwrap())
            .with_row(
                RowId::new(),
                [(Timeline::sequence("frame"), 2)],
                [(
                    crate::ComponentName::CLEAR_IS_RECURSIVE,
                    Arc::new(Float64Array::from(vec![1.0])) as ArrayRef,
                )],
            )
            .build()
            .unwrap();
        let b = StoreId::recording("app", "b");
        let err = hub
            .ingest(&LogMsg::from_chunk(&b, &not_a_clear, true).unwrap())
            .unwrap_err();
        assert!(matches!(err, IngestError::Insert(_)), "{err}");
        assert_eq!(hub.last_seq(), 1);
        assert_eq!(hub.recordings().len(), 1);
        assert_eq!(hub.recordings()[0].snapshot.stats().num_rows(), 1);

        // Replaying into a new hub gives the same contents.
        let copy = StoreHub::new(StoreConfig::DEFAULT).unwrap();
        for msg in hub.replay().into_messages() {
            copy.ingest(&msg.unwrap()).unwrap();
        }
        let (one, two) = (&hub.recordings()[0], &copy.recordings()[0]);
        assert_eq!(one.info.store_id, two.info.store_id);
        assert_eq!(
            one.snapshot.stats().num_rows(),
            two.snapshot.stats().num_rows()
        );
        copy.sanity_check().unwrap();
    }

    #[test]
    fn garbage_collection_brings_the_heap_under_the_limit_and_keeps_the_latest() {
        let hub = StoreHub::new(StoreConfig::DEFAULT).unwrap();
        let a = StoreId::recording("app", "a");
        for frame in 0..200 {
            let values: Vec<f64> = (0..1000).map(f64::from).collect();
            let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/x").unwrap())
                .with_row(
                    RowId::new(),
                    [(Timeline::sequence("frame"), frame)],
                    [("x", Arc::new(Float64Array::from(values)) as ArrayRef)],
                )
                .build()
                .unwrap();
            hub.ingest(&LogMsg::from_chunk(&a, &chunk, true).unwrap())
                .unwrap();
        }
        let before = hub.heap_bytes();
        let limit = before / 4;
        let outcome = hub.collect_garbage(limit);
        assert!(outcome.chunks_dropped > 0);
        assert!(outcome.bytes_after <= limit, "{outcome:?} over {limit}");
        assert_eq!(hub.heap_bytes(), outcome.bytes_after);
        // The newest row is still there.
        let snapshot = &hub.recordings()[0].snapshot;
        let frame = snapshot.view().time_range("frame");
        assert_eq!(frame.map(|r| r.max().as_i64()), Some(199));
        hub.sanity_check().unwrap();
        // Under the limit: nothing to do.
        let again = hub.collect_garbage(limit);
        assert_eq!(again.chunks_dropped, 0);
    }

    #[test]
    fn retention_measures_each_recording_from_its_own_newest_time() {
        let hub = StoreHub::new(StoreConfig::DEFAULT).unwrap();
        let (a, b) = (
            StoreId::recording("app", "a"),
            StoreId::recording("app", "b"),
        );
        for frame in 0..20 {
            hub.ingest(&LogMsg::from_chunk(&a, &chunk("/x", frame, 1.0), true).unwrap())
                .unwrap();
        }
        for frame in 0..5 {
            hub.ingest(&LogMsg::from_chunk(&b, &chunk("/y", frame, 1.0), true).unwrap())
                .unwrap();
        }
        let removed = hub.retain_recent(|t| (t.name() == "frame").then_some(3));
        assert!(removed > 0);
        let ranges: Vec<_> = hub
            .recordings()
            .iter()
            .map(|r| {
                let range = r.snapshot.view().time_range("frame").unwrap();
                (
                    range.min().as_i64(),
                    range.max().as_i64(),
                    r.snapshot.stats().num_rows(),
                )
            })
            .collect();
        assert_eq!(ranges, [(16, 19, 4), (1, 4, 4)]);
        // A timeline the rule does not cover is untouched.
        assert_eq!(hub.retain_recent(|t| (t.name() == "other").then_some(0)), 0);
        hub.sanity_check().unwrap();
    }

    #[test]
    fn a_dropped_recording_is_gone_and_the_others_stay_reachable() {
        let hub = StoreHub::new(StoreConfig::DEFAULT).unwrap();
        let ids = ["a", "b", "c"].map(|id| StoreId::recording("app", id));
        for (frame, id) in (0..).zip(&ids) {
            hub.ingest(&LogMsg::from_store_info(&StoreInfo::new(id.clone())))
                .unwrap();
            hub.ingest(&LogMsg::from_chunk(id, &chunk("/x", frame, 1.0), true).unwrap())
                .unwrap();
        }
        assert_eq!(hub.drop_recording("b"), [ids[1].clone()]);
        assert!(hub.drop_recording("b").is_empty());
        hub.sanity_check().unwrap();
        let left: Vec<_> = hub
            .recordings()
            .iter()
            .map(|r| r.info.store_id.clone())
            .collect();
        assert_eq!(left, [ids[0].clone(), ids[2].clone()]);
        // The one after it is still found by id: a chunk goes into it, not a new one.
        hub.ingest(&LogMsg::from_chunk(&ids[2], &chunk("/x", 9, 1.0), true).unwrap())
            .unwrap();
        assert_eq!(hub.recording_count(), 2);
        assert_eq!(hub.recordings()[1].snapshot.stats().num_rows(), 2);
        // The replay has no trace of it: two store infos, no chunk of "b".
        let replayed: Vec<LogMsg> = hub.replay().into_messages().map(Result::unwrap).collect();
        let infos = replayed
            .iter()
            .filter(|m| m.kind() == LogMsgKind::SetStoreInfo);
        assert_eq!(infos.count(), 2);
        assert!(
            replayed
                .iter()
                .all(|m| m.store_id().unwrap() != Some(ids[1].clone()))
        );
        hub.sanity_check().unwrap();
    }
}
