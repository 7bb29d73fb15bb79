//! The temporal index of one (entity, timeline, component): which chunks hold non-null
//! cells of the component, arranged so that latest-at and range find their chunks in
//! O(log n) plus the chunks that really matter, whatever the order chunks arrived in.
//!
//! Three views of the same set of chunks:
//! - by **greatest index** `(max time, row id)`: the predecessor of `(t, ∞)` is the best
//!   answer among all chunks that end at or before `t`;
//! - by **least time**: range queries take every chunk starting inside `[min, max]` (the
//!   entry is stored here too, so a range pays no lookup per chunk);
//! - chunks whose cells **span** more than one time, bucketed by `⌊log2(span)⌋` and keyed by
//!   least time: a chunk of bucket `L` that contains `t` starts in `(t − 2^(L+1), t]`, so the
//!   chunks straddling a time are found without scanning older ones. (This is what keeps one
//!   long chunk from slowing every query down, unlike bounding a walk by the longest span.)
//!
//! Most indices hold few chunks (a viewer logs thousands of entities, each with a handful
//! of chunks): up to [`SMALL_INDEX_MAX_CHUNKS`] chunks, an index is one vector sorted by
//! least time and scanned linearly, which costs a fraction of three B-trees' nodes in
//! memory and answers in a few cache lines. Beyond that, chunks that do not overlap in
//! time and arrive in time order (batches of a live stream, recordings loaded in order)
//! stay in one *sequence*: a deque in which least times, greatest times and greatest
//! indices all ascend together, so every question is one binary search, and arrival and
//! garbage collection (oldest first, or from both ends around a cursor) touch only its
//! ends. The first chunk that breaks the order turns the index into the three views
//! above, which keep their newest few chunks in arrival order outside the B-trees
//! (compaction merges most small chunks away before they would reach them). Either turns
//! back into a vector once it holds half of the small limit.
//!
//! Snapshots share indices with the store (SEMANTICS.md section 10), so a write to an index
//! a snapshot holds must copy what it changes, and each form bounds that copy. A small
//! index is one vector of at most [`SMALL_INDEX_MAX_CHUNKS`] entries, copied whole. A
//! sequence is a deque of entries and one of their least times behind an `Arc` (a
//! query's binary search reads the dense times, `sequence.rs`, and a store nobody
//! snapshots changes both in place), copied whole too,
//! so it holds at most [`SEQUENCE_MAX_CHUNKS`]: past that, even in order, an index takes
//! the three views, persistent B-trees (`imbl::OrdMap`, 16-entry nodes) of which a write
//! copies only the nodes on its path, O(log n) however many chunks the index holds.

mod large;
mod sequence;

use std::sync::Arc;

use crate::chunk::ComponentTimeBounds;
use crate::sanity::{SanityError, Structure};
use crate::{Chunk, ChunkId, RowId, TimeInt};
use large::LargeIndex;
use sequence::ChunkSequence;

/// A chunk as the index sees it: the chunk, where its time column and component column are,
/// and the component's bounds on this timeline.
#[derive(Clone, Debug)]
pub(crate) struct IndexedChunk {
    pub chunk: Arc<Chunk>,
    /// The chunk's id, kept beside its bounds: every scan and search of an index compares
    /// ids, and reading them from the chunks would cost a cache miss per chunk.
    pub chunk_id: ChunkId,
    pub time_column: u32,
    pub component_column: u32,
    pub bounds: ComponentTimeBounds,
}

pub(crate) type MaxIndexKey = (TimeInt, RowId, ChunkId);
type MinTimeKey = (TimeInt, ChunkId);

/// Up to this many chunks, an index is one sorted vector; see the module docs.
pub(crate) const SMALL_INDEX_MAX_CHUNKS: usize = 32;

/// Heap of one chunk's entry in a small index: its slot in the vector, with the vector's
/// usual spare capacity. An estimate, held to account by `tests/memory/main.rs`.
pub(crate) const SMALL_INDEX_BYTES_PER_ENTRY: u64 = 80;

/// Heap of one chunk's entry in a large index: its share of the nodes of the two ordered
/// views (B-tree nodes filled in order are about half full, so an entry costs about twice
/// its keys and values). Measured with the counting allocator of `tests/memory/main.rs`.
pub(crate) const LARGE_INDEX_BYTES_PER_ENTRY: u64 = 490;

