//! The large form of a [`TemporalComponentIndex`](super::TemporalComponentIndex): three
//! ordered views (by greatest index, by least time, and spanning chunks by span class) and
//! a short queue of the newest chunks kept outside them.
//!
//! The views are persistent B-trees (`imbl::OrdMap`, nodes of 16 entries): cloning one is
//! a reference count, and a write to an index a snapshot shares copies only the nodes on
//! the path to what it changes, O(log n), never the whole index. A store nobody snapshots
//! owns every node, so its writes copy nothing.

use std::collections::VecDeque;
use std::ops::Bound;
use std::sync::Arc;

use super::{IndexedChunk, MaxIndexKey, MinTimeKey, check_bounds, max_index_key, min_time_key};
use crate::chunk::ComponentTimeBounds;
use crate::sanity::{SanityError, Structure};
use crate::{ChunkId, RowId, TimeInt};

/// A large index keeps up to this many of its newest chunks in arrival order, outside its
/// B-trees. See [`LargeIndex::recent`].
const LARGE_INDEX_RECENT_CHUNKS: usize = 16;

/// The three views of a large index, and its newest chunks.
#[derive(Clone, Debug, Default)]
pub(crate) struct LargeIndex {
    /// The newest chunks, oldest first, in none of the views: the oldest moves into them
    /// when this is full. Compaction on insert merges small chunks a few inserts after
    /// they arrive, so most of them come and go here without touching a B-tree (three
    /// inserts and three removals each); every question scans these few as well.
    pub(super) recent: VecDeque<IndexedChunk>,
    pub(super) chunks_by_max_index: OrdMap<MaxIndexKey, IndexedChunk>,
    pub(super) chunks_by_min_time: OrdMap<MinTimeKey, IndexedChunk>,
    /// `spanning_chunk_ids_by_min_time_per_span_class[L]`: chunks with `2^L ≤ max − min <
    /// 2^(L+1)`, mapped to their `max`; their key is also their key in `chunks_by_min_time`,
    /// which resolves them. Empty classes cost nothing but an empty map.
    pub(super) spanning_chunk_ids_by_min_time_per_span_class: Vec<OrdMap<MinTimeKey, TimeInt>>,
}

type OrdMap<K, V> = imbl::OrdMap<K, V>;

fn span_class(min: TimeInt, max: TimeInt) -> Option<usize> {
    let span = max.as_i64().abs_diff(min.as_i64());
    (span > 0).then(|| span.ilog2() as usize)
}

impl LargeIndex {
    pub(super) fn len(&self) -> usize {
        self.chunks_by_min_time.len() + self.recent.len()
    }

    /// Every entry `keep` keeps, sorted by `(least time, chunk id)`.
    pub(super) fn entries_by_min_time(
        &self,
        keep: impl Fn(&IndexedChunk) -> bool,
    ) -> Vec<IndexedChunk> {
        let mut entries: Vec<IndexedChunk> = self
            .chunks_by_min_time
            .values()
            .chain(&self.recent)
            .filter(|e| keep(e))
            .cloned()
            .collect();
        entries.sort_by_key(min_time_key);
        entries
    }

    pub(super) fn insert(&mut self, entry: IndexedChunk) {
        // The store adds a chunk id once (its chunk map refuses a second), so no search
        // for an earlier copy is made here.
        debug_assert!(
            !self.recent.iter().any(|e| e.chunk_id == entry.chunk_id)
                && !self
                    .chunks_by_min_time
                    .contains_key(&(entry.bounds.min_time, entry.chunk_id)),
            "{} indexed twice",
            entry.chunk_id
        );
        self.recent.push_back(entry);
        if self.recent.len() > LARGE_INDEX_RECENT_CHUNKS
            && let Some(oldest) = self.recent.pop_front()
        {
            self.insert_in_views(oldest);
        }
    }

