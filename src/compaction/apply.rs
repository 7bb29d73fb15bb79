//! Carrying out a [`CompactionPlan`]: each group's rows rewritten, the group removed, the
//! pieces added and marked as one rewrite.

use std::sync::Arc;

use super::plan::{CompactionGroup, CompactionPlan};
use crate::store::{DeletionReason, RewriteMark};
use crate::{Chunk, ChunkStore, StoreEvent};

impl ChunkStore {
    /// Rewrites the store's temporal chunks into chunks near the thresholds: per entity
    /// and layout, every set of chunks that is not already compact (time-sorted and
    /// non-overlapping on the first timeline, each within the thresholds, no two
    /// neighbours that would fit in one chunk; nor exactly what an earlier call made of
    /// it) is merged, sorted and cut again into as few chunks as the thresholds allow.
    /// For a store filled with compaction off, or fragmented by garbage collection.
    /// Returns the deletions (reason [`DeletionReason::Compaction`]) and additions; no
    /// query answer changes, and a second call in a row changes nothing.
    ///
    /// The same as [`ChunkStore::plan_compaction`] then [`ChunkStore::apply_compaction`].
    pub fn compact(&mut self) -> Vec<StoreEvent> {
        let plan = self.plan_compaction();
        self.apply_compaction(&plan)
    }

    /// Compacts as [`ChunkStore::compact`] does, but one group at a time: each group's
    /// events go to `on_group` (and to subscribers) as soon as that group is rewritten,
    /// instead of all of them being returned at the end. A deletion event holds its
    /// chunk, so `compact()`'s events hold every replaced chunk until they are dropped:
    /// the old and the new copy of everything it rewrote at once. Here, a caller that
    /// drops each group's events (as `|_| {}` does) holds the store and one group's
    /// rewrite at most. The whole call is one mutation, as `compact()` is (see
    /// [`crate::Snapshot::version`]).
    ///
    /// ```
    /// # use chunkstore::ChunkStore;
    /// let mut store = ChunkStore::new();
    /// let mut rewritten = 0;
    /// store.compact_group_by_group(|events| rewritten += events.len());
    /// assert_eq!(rewritten, 0); // an empty store has nothing to compact
    /// ```
    pub fn compact_group_by_group(&mut self, mut on_group: impl FnMut(Vec<StoreEvent>)) {
        let plan = self.plan_compaction();
        let set_aside = self.sets_global_orders_aside(&plan);
        for group in &plan.groups {
            let mut events = Vec::new();
            if let Some(chunks) = self.planned_chunks(group) {
                self.rewrite_group(&chunks, &mut events);
            }
            self.announce(&events);
            on_group(events);
        }
        if set_aside {
            self.restore_global_orders();
        }
        // One mutation, as `compact()` is (a snapshot's version counts it once), checked
        // once on the debug schedule; its events are all announced already.
        self.finish_mutation(Vec::new());
    }

    /// Rewrites the groups of `plan`. A group the store no longer holds exactly as
    /// planned (one of its chunks left, or they are not all temporal chunks of its entity
    /// and one layout: a plan made before other changes, or by hand) is skipped whole, so
    /// applying any plan keeps every query's answer.
    pub fn apply_compaction(&mut self, plan: &CompactionPlan) -> Vec<StoreEvent> {
        let set_aside = self.sets_global_orders_aside(plan);
        let mut events = Vec::new();
        for group in &plan.groups {
            if let Some(chunks) = self.planned_chunks(group) {
                self.rewrite_group(&chunks, &mut events);
            }
        }
        if set_aside {
            self.restore_global_orders();
        }
        self.finish_mutation(events)
    }

    /// Sets the store-wide orders aside for `plan` if it rewrites at least a quarter of
    /// the store's chunks: then one rebuild of the orders at the end (a pass over the
    /// chunk map and a sort per order) costs less than taking every rewritten chunk out
    /// of three B-trees and putting each piece into them (the B-trees' searches miss the
    /// cache at every level). Returns whether it did.
    fn sets_global_orders_aside(&mut self, plan: &CompactionPlan) -> bool {
        let rewritten: usize = plan.groups.iter().map(|g| g.chunk_ids.len()).sum();
        // No minimum size: small stores (the model test's) take this path too.
        let set_aside = rewritten > 0 && rewritten.saturating_mul(4) >= self.chunks.len();
        if set_aside {
            self.set_global_orders_aside();
        }
        set_aside
    }

    /// The chunks of `group`, if the store holds them all and they can be rewritten
    /// together.
    fn planned_chunks(&self, group: &CompactionGroup) -> Option<Vec<Arc<Chunk>>> {
        let chunks: Vec<Arc<Chunk>> = group
            .chunk_ids
            .iter()
            .map(|id| self.chunk(*id).cloned())
            .collect::<Option<_>>()?;
        let first = chunks.first()?;
        let fits = chunks.iter().all(|c| {
            !c.is_static() && c.entity_path() == &group.entity_path && c.has_same_layout(first)
        });
        let distinct = {
            let mut ids: Vec<_> = group.chunk_ids.clone();
            ids.sort_unstable();
            ids.windows(2).all(|w| w[0] != w[1])
        };
        (fits && distinct).then_some(chunks)
    }

    /// Rewrites one group (chunks of one entity and layout held by the store).
    fn rewrite_group(&mut self, chunks: &[Arc<Chunk>], events: &mut Vec<StoreEvent>) {
        let config = self.config;
        let Some(pieces) = self.rewrite_held(chunks, "rewriting a compaction group") else {
            return; // the group stays as it is
        };
        // Removed first, as in `merge_cascade`: the pieces cover the same times. One
        // lookup of the entity for all of them.
        let stored = chunks
            .iter()
            .filter_map(|chunk| self.chunks.remove(&chunk.id()))
            .collect();
        self.take_out_all(stored, DeletionReason::Compaction, events);
        let mark = RewriteMark {
            rewrite: self.num_rewrites,
            num_pieces: pieces.len(),
        };
        self.num_rewrites += 1;
        let mut small = Vec::new();
        for piece in pieces {
            let piece = Arc::new(piece);
            if mark.num_pieces == 1 && config.can_grow(&piece) {
                small.push(Arc::clone(&piece));
            }
            let id = piece.id();
            self.add_chunk(piece, events);
            if let Some(stored) = self.chunks.get_mut(&id) {
                stored.rewritten_by = Some(mark);
            }
        }
        // A lone small result may keep growing with later inserts, from the second level
        // (the first is the write buffer, which holds only chunks that arrive).
        if config.compact_on_insert {
            for chunk in small {
                if config.level(chunk.num_rows()) > 0 {
                    self.merge_cascade(chunk, events);
                }
            }
        }
    }
}