/// The index of one (entity, timeline, component): see the module docs.
#[derive(Clone, Debug)]
pub(crate) enum TemporalComponentIndex {
    /// At most [`SMALL_INDEX_MAX_CHUNKS`] entries, sorted by `(least time, chunk id)`.
    Small(Vec<IndexedChunk>),
    /// More than half of [`SMALL_INDEX_MAX_CHUNKS`] and at most [`SEQUENCE_MAX_CHUNKS`]
    /// entries that do not overlap in time, in time order: each ends strictly before the
    /// next starts.
    Sequence(Arc<ChunkSequence>),
    /// More than half of [`SMALL_INDEX_MAX_CHUNKS`] entries. Behind an `Arc` so that
    /// copying an entity's view counts one reference here; a write under a snapshot then
    /// copies the index's roots and recent queue, and the B-tree nodes on its path.
    Large(Arc<LargeIndex>),
}

/// [`TemporalComponentIndex::remove_many`] indexes the survivors afresh only from this
/// many removals on (and only when they are at least half of the index): below it, a
/// removal each costs less than making the set of removed ids.
const REBUILD_MIN_REMOVALS: usize = 8;

/// A middle removal from a sequence shifts at most this many entries; past that the
/// sequence turns into the three views, where removal is logarithmic.
const SEQUENCE_MAX_SHIFT: usize = 64;

/// A sequence holds at most this many chunks; one more turns it into the three views. A
/// write to a sequence a snapshot shares copies it whole, where the views copy a path:
/// without a bound, a `SharedStore` publishing after every insert into one entity of
/// 40,000 chunks spent 5 ms per row (see `docs/performance-log.md`, "Snapshots and the shared store"). The bound
/// trades that copy (at most 1 MiB of entries and as many reference counts, about a
/// millisecond when the chunks are cold) against the plain store's inserts, which cost a
/// sequence a `push_back` and the views two or three B-tree insertions (`insert_batched`'s
/// 10,000 chunks took 2.4× the instructions as views). A segmented sequence would bound
/// the copy without that trade; until then, this keeps sequences for entities of up to
/// 16,384 chunks (at the default compaction, tens of millions of rows).
pub(crate) const SEQUENCE_MAX_CHUNKS: usize = 16_384;

/// Do `entries` (sorted by least time) each end strictly before the next starts?
fn in_sequence<'a>(entries: impl IntoIterator<Item = &'a IndexedChunk>) -> bool {
    let mut previous_max = None;
    entries.into_iter().all(|e| {
        let ordered = previous_max.is_none_or(|max| max < e.bounds.min_time);
        previous_max = Some(e.bounds.max_time);
        ordered
    })
}

fn large_from(entries: impl IntoIterator<Item = IndexedChunk>) -> TemporalComponentIndex {
    let mut large = LargeIndex::default();
    for entry in entries {
        large.insert(entry);
    }
    TemporalComponentIndex::Large(Arc::new(large))
}

impl Default for TemporalComponentIndex {
    fn default() -> Self {
        Self::Small(Vec::new())
    }
}

fn min_time_key(entry: &IndexedChunk) -> MinTimeKey {
    (entry.bounds.min_time, entry.chunk_id)
}

impl TemporalComponentIndex {
    /// Indexes a chunk (once: a chunk already indexed is left as it is).
    pub fn insert(&mut self, entry: IndexedChunk) {
        match self {
            Self::Small(entries) => {
                let key = min_time_key(&entry);
                let Err(position) = entries.binary_search_by_key(&key, min_time_key) else {
                    return; // already indexed: a store never inserts a chunk id twice
                };
                // Most indices of a many-entity store hold one chunk: a first push would
                // make room for four (320 bytes, 240 of them never used).
                if entries.capacity() == 0 {
                    entries.reserve_exact(1);
                }
                entries.insert(position, entry);
                if entries.len() > SMALL_INDEX_MAX_CHUNKS {
                    *self = Self::from_sorted(std::mem::take(entries));
                }
            }
            Self::Sequence(shared) => {
                let entries = Arc::make_mut(shared);
                let (Some(first), Some(last)) = (entries.front(), entries.back()) else {
                    entries.push_back(entry);
                    return;
                };
                if entries.len() >= SEQUENCE_MAX_CHUNKS {
                    let mut index = large_from(entries.take_entries());
                    index.insert(entry);
                    *self = index;
                } else if last.bounds.max_time < entry.bounds.min_time {
                    entries.push_back(entry);
                } else if entry.bounds.max_time < first.bounds.min_time {
                    entries.push_front(entry);
                } else if let Err(position) = entries.search(&min_time_key(&entry)) {
                    // A chunk filling a gap (the rest of a chunk a range drop cut) keeps
                    // the sequence, if it overlaps neither neighbour and few entries move.
                    let fits = position
                        .checked_sub(1)
                        .and_then(|before| entries.get(before))
                        .is_none_or(|before| before.bounds.max_time < entry.bounds.min_time)
                        && entries
                            .get(position)
                            .is_none_or(|after| entry.bounds.max_time < after.bounds.min_time);
                    if fits && position.min(entries.len() - position) <= SEQUENCE_MAX_SHIFT {
                        entries.insert(position, entry);
                    } else {
                        let mut index = large_from(entries.take_entries());
                        index.insert(entry);
                        *self = index;
                    }
                }
            }
            Self::Large(large) => Arc::make_mut(large).insert(entry),
        }
    }