    /// Puts an entry leaving `recent` into the views (the store adds each chunk once, so
    /// it is not there yet).
    pub(super) fn insert_in_views(&mut self, entry: IndexedChunk) {
        let id = entry.chunk_id;
        let (min, max) = (entry.bounds.min_time, entry.bounds.max_time);
        self.chunks_by_min_time.insert((min, id), entry.clone());
        if let Some(class) = span_class(min, max) {
            let classes = &mut self.spanning_chunk_ids_by_min_time_per_span_class;
            if classes.len() <= class {
                classes.resize_with(class + 1, OrdMap::new);
            }
            classes[class].insert((min, id), max);
        }
        self.chunks_by_max_index
            .insert(max_index_key(&entry), entry);
    }

    pub(super) fn remove(&mut self, id: ChunkId, bounds: &ComponentTimeBounds) -> bool {
        if let Some(position) = self.recent.iter().position(|e| e.chunk_id == id) {
            self.recent.remove(position);
            return true;
        }
        let (min, max) = (bounds.min_time, bounds.max_time);
        if self.chunks_by_min_time.remove(&(min, id)).is_none() {
            return false;
        }
        if let Some(class) = span_class(min, max) {
            let classes = &mut self.spanning_chunk_ids_by_min_time_per_span_class;
            if let Some(chunks) = classes.get_mut(class) {
                chunks.remove(&(min, id));
            }
            while classes.last().is_some_and(OrdMap::is_empty) {
                classes.pop();
            }
        }
        self.chunks_by_max_index
            .remove(&(max, bounds.max_row_id, id));
        true
    }

    /// How many entries have a greatest index above `key`, counting at most `cap` of
    /// those in the views.
    pub(super) fn count_after(&self, key: MaxIndexKey, cap: usize) -> usize {
        let in_views = self
            .chunks_by_max_index
            .range((Bound::Excluded(key), Bound::Unbounded))
            .take(cap)
            .count();
        in_views
            + self
                .recent
                .iter()
                .filter(|e| max_index_key(e) > key)
                .count()
    }

    pub(super) fn latest_ending_at_or_before(&self, t: TimeInt) -> Option<&IndexedChunk> {
        let in_views = self
            .chunks_by_max_index
            .get_prev(&(t, RowId::MAX, ChunkId::MAX))
            .map(|(_, entry)| entry);
        self.recent
            .iter()
            .filter(|e| e.bounds.max_time <= t)
            .chain(in_views)
            .max_by_key(|e| max_index_key(e))
    }

    pub(super) fn for_each_straddling<'a>(
        &'a self,
        t: TimeInt,
        mut f: impl FnMut(&'a IndexedChunk),
    ) {
        self.recent
            .iter()
            .filter(|e| e.bounds.min_time <= t && t < e.bounds.max_time)
            .for_each(&mut f);
        self.for_each_spanning(t, Bound::Included((t, ChunkId::MAX)), |max| max > t, f);
    }

    pub(super) fn for_each_reaching_into<'a>(
        &'a self,
        t: TimeInt,
        mut f: impl FnMut(&'a IndexedChunk),
    ) {
        self.recent
            .iter()
            .filter(|e| e.bounds.min_time < t && t <= e.bounds.max_time)
            .for_each(&mut f);
        self.for_each_spanning(t, Bound::Excluded((t, ChunkId::ZERO)), |max| max >= t, f);
    }

    /// Spanning chunks keyed up to `key_end` whose `max` is accepted by `reaches`, where
    /// every accepted `max` is at least `t`.
    pub(super) fn for_each_spanning<'a>(
        &'a self,
        t: TimeInt,
        key_end: Bound<MinTimeKey>,
        reaches: impl Fn(TimeInt) -> bool,
        mut f: impl FnMut(&'a IndexedChunk),
    ) {
        let classes = &self.spanning_chunk_ids_by_min_time_per_span_class;
        for (class, chunks) in classes.iter().enumerate().filter(|(_, c)| !c.is_empty()) {
            // span < 2^(class+1) and max ≥ t  ⇒  min > t − 2^(class+1).
            let lowest = i128::from(t.as_i64()) - (1i128 << (class + 1)) + 1;
            let lowest = TimeInt::saturating(i64::try_from(lowest).unwrap_or(i64::MIN));
            for (key, &max) in chunks.range((Bound::Included((lowest, ChunkId::ZERO)), key_end)) {
                if reaches(max)
                    && let Some(entry) = self.chunks_by_min_time.get(key)
                {
                    f(entry);
                }
            }
        }
    }

