//! [`RecordingSelector`]: which one recording of a stream a reader loads.
//!
//! A file can hold several stores: a blueprint beside its recording (Rerun's
//! `RecordingStream.save(path, default_blueprint=…)` writes the blueprint first), several
//! recordings in one stream (one file sink shared by several recording streams), or several
//! streams concatenated (`cat a.rrd b.rrd`, which the format allows). A store holds one
//! recording: mixing two would let one recording's values answer for the other's and write
//! one's chunks under the other's identity. So a reader takes one recording, by its id
//! when one is asked for, else the only one there is; a second recording is an error that
//! names both, never a silent merge. Blueprints are never data (the reader skips them).

use super::error::RrdErrorKind;
use super::messages::{StoreId, StoreInfo, StoreKind};

/// Chooses the one recording a reader loads from a stream that may hold several, and
/// keeps that recording's store info. Feed it every store info and ask it about every
/// chunk's store, in stream order.
///
/// ```
/// use chunkstore::rrd::{RecordingSelector, StoreId};
/// let a = StoreId::recording("app", "a");
/// let b = StoreId::recording("app", "b");
///
/// // Asked for nothing: the first recording is taken, a second one is an error.
/// let mut only = RecordingSelector::new(None);
/// assert!(only.wants(&a).unwrap());
/// assert!(only.wants(&b).is_err());
///
/// // Asked for `b`: `a`'s chunks are passed over.
/// let mut chosen = RecordingSelector::new(Some("b"));
/// assert!(!chosen.wants(&a).unwrap());
/// assert!(chosen.wants(&b).unwrap());
/// assert_eq!(chosen.recording_ids(), ["a", "b"]);
/// ```
#[derive(Debug, Clone, Default)]
pub struct RecordingSelector {
    /// The recording id asked for, if any.
    wanted: Option<String>,
    /// The recording taken: the one asked for, or the first one with data.
    chosen: Option<StoreId>,
    /// The first store info of every recording seen, in stream order.
    infos: Vec<StoreInfo>,
    /// Every recording seen (by a store info or a chunk), in stream order, each once.
    seen: Vec<StoreId>,
}

impl RecordingSelector {
    /// A selector for the recording `wanted` (its recording id), or for the only one.
    pub fn new(wanted: Option<&str>) -> Self {
        Self {
            wanted: wanted.map(str::to_owned),
            ..Self::default()
        }
    }

    /// Notes a store info of the stream.
    pub fn observe(&mut self, info: &StoreInfo) {
        if info.store_id.kind != StoreKind::Recording {
            return;
        }
        self.note_seen(&info.store_id);
        if !self.infos.iter().any(|i| i.store_id == info.store_id) {
            self.infos.push(info.clone());
        }
    }

    fn note_seen(&mut self, store: &StoreId) {
        if !self.seen.contains(store) {
            self.seen.push(store.clone());
        }
    }

    /// Whether to load a chunk of `store`.
    ///
    /// # Errors
    /// [`RrdErrorKind::SeveralRecordings`] if no recording was asked for and this chunk
    /// belongs to a second one.
    pub fn wants(&mut self, store: &StoreId) -> Result<bool, RrdErrorKind> {
        if store.kind != StoreKind::Recording {
            return Ok(false);
        }
        self.note_seen(store);
        if let Some(wanted) = &self.wanted {
            if *store.recording_id != **wanted {
                return Ok(false);
            }
            self.chosen.get_or_insert_with(|| store.clone());
            return Ok(true);
        }
        match &self.chosen {
            None => {
                self.chosen = Some(store.clone());
                Ok(true)
            }
            Some(chosen) if chosen == store => Ok(true),
            Some(_) => Err(self.several()),
        }
    }

    fn several(&self) -> RrdErrorKind {
        RrdErrorKind::SeveralRecordings {
            recording_ids: self.recording_ids(),
        }
    }

    /// The recording ids seen so far, in stream order, each once.
    pub fn recording_ids(&self) -> Vec<String> {
        let mut ids: Vec<String> = Vec::new();
        for store in &self.seen {
            if !ids.iter().any(|id| **id == *store.recording_id) {
                ids.push(store.recording_id.to_string());
            }
        }
        ids
    }

    /// The chosen recording's store info: the first one seen of its store. Before any
    /// chunk (a recording without data), the one asked for, or the first recording's.
    pub fn store_info(&self) -> Option<&StoreInfo> {
        match (&self.chosen, &self.wanted) {
            (Some(chosen), _) => self.infos.iter().find(|i| &i.store_id == chosen),
            (None, Some(wanted)) => self
                .infos
                .iter()
                .find(|i| *i.store_id.recording_id == **wanted),
            (None, None) => self.infos.first(),
        }
    }