    /// Forgets a chunk indexed with `bounds`; returns whether it was indexed.
    pub fn remove(&mut self, id: ChunkId, bounds: &ComponentTimeBounds) -> bool {
        match self {
            Self::Small(entries) => {
                let key = (bounds.min_time, id);
                let Ok(position) = entries.binary_search_by_key(&key, min_time_key) else {
                    return false;
                };
                entries.remove(position);
                if entries.len() * 4 <= entries.capacity() {
                    entries.shrink_to(entries.len() * 2);
                }
                true
            }
            Self::Sequence(shared) => {
                let entries = Arc::make_mut(shared);
                let key = (bounds.min_time, id);
                let position = if entries.front().is_some_and(|e| min_time_key(e) == key) {
                    0
                } else if entries.back().is_some_and(|e| min_time_key(e) == key) {
                    entries.len() - 1
                } else {
                    let Ok(position) = entries.search(&key) else {
                        return false;
                    };
                    position
                };
                if position.min(entries.len() - 1 - position) > SEQUENCE_MAX_SHIFT {
                    let mut index = large_from(entries.take_entries());
                    let removed = index.remove(id, bounds);
                    *self = index;
                    return removed;
                }
                entries.remove(position);
                if entries.len() <= SMALL_INDEX_MAX_CHUNKS / 2 {
                    *self = Self::Small(entries.take_entries().into());
                } else {
                    entries.shrink_if_sparse();
                }
                true
            }
            Self::Large(shared) => {
                let large = Arc::make_mut(shared);
                let removed = large.remove(id, bounds);
                if large.len() <= SMALL_INDEX_MAX_CHUNKS / 2 {
                    *self = Self::Small(large.entries_by_min_time(|_| true));
                }
                removed
            }
        }
    }

    /// Forgets the chunks of `removed` (each indexed with its bounds here); returns how
    /// many were indexed. Where they are at least half of an index in the three views,
    /// the survivors are indexed afresh in whichever form suits them (one pass, and
    /// nothing when none survive) rather than removed one search and rebalance at a time:
    /// compaction and garbage collection take most or all of an entity's chunks out at
    /// once.
    pub fn remove_many(&mut self, removed: &[(ChunkId, ComponentTimeBounds)]) -> usize {
        let len = self.len();
        // Only the views pay a search and a rebalance per removal; a vector or a
        // sequence loses an entry for a shift (none at its ends).
        let survivors = match &*self {
            Self::Large(large)
                if removed.len() >= REBUILD_MIN_REMOVALS && removed.len() * 2 >= len =>
            {
                let gone: ahash::HashSet<ChunkId> = removed.iter().map(|&(id, _)| id).collect();
                large.entries_by_min_time(|e| !gone.contains(&e.chunk_id))
            }
            _ => {
                return removed
                    .iter()
                    .filter(|(id, bounds)| self.remove(*id, bounds))
                    .count();
            }
        };
        let num_removed = len - survivors.len();
        *self = Self::from_sorted(survivors);
        num_removed
    }

    /// An index of `entries`, sorted by `(least time, chunk id)` and distinct, in the
    /// form their number and order call for.
    fn from_sorted(entries: Vec<IndexedChunk>) -> Self {
        if entries.len() <= SMALL_INDEX_MAX_CHUNKS {
            Self::Small(entries)
        } else if entries.len() <= SEQUENCE_MAX_CHUNKS && in_sequence(&entries) {
            Self::Sequence(Arc::new(ChunkSequence::new(entries)))
        } else {
            large_from(entries)
        }
    }