    pub(super) fn for_each_starting_in<'a>(
        &'a self,
        min: TimeInt,
        max: TimeInt,
        mut f: impl FnMut(&'a IndexedChunk),
    ) {
        let in_range = |e: &&IndexedChunk| (min..=max).contains(&e.bounds.min_time);
        let mut recent: Vec<&IndexedChunk> = self.recent.iter().filter(in_range).collect();
        recent.sort_by_key(|e| min_time_key(e));
        let mut recent = recent.into_iter().peekable();
        for entry in self
            .chunks_by_min_time
            .range((min, ChunkId::ZERO)..=(max, ChunkId::MAX))
            .map(|(_, e)| e)
        {
            while let Some(earlier) = recent.next_if(|r| min_time_key(r) < min_time_key(entry)) {
                f(earlier);
            }
            f(entry);
        }
        recent.for_each(f);
    }

    pub(super) fn sanity_check(&self) -> Result<(), SanityError> {
        let fail = |invariant| SanityError::new(Structure::TemporalIndex, invariant);
        let Self {
            recent,
            chunks_by_max_index,
            chunks_by_min_time,
            spanning_chunk_ids_by_min_time_per_span_class,
        } = self;
        if recent.len() > LARGE_INDEX_RECENT_CHUNKS {
            return Err(fail(
                "a large index keeps at most LARGE_INDEX_RECENT_CHUNKS recent chunks",
            )
            .at(format_args!("{} recent", recent.len())));
        }
        for (i, entry) in recent.iter().enumerate() {
            let id = entry.chunk_id;
            if recent.iter().skip(i + 1).any(|e| e.chunk_id == id)
                || chunks_by_min_time.contains_key(&(entry.bounds.min_time, id))
            {
                return Err(fail("a chunk is indexed once").at(id));
            }
            check_bounds(entry)?;
        }
        if chunks_by_max_index.len() != chunks_by_min_time.len() {
            return Err(fail("both views index the same chunks").at(format_args!(
                "{} by max index, {} by min time",
                chunks_by_max_index.len(),
                chunks_by_min_time.len()
            )));
        }
        let mut num_spanning = 0;
        for (class, chunks) in spanning_chunk_ids_by_min_time_per_span_class
            .iter()
            .enumerate()
        {
            for (key @ &(min, id), &max) in chunks {
                num_spanning += 1;
                if span_class(min, max) != Some(class) {
                    return Err(fail("a chunk sits in the span class of its span").at(id));
                }
                if chunks_by_min_time
                    .get(key)
                    .is_none_or(|e| e.bounds.max_time != max)
                {
                    return Err(fail("a span class entry resolves to its chunk's bounds").at(id));
                }
            }
        }
        for (key, entry) in chunks_by_max_index {
            let b = entry.bounds;
            if *key != max_index_key(entry) {
                return Err(fail("a chunk is keyed by its greatest index").at(entry.chunk_id));
            }
            let by_min = chunks_by_min_time.get(&(b.min_time, entry.chunk_id));
            if by_min.is_none_or(|e| !Arc::ptr_eq(&e.chunk, &entry.chunk)) {
                return Err(fail("a chunk is keyed by its least time").at(entry.chunk_id));
            }
            check_bounds(entry)?;
        }
        let expected_spanning = chunks_by_max_index
            .values()
            .filter(|e| e.bounds.min_time < e.bounds.max_time)
            .count();
        if num_spanning != expected_spanning {
            return Err(fail(
                "exactly the chunks spanning several times are in span classes",
            ));
        }
        Ok(())
    }
}