    /// The end of the stream: the chosen recording's store info.
    ///
    /// # Errors
    /// [`RrdErrorKind::NoSuchRecording`] if a recording was asked for and the stream has
    /// neither a chunk nor a store info of it.
    pub fn finish(self) -> Result<Option<StoreInfo>, RrdErrorKind> {
        if let Some(wanted) = &self.wanted
            && self.chosen.is_none()
            && self.store_info().is_none()
        {
            return Err(RrdErrorKind::NoSuchRecording {
                wanted: wanted.clone(),
                recording_ids: self.recording_ids(),
            });
        }
        Ok(self.store_info().cloned())
    }
}

/// Picks the recording `wanted` (or the only one) among `stores`, the recordings a footer
/// lists: for a reader that knows every store up front.
pub(crate) fn pick<'a>(
    stores: impl IntoIterator<Item = &'a StoreId>,
    wanted: Option<&str>,
) -> Result<Option<&'a StoreId>, RrdErrorKind> {
    let mut selector = RecordingSelector::new(wanted);
    let stores: Vec<&StoreId> = stores.into_iter().collect();
    // Every recording the footer lists is seen before any is chosen: an error for "more
    // than one" names them all, not the first two.
    for store in &stores {
        if store.kind == StoreKind::Recording {
            selector.note_seen(store);
        }
    }
    let mut picked = None;
    for store in stores {
        if selector.wants(store)? && picked.is_none() {
            picked = Some(store);
        }
    }
    if picked.is_none()
        && let Some(wanted) = wanted
    {
        return Err(RrdErrorKind::NoSuchRecording {
            wanted: wanted.to_owned(),
            recording_ids: selector.recording_ids(),
        });
    }
    Ok(picked)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(kind: StoreKind, id: &str) -> StoreInfo {
        StoreInfo::new(StoreId {
            kind,
            application_id: "app".into(),
            recording_id: id.into(),
        })
    }

    #[test]
    fn a_blueprint_first_is_not_the_recording() {
        let mut selector = RecordingSelector::new(None);
        selector.observe(&info(StoreKind::Blueprint, "bp"));
        selector.observe(&info(StoreKind::Recording, "rec"));
        let blueprint = info(StoreKind::Blueprint, "bp").store_id;
        assert!(!selector.wants(&blueprint).unwrap());
        assert!(
            selector
                .wants(&info(StoreKind::Recording, "rec").store_id)
                .unwrap()
        );
        let chosen = selector.finish().unwrap().unwrap();
        assert_eq!(&*chosen.store_id.recording_id, "rec");
        assert_eq!(chosen.store_id.kind, StoreKind::Recording);
    }

    #[test]
    fn a_second_recording_is_named_unless_one_was_asked_for() {
        let a = info(StoreKind::Recording, "a");
        let b = info(StoreKind::Recording, "b");
        let mut selector = RecordingSelector::new(None);
        selector.observe(&a);
        selector.observe(&b);
        assert!(selector.wants(&a.store_id).unwrap());
        let error = selector.wants(&b.store_id).unwrap_err();
        assert!(
            matches!(&error, RrdErrorKind::SeveralRecordings { recording_ids } if recording_ids == &["a", "b"]),
            "{error:?}"
        );

        let mut selector = RecordingSelector::new(Some("b"));
        selector.observe(&a);
        selector.observe(&b);
        assert!(!selector.wants(&a.store_id).unwrap());
        assert!(selector.wants(&b.store_id).unwrap());
        assert_eq!(selector.finish().unwrap(), Some(b));

        let mut selector = RecordingSelector::new(Some("c"));
        selector.observe(&a);
        assert!(!selector.wants(&a.store_id).unwrap());
        assert!(matches!(
            selector.finish(),
            Err(RrdErrorKind::NoSuchRecording { wanted, recording_ids }) if wanted == "c" && recording_ids == ["a"]
        ));
    }

    #[test]
    fn pick_chooses_among_a_footer_s_stores() {
        let a = info(StoreKind::Recording, "a").store_id;
        let b = info(StoreKind::Recording, "b").store_id;
        let bp = info(StoreKind::Blueprint, "bp").store_id;
        assert_eq!(pick([&bp, &a], None).unwrap(), Some(&a));
        assert!(pick([&a, &b], None).is_err());
        assert_eq!(pick([&a, &b], Some("b")).unwrap(), Some(&b));
        assert!(pick([&a, &b], Some("c")).is_err());
        assert_eq!(pick([&bp], None).unwrap(), None);
    }

    #[test]
    fn several_recordings_in_a_footer_are_all_named() {
        let stores: Vec<StoreId> = ["a", "b", "c", "d"]
            .into_iter()
            .map(|id| info(StoreKind::Recording, id).store_id)
            .collect();
        let error = pick(&stores, None).unwrap_err();
        assert!(
            matches!(&error, RrdErrorKind::SeveralRecordings { recording_ids } if recording_ids == &["a", "b", "c", "d"]),
            "{error:?}"
        );
    }
}