    /// How many chunks the index holds.
    pub fn len(&self) -> usize {
        match self {
            Self::Small(entries) => entries.len(),
            Self::Sequence(entries) => entries.len(),
            Self::Large(large) => large.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        match self {
            Self::Small(entries) => entries.is_empty(),
            Self::Sequence(entries) => entries.is_empty(),
            Self::Large(large) => large.len() == 0,
        }
    }

    /// Heap this index holds beyond [`SMALL_INDEX_BYTES_PER_ENTRY`] per chunk, which the
    /// store counts with each chunk: what a large index's B-trees add.
    pub fn extra_heap_bytes(&self) -> u64 {
        match self {
            Self::Small(_) | Self::Sequence(_) => 0,
            Self::Large(large) => {
                large.len() as u64 * (LARGE_INDEX_BYTES_PER_ENTRY - SMALL_INDEX_BYTES_PER_ENTRY)
            }
        }
    }

    /// How many chunks have a greatest index `(max time, max row id, chunk id)` above
    /// `key`; past `cap`, the count may stop at `cap`.
    pub fn count_after(&self, key: MaxIndexKey, cap: usize) -> usize {
        match self {
            Self::Small(entries) => entries.iter().filter(|e| max_index_key(e) > key).count(),
            // Greatest indices ascend with the position: the chunks after `key` are the
            // last ones, counted from the end up to `cap` (garbage collection asks with the
            // few it protects, so this reads the entries it is about to read anyway rather
            // than a binary search's cold ones).
            Self::Sequence(entries) => entries
                .iter()
                .rev()
                .take(cap)
                .take_while(|e| max_index_key(e) > key)
                .count(),
            Self::Large(large) => large.count_after(key, cap),
        }
    }

    /// Every chunk that may hold the latest-at answer at `t`, as `f(entry, straddles)`: the
    /// one whose greatest index is the greatest among those ending at or before `t`
    /// (`straddles == false`: its answer is that greatest cell), and every chunk with
    /// `min ≤ t < max` (`true`: its answer is not its greatest index, so it needs a search
    /// inside the chunk). A chunk another one reported is known to beat may be left out.
    pub fn for_each_latest_at_candidate<'a>(
        &'a self,
        t: TimeInt,
        mut f: impl FnMut(&'a IndexedChunk, bool),
    ) {
        match self {
            // One pass, which stops at the first chunk starting after `t`.
            Self::Small(entries) => {
                let mut latest_ending: Option<&IndexedChunk> = None;
                for entry in entries.iter().take_while(|e| e.bounds.min_time <= t) {
                    if entry.bounds.max_time > t {
                        f(entry, true);
                    } else if latest_ending
                        .is_none_or(|latest| max_index_key(entry) > max_index_key(latest))
                    {
                        latest_ending = Some(entry);
                    }
                }
                if let Some(entry) = latest_ending {
                    f(entry, false);
                }
            }
            // One search. The last chunk starting at or before `t` is the only one that can
            // reach past it; if it does not, it is the latest one ending by `t`. If it
            // does, it has a non-null cell at its least time, at or before `t` and after
            // every cell of the chunks before it (each ends before the next starts), so it
            // alone holds the answer.
            Self::Sequence(entries) => {
                let starting = entries.count_starting(|&min| min <= t);
                if let Some(entry) = starting.checked_sub(1).and_then(|last| entries.get(last)) {
                    f(entry, entry.bounds.max_time > t);
                }
            }
            Self::Large(large) => {
                if let Some(entry) = large.latest_ending_at_or_before(t) {
                    f(entry, false);
                }
                large.for_each_straddling(t, &mut |entry| f(entry, true));
            }
        }
    }

    /// Chunks with `min < t ≤ max`: those that start before a range beginning at `t` and
    /// reach into it.
    pub fn for_each_reaching_into<'a>(&'a self, t: TimeInt, mut f: impl FnMut(&'a IndexedChunk)) {
        match self {
            Self::Small(entries) => entries
                .iter()
                .take_while(|e| e.bounds.min_time < t)
                .filter(|e| e.bounds.max_time >= t)
                .for_each(f),
            Self::Sequence(entries) => {
                let end = entries.count_starting(|&min| min < t);
                if let Some(e) = end.checked_sub(1).and_then(|last| entries.get(last))
                    && e.bounds.max_time >= t
                {
                    f(e);
                }
            }
            Self::Large(large) => large.for_each_reaching_into(t, &mut f),
        }
    }

    /// Every chunk starting in `[min, max]`, by least time.
    pub fn for_each_starting_in<'a>(
        &'a self,
        min: TimeInt,
        max: TimeInt,
        mut f: impl FnMut(&'a IndexedChunk),
    ) {
        match self {
            Self::Small(entries) => entries
                .iter()
                .skip_while(|e| e.bounds.min_time < min)
                .take_while(|e| e.bounds.min_time <= max)
                .for_each(f),
            Self::Sequence(entries) => {
                let start = entries.count_starting(|&t| t < min);
                let end = entries.count_starting(|&t| t <= max);
                entries.range(start..end.max(start)).for_each(f);
            }
            Self::Large(large) => large.for_each_starting_in(min, max, &mut f),
        }
    }

    /// Every chunk, in no particular order.
    pub fn chunks(&self) -> Box<dyn Iterator<Item = &IndexedChunk> + '_> {
        match self {
            Self::Small(entries) => Box::new(entries.iter()),
            Self::Sequence(entries) => Box::new(entries.iter()),
            Self::Large(large) => Box::new(large.chunks_by_max_index.values().chain(&large.recent)),
        }
    }

