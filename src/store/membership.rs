//! The two primitives every mutation is made of: adding a validated chunk to every index,
//! order and figure, and taking one out of all of them, each recording its event. Whoever
//! decides what to add or remove (insertion, compaction, garbage collection, drops) calls
//! these and nothing lower.

use std::sync::Arc;

use super::{ChunkStore, DeletionReason, StoreEvent, StoredChunk};
use crate::clear::ClearIndex;
use crate::{Chunk, ChunkId};

impl ChunkStore {
    /// Adds a validated chunk to every index and figure, and records its addition (and
    /// any static chunk it overwrites).
    pub(crate) fn add_chunk(&mut self, chunk: Arc<Chunk>, events: &mut Vec<StoreEvent>) {
        self.add_chunk_to_orders(chunk, true, events);
    }

    /// [`ChunkStore::add_chunk`], leaving a temporal chunk out of the store-wide orders
    /// unless `in_global_orders`: for a chunk compaction keeps waiting, which must then
    /// either leave the store or be [settled](ChunkStore::settle_in_global_orders).
    pub(crate) fn add_chunk_to_orders(
        &mut self,
        chunk: Arc<Chunk>,
        in_global_orders: bool,
        events: &mut Vec<StoreEvent>,
    ) {
        let ledgered = !chunk.owns_all_buffers();
        let Some(mut entity) = super::entity_mut(
            &mut self.entities,
            &mut self.view.entities,
            chunk.entity_path(),
            true,
        ) else {
            return;
        };
        // An entity leaves the map with its last chunk, so one without chunks is new.
        let new_entity = entity.index.chunk_ids.is_empty();
        if new_entity {
            entity.view.stats.heap_bytes += crate::stats::ENTITY_BYTES;
        }
        entity.add_components(&chunk);
        entity.index.chunk_ids.insert(chunk.id());
        entity.index.max_row_id = entity.index.max_row_id.max(chunk.row_id_range().1);
        let mut store_stats = self.view.stats;
        if new_entity {
            store_stats.heap_bytes += crate::stats::ENTITY_BYTES;
        }
        crate::stats::account(
            &chunk,
            ledgered,
            true,
            &mut store_stats,
            &mut self.ledgers,
            &mut entity.view.stats,
            &mut entity.index.ledger,
        );
        events.push(StoreEvent::Addition(Arc::clone(&chunk)));
        if chunk.is_static() {
            let overwritten = entity.insert_static(&chunk);
            self.view.stats = store_stats;
            ClearIndex::insert_chunk(&mut self.view.clears, &chunk);
            let stored = StoredChunk {
                chunk,
                ledgered,
                in_global_orders: true,
                rewritten_by: None,
            };
            self.chunks.insert(stored.chunk.id(), stored);
            for overwritten in overwritten {
                // An overwritten static Clear keeps hiding what it hid: its index entry
                // stays, as SEMANTICS.md section 5 asks.
                if let Some(stored) = self.chunks.remove(&overwritten.id()) {
                    self.take_out(stored, false, DeletionReason::Overwrite, events);
                }
            }
        } else {
            let extra = entity.insert_temporal(&chunk);
            crate::stats::add_index_bytes(&mut store_stats, &mut entity.view.stats, extra);
            self.view.stats = store_stats;
            ClearIndex::insert_chunk(&mut self.view.clears, &chunk);
            if in_global_orders {
                self.insert_in_global_orders(&chunk);
            } else {
                self.num_outside_global_orders += 1;
            }
            let stored = StoredChunk {
                chunk,
                ledgered,
                in_global_orders,
                rewritten_by: None,
            };
            self.chunks.insert(stored.chunk.id(), stored);
        }
    }

    fn insert_in_global_orders(&mut self, chunk: &Chunk) {
        let id = chunk.id();
        self.temporal_by_row_id.insert((chunk.row_id_range().0, id));
        for column in chunk.time_columns() {
            let (min, max) = column.time_range();
            let per_timeline = self
                .temporal_per_timeline
                .entry(Arc::clone(column.timeline().name_arc()))
                .or_default();
            per_timeline.by_min_time.insert((min, id));
            per_timeline.by_max_time.insert((max, id));
        }
    }

