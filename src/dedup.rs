//! Idempotent ingest (SEMANTICS.md section 6): which rows of an incoming chunk the store
//! already holds.
//!
//! A row is held when a chunk of the same entity and layout holds a row with the same row
//! id, the same time on every timeline and the same cell in every component: whether the
//! chunk is the row's own, a compacted chunk that absorbed it, a piece of a split, or the
//! rest of a range drop. The store inserts only the rows it does not hold, so a chunk
//! inserted twice, a file loaded twice, or a recording loaded beside a re-chunked copy of
//! itself changes nothing the second time, with compaction on or off.
//!
//! Nothing is remembered for this beyond one row id per entity: the rows themselves are
//! the record. (Remembering the id of every chunk compaction absorbed would cost 16 bytes
//! a row on a stream of single-row chunks, as much as the row's own data.) Most chunks
//! carry row ids beyond any their entity held, which one comparison shows; the others are
//! looked up row by row through the entity's temporal indices.

use std::sync::Arc;

use crate::index::IndexedChunk;
use crate::store::{EntityIndex, EntityView};
use crate::{Chunk, ChunkId, ChunkStore};

/// What an incoming chunk adds to the store.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum NewRows {
    /// Every row: the chunk goes in as it is.
    All,
    /// None: the store holds every row already.
    None,
    /// Only these rows (ascending); the others are held.
    Some(Vec<usize>),
}

impl ChunkStore {
    /// Which rows of `chunk` (a chunk whose id the store does not hold) are new.
    ///
    /// The store asks only when the chunk has a row id within its entity's
    /// ([`EntityIndex::max_row_id`]): rows logged after everything the entity holds, the
    /// common case, are new.
    pub(crate) fn new_rows(&self, chunk: &Chunk) -> NewRows {
        let Some((entity, view)) = self.entity(chunk.entity_path()) else {
            return NewRows::All;
        };
        let candidates = self.chunks_that_may_hold_rows_of(entity, view, chunk);
        if candidates.is_empty() {
            return NewRows::All;
        }
        let new: Vec<usize> = (0..chunk.num_rows())
            .filter(|&row| !candidates.iter().any(|held| held.holds_row_of(chunk, row)))
            .collect();
        if new.is_empty() {
            NewRows::None
        } else if new.len() == chunk.num_rows() {
            NewRows::All
        } else {
            NewRows::Some(new)
        }
    }

    /// The entity's chunks of `chunk`'s layout that could hold one of its rows: those
    /// overlapping it in time on its first timeline (found through the index of each of
    /// its components), or every static chunk of the layout for a static chunk.
    fn chunks_that_may_hold_rows_of<'a>(
        &'a self,
        entity: &'a EntityIndex,
        view: &'a EntityView,
        chunk: &Chunk,
    ) -> Vec<&'a Arc<Chunk>> {
        let mut candidates: Vec<&'a Arc<Chunk>> = Vec::new();
        let mut seen: ahash::HashSet<ChunkId> = ahash::HashSet::default();
        let mut consider = |held: &'a Arc<Chunk>| {
            if seen.insert(held.id()) && held.has_same_layout(chunk) {
                candidates.push(held);
            }
        };
        let Some(first) = chunk.time_columns().first() else {
            entity
                .static_chunks
                .values()
                .for_each(|(held, _)| consider(held));
            return candidates;
        };
        if chunk.has_rows_without_cells() {
            // A row without cells is in no index: only a scan finds where it is held.
            let bounds = first.time_range();
            let (min, max) = (bounds.min(), bounds.max());
            for held in entity.held_chunks(view, &self.chunks) {
                let overlaps = held.time_columns().first().is_some_and(|held| {
                    let bounds = held.time_range();
                    let (lo, hi) = (bounds.min(), bounds.max());
                    lo <= max && min <= hi
                });
                if overlaps {
                    consider(held);
                }
            }
            return candidates;
        }
        // The write buffer's few chunks are in no index: each is a candidate.
        view.buffered.chunks().for_each(&mut consider);
        let Some(per_component) = view
            .temporal_per_timeline_per_component
            .get(first.timeline().name())
        else {
            return candidates;
        };
        // A held row equal to one of the chunk's has its non-null cells: the holding chunk
        // is indexed under that component, with bounds reaching the row's time.
        for column in chunk.components() {
            let (Some(bounds), Some(index)) = (column.bounds(0), per_component.get(column.name()))
            else {
                continue;
            };
            let mut visit = |entry: &'a IndexedChunk| consider(&entry.chunk);
            index.for_each_reaching_into(bounds.min_time, &mut visit);
            index.for_each_starting_in(bounds.min_time, bounds.max_time, &mut visit);
        }
        candidates
    }
}