    pub fn sanity_check(&self) -> Result<(), SanityError> {
        let fail = |invariant| SanityError::new(Structure::TemporalIndex, invariant);
        match self {
            Self::Small(entries) => {
                if entries.len() > SMALL_INDEX_MAX_CHUNKS {
                    return Err(
                        fail("a small index holds at most SMALL_INDEX_MAX_CHUNKS chunks")
                            .at(format_args!("{} chunks", entries.len())),
                    );
                }
                if !entries
                    .windows(2)
                    .all(|w| min_time_key(&w[0]) < min_time_key(&w[1]))
                {
                    return Err(fail("a small index is sorted by (least time, chunk id)"));
                }
                entries.iter().try_for_each(check_bounds)
            }
            Self::Sequence(entries) => {
                if entries.len() <= SMALL_INDEX_MAX_CHUNKS / 2
                    || entries.len() > SEQUENCE_MAX_CHUNKS
                {
                    return Err(fail(
                        "a sequence holds more than SMALL_INDEX_MAX_CHUNKS / 2 chunks and at \
                         most SEQUENCE_MAX_CHUNKS",
                    )
                    .at(format_args!("{} chunks", entries.len())));
                }
                if !in_sequence(entries.iter()) {
                    return Err(fail("a sequence's chunks each end before the next starts"));
                }
                if !entries.keys_match_entries() {
                    return Err(fail("a sequence keeps each entry's least time beside it"));
                }
                entries.iter().try_for_each(check_bounds)
            }
            Self::Large(large) => {
                if large.len() <= SMALL_INDEX_MAX_CHUNKS / 2 {
                    return Err(fail(
                        "a large index holds more than SMALL_INDEX_MAX_CHUNKS / 2 chunks",
                    )
                    .at(format_args!("{} chunks", large.len())));
                }
                large.sanity_check()
            }
        }
    }
}

/// The position of the entry keyed `key` in a sequence (sorted by that key), or where it
/// would go.
/// Do the entry's bounds equal what its chunk computed?
fn check_bounds(entry: &IndexedChunk) -> Result<(), SanityError> {
    let IndexedChunk {
        chunk,
        chunk_id,
        time_column,
        component_column,
        bounds,
    } = entry;
    if *chunk_id != chunk.id() {
        return Err(
            SanityError::new(Structure::TemporalIndex, "an entry carries its chunk's id")
                .at(chunk.id()),
        );
    }
    let component = chunk.components().get(*component_column as usize);
    if component.and_then(|c| c.bounds(*time_column as usize)) == Some(*bounds) {
        Ok(())
    } else {
        Err(SanityError::new(
            Structure::TemporalIndex,
            "an entry has the bounds its chunk computed",
        )
        .at(chunk_id))
    }
}

fn max_index_key(entry: &IndexedChunk) -> MaxIndexKey {
    entry.bounds.max_index_key(entry.chunk_id)
}