    /// Puts a temporal chunk left out of the store-wide orders into them (a chunk
    /// compaction stopped waiting for).
    pub(crate) fn settle_in_global_orders(&mut self, id: ChunkId) {
        let Some(stored) = self.chunks.get_mut(&id) else {
            return;
        };
        if stored.in_global_orders || stored.chunk.is_static() {
            return;
        }
        stored.in_global_orders = true;
        let chunk = Arc::clone(&stored.chunk);
        self.num_outside_global_orders -= 1;
        self.insert_in_global_orders(&chunk);
    }

    /// The temporal chunks outside the store-wide orders: some of the chunks compaction
    /// keeps waiting. O(entities) when there are any, O(1) when none.
    pub(crate) fn chunks_outside_global_orders(&self) -> Vec<&Arc<Chunk>> {
        if self.num_outside_global_orders == 0 {
            return Vec::new();
        }
        self.entities
            .values()
            .flat_map(|entity| entity.pending.chunks())
            .filter(|chunk| {
                self.chunks
                    .get(&chunk.id())
                    .is_some_and(|stored| !stored.in_global_orders)
            })
            .collect()
    }

    /// Removes a chunk from every index and figure and records its deletion; returns the
    /// chunk, or `None` if the store does not hold it.
    pub(crate) fn remove_chunk(
        &mut self,
        id: ChunkId,
        reason: DeletionReason,
        events: &mut Vec<StoreEvent>,
    ) -> Option<Arc<Chunk>> {
        let stored = self.chunks.remove(&id)?;
        Some(self.take_out(stored, true, reason, events))
    }

    /// Takes a chunk already out of the chunk map out of everything else: with `unindex`,
    /// its indices and orders; always its entity's chunk set, the figures (and the entity
    /// itself if it is left empty), and records the deletion event. One lookup of the
    /// entity serves all of it.
    pub(crate) fn take_out(
        &mut self,
        stored: StoredChunk,
        unindex: bool,
        reason: DeletionReason,
        events: &mut Vec<StoreEvent>,
    ) -> Arc<Chunk> {
        let StoredChunk {
            chunk,
            ledgered,
            in_global_orders,
            rewritten_by: _,
        } = stored;
        let id = chunk.id();
        if unindex && !chunk.is_static() {
            ClearIndex::remove_chunk(&mut self.view.clears, &chunk);
            if in_global_orders {
                self.remove_from_global_orders(&chunk);
            } else {
                self.num_outside_global_orders -= 1;
            }
        }
        let config = self.config;
        let mut store_stats = self.view.stats;
        if let Some(mut entity) = super::entity_mut(
            &mut self.entities,
            &mut self.view.entities,
            chunk.entity_path(),
            false,
        ) {
            if unindex {
                if chunk.is_static() {
                    entity.remove_static(id);
                } else {
                    let extra = entity.remove_temporal(&chunk, &config);
                    crate::stats::add_index_bytes(&mut store_stats, &mut entity.view.stats, extra);
                }
            }
            entity.index.chunk_ids.remove(&id);
            entity.remove_components(&chunk);
            crate::stats::account(
                &chunk,
                ledgered,
                false,
                &mut store_stats,
                &mut self.ledgers,
                &mut entity.view.stats,
                &mut entity.index.ledger,
            );
            if entity.index.chunk_ids.is_empty() {
                // Nothing left: the entity is forgotten, as if never inserted (its
                // component types included).
                self.forget_entity(chunk.entity_path());
                store_stats.heap_bytes = store_stats
                    .heap_bytes
                    .saturating_sub(crate::stats::ENTITY_BYTES);
            }
        }
        self.view.stats = store_stats;
        events.push(StoreEvent::Deletion {
            chunk: Arc::clone(&chunk),
            reason,
        });
        chunk
    }

    fn remove_from_global_orders(&mut self, chunk: &Chunk) {
        let id = chunk.id();
        self.temporal_by_row_id
            .remove(&(chunk.row_id_range().0, id));
        for column in chunk.time_columns() {
            let (min, max) = column.time_range();
            let name = column.timeline().name();
            if let Some(per_timeline) = self.temporal_per_timeline.get_mut(name) {
                per_timeline.by_min_time.remove(&(min, id));
                per_timeline.by_max_time.remove(&(max, id));
                if per_timeline.by_min_time.is_empty() {
                    self.temporal_per_timeline.remove(name);
                }
            }
        }
    }
}
