//! The two primitives every mutation is made of: adding a validated chunk to every index,
//! order and figure, and taking one out of all of them, each recording its event. Whoever
//! decides what to add or remove (insertion, compaction, garbage collection, drops) calls
//! these and nothing lower.

use std::sync::Arc;

use smallvec::SmallVec;

use super::{ChunkStore, DeletionReason, StoreEvent, StoredChunk};
use crate::clear::ClearIndex;
use crate::small_map::SmallMap;
use crate::{Chunk, ChunkId, EntityPath};

impl ChunkStore {
    /// Adds a validated chunk to every index and figure, and records its addition (and
    /// any static chunk it overwrites).
    pub(crate) fn add_chunk(&mut self, chunk: Arc<Chunk>, events: &mut Vec<StoreEvent>) {
        self.add_chunk_to_orders(chunk, Joining::Settled, events);
    }

    /// [`ChunkStore::add_chunk`], where `joining` says which of the store-wide orders and
    /// indices a temporal chunk joins: a chunk compaction keeps waiting stays out of the
    /// orders (it must then either leave the store or be
    /// [settled](ChunkStore::settle_in_global_orders)). Not for a buffered chunk: see
    /// [`ChunkStore::buffer_chunk`].
    pub(crate) fn add_chunk_to_orders(
        &mut self,
        chunk: Arc<Chunk>,
        joining: Joining,
        events: &mut Vec<StoreEvent>,
    ) {
        debug_assert!(joining != Joining::Buffered, "buffer_chunk buffers");
        let fan = self.join(chunk, joining, events);
        debug_assert!(fan.is_none(), "only a buffered chunk completes a fan");
    }

    /// Adds a small temporal chunk to its entity's write buffer (out of the store-wide
    /// orders and the indices). If it completes a full fan of its buffer's group, returns
    /// the fan (itself included), out of the buffer, for compaction to merge at once.
    #[must_use = "a full fan of the write buffer must be merged"]
    pub(crate) fn buffer_chunk(
        &mut self,
        chunk: Arc<Chunk>,
        events: &mut Vec<StoreEvent>,
    ) -> Option<super::Fan> {
        self.join(chunk, Joining::Buffered, events)
    }

    /// What [`ChunkStore::add_chunk_to_orders`] and [`ChunkStore::buffer_chunk`] share:
    /// the chunk joins what `joining` says; a buffered chunk's full fan is returned.
    fn join(
        &mut self,
        chunk: Arc<Chunk>,
        joining: Joining,
        events: &mut Vec<StoreEvent>,
    ) -> Option<super::Fan> {
        let in_global_orders = joining == Joining::Settled;
        let ledgered = !chunk.owns_all_buffers();
        let mut entity = super::entity_mut(
            &mut self.entities,
            &mut self.view.entities,
            chunk.entity_path(),
            true,
        )?;
        // An entity leaves the map with its last chunk, so one without chunks is new.
        let new_entity = entity.holds_no_chunks();
        if new_entity {
            entity.view.stats.heap_bytes += crate::stats::ENTITY_BYTES;
        }
        if joining != Joining::Buffered {
            entity.add_components(&chunk);
            entity.index.chunk_ids.insert(chunk.id());
        }
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
        let mut full_fan = None;
        if chunk.is_static() {
            let overwritten = entity.insert_static(&chunk);
            self.view.stats = store_stats;
            ClearIndex::insert_chunk(&mut self.view.clears, &chunk);
            let stored = StoredChunk {
                chunk,
                ledgered,
                in_global_orders: true,
                buffered: false,
                rewritten_by: None,
            };
            self.chunks.insert(stored.chunk.id(), stored);
            for overwritten in overwritten {
                // An overwritten static Clear keeps hiding what it hid: its index entry
                // stays, as SEMANTICS.md section 5 asks.
                if let Some(stored) = self.chunks.remove(&overwritten.id()) {
                    self.take_out(
                        stored,
                        Holding::FiguresOnly,
                        DeletionReason::Overwrite,
                        events,
                    );
                }
            }
        } else {
            let buffered = joining == Joining::Buffered;
            let extra = if buffered {
                let pushed = entity.view.buffered.push(&chunk, self.config.merge_fanout);
                // A group counts once among the components (`ComponentType::num_chunks`).
                if matches!(pushed, super::buffer::Pushed::Opened) {
                    entity.add_components(&chunk);
                }
                full_fan =
                    entity
                        .index
                        .buffer_columns
                        .follow(&entity.view.buffered, pushed, &chunk);
                0
            } else {
                entity.insert_temporal(&chunk)
            };
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
                buffered,
                rewritten_by: None,
            };
            self.chunks.insert(stored.chunk.id(), stored);
        }
        full_fan
    }

    fn insert_in_global_orders(&mut self, chunk: &Chunk) {
        if self.global_orders_set_aside {
            return; // the chunk's mark is what `restore_global_orders` reads
        }
        self.temporal_by_row_id
            .insert(super::row_id_order_key(chunk));
        for (name, by_min, by_max) in super::time_order_keys(chunk) {
            let per_timeline = self.temporal_per_timeline.get_or_default(Arc::clone(name));
            per_timeline.by_min_time.insert(by_min);
            per_timeline.by_max_time.insert(by_max);
        }
    }

    /// Empties the store-wide orders and stops keeping them, for a mutation that moves so
    /// many chunks that sorting the survivors again costs less than moving each through
    /// the orders (an on-demand compaction that rewrites much of the store: a removal and
    /// an insertion in each of three B-trees per piece were a third of it; a removal that
    /// leaves few chunks, see [`ChunkStore::take_out_all`]).
    /// Chunks keep their [`StoredChunk::in_global_orders`] marks meanwhile; nothing may
    /// read the orders until [`ChunkStore::restore_global_orders`], which the mutation
    /// calls before it ends.
    pub(crate) fn set_global_orders_aside(&mut self) {
        self.temporal_by_row_id = crate::ordered::OrderedSet::default();
        self.temporal_per_timeline = SmallMap::default();
        self.global_orders_set_aside = true;
    }

    /// Makes the store-wide orders again from the marks of the chunks the store holds, if
    /// they were [set aside](ChunkStore::set_global_orders_aside): one pass over the chunk
    /// map and one sort per order.
    pub(crate) fn restore_global_orders(&mut self) {
        type Keys = Vec<(crate::TimeInt, ChunkId)>;
        if !std::mem::take(&mut self.global_orders_set_aside) {
            return;
        }
        let mut by_row_id = Vec::with_capacity(self.chunks.len());
        let mut per_timeline: SmallMap<Arc<str>, (Keys, Keys)> = SmallMap::default();
        for stored in self.chunks.values() {
            let chunk = &stored.chunk;
            if !stored.in_global_orders || chunk.is_static() {
                continue;
            }
            by_row_id.push(super::row_id_order_key(chunk));
            for (name, min_key, max_key) in super::time_order_keys(chunk) {
                let (by_min, by_max) = per_timeline.get_or_default(Arc::clone(name));
                by_min.push(min_key);
                by_max.push(max_key);
            }
        }
        self.temporal_by_row_id = crate::ordered::OrderedSet::from_keys(by_row_id);
        let mut orders = SmallMap::default();
        for (name, (by_min, by_max)) in per_timeline.into_entries() {
            orders.insert(
                name,
                super::TimelineChunks {
                    by_min_time: crate::ordered::OrderedSet::from_keys(by_min),
                    by_max_time: crate::ordered::OrderedSet::from_keys(by_max),
                },
            );
        }
        self.temporal_per_timeline = orders;
    }

    /// Puts a temporal chunk left out of the store-wide orders into them (a chunk
    /// compaction stopped waiting for; one out of a write buffer's fan into its indices
    /// too).
    pub(crate) fn settle_in_global_orders(&mut self, id: ChunkId) {
        let Some(stored) = self.chunks.get_mut(&id) else {
            return;
        };
        if stored.in_global_orders || stored.chunk.is_static() {
            return;
        }
        stored.in_global_orders = true;
        let was_buffered = std::mem::take(&mut stored.buffered);
        let chunk = Arc::clone(&stored.chunk);
        self.num_outside_global_orders -= 1;
        self.insert_in_global_orders(&chunk);
        // A chunk of a fan its write buffer gave up is in no index yet.
        if was_buffered
            && let Some(mut entity) = super::entity_mut(
                &mut self.entities,
                &mut self.view.entities,
                chunk.entity_path(),
                false,
            )
        {
            entity.add_components(&chunk);
            entity.index.chunk_ids.insert(chunk.id());
            let extra = entity.insert_temporal(&chunk);
            crate::stats::add_index_bytes(&mut self.view.stats, &mut entity.view.stats, extra);
        }
    }

    /// Settles every chunk of a full fan whose merge failed
    /// ([`ChunkStore::settle_in_global_orders`]). A write buffer's fan was one group,
    /// counted once among its entity's components, and is now that many settled chunks,
    /// each counted.
    pub(crate) fn settle_fan(&mut self, fan: &[Arc<Chunk>]) {
        let Some(first) = fan.first() else {
            return;
        };
        let was_buffered = self.chunks.get(&first.id()).is_some_and(|s| s.buffered);
        for chunk in fan {
            self.settle_in_global_orders(chunk.id());
        }
        if was_buffered
            && let Some(mut entity) = super::entity_mut(
                &mut self.entities,
                &mut self.view.entities,
                first.entity_path(),
                false,
            )
        {
            entity.remove_components(first);
        }
    }

    /// The temporal chunks outside the store-wide orders: some of the chunks compaction
    /// keeps waiting. O(entities) when there are any, O(1) when none.
    pub(crate) fn chunks_outside_global_orders(&self) -> Vec<&Arc<Chunk>> {
        if self.num_outside_global_orders == 0 {
            return Vec::new();
        }
        self.entities
            .values()
            .flat_map(|entity| self.waiting_chunks(entity))
            .filter(|chunk| {
                self.chunks
                    .get(&chunk.id())
                    .is_some_and(|stored| !stored.in_global_orders)
            })
            .collect()
    }

    /// The chunks compaction on insert keeps waiting at `entity`: in its compaction groups
    /// and in its write buffer.
    pub(super) fn waiting_chunks<'a>(
        &'a self,
        entity: &'a super::entity::EntityIndex,
    ) -> impl Iterator<Item = &'a Arc<Chunk>> + 'a {
        let view = self.view.entities.at(entity.slot).into_iter();
        entity
            .pending
            .chunks()
            .chain(view.flat_map(|view| view.buffered.chunks()))
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
        Some(self.take_out(stored, Holding::Everywhere, reason, events))
    }

    /// Removes the chunks compaction on insert just merged (a fan of waiting chunks or a
    /// cluster of a tier's runs, all of one entity, already out of its compaction
    /// groups): [`ChunkStore::remove_chunk`] for each, with one lookup of the entity for
    /// all of them and no search of the groups that no longer hold them.
    pub(crate) fn remove_merged(&mut self, merged: &[Arc<Chunk>], events: &mut Vec<StoreEvent>) {
        let Some(path) = merged.first().map(|chunk| chunk.entity_path().clone()) else {
            return;
        };
        debug_assert!(merged.iter().all(|chunk| *chunk.entity_path() == path));
        let mut stored = SmallVec::with_capacity(merged.len());
        stored.extend(
            merged
                .iter()
                .filter_map(|chunk| self.chunks.remove(&chunk.id())),
        );
        self.take_out_of_entity(
            &path,
            stored,
            Holding::TakenByCompaction,
            DeletionReason::Compaction,
            events,
        );
    }

    /// Removes the chunks of `stored` (already out of the chunk map, still everywhere
    /// else: [`Holding::Everywhere`]) for `reason`, one lookup of each entity for all of
    /// its chunks, and records the deletions in the order given: what a removal one
    /// chunk at a time records, for the cost of grouping.
    pub(crate) fn take_out_all(
        &mut self,
        stored: Vec<StoredChunk>,
        reason: DeletionReason,
        events: &mut Vec<StoreEvent>,
    ) {
        // Each chunk's position in `stored`, grouped by entity (first appearance first).
        let mut groups: ahash::HashMap<EntityPath, Vec<usize>> = ahash::HashMap::default();
        let mut paths: Vec<EntityPath> = Vec::new();
        for (position, chunk) in stored.iter().enumerate() {
            let path = chunk.chunk.entity_path();
            if let Some(positions) = groups.get_mut(path) {
                positions.push(position);
            } else {
                groups.insert(path.clone(), vec![position]);
                paths.push(path.clone());
            }
        }
        // Where few chunks stay (a collection of everything, the drop of an entity that
        // was most of the store), the store-wide orders are made again from the survivors
        // rather than every chunk taken out of them: a rebuild costs about 1.8 k
        // instructions a chunk kept, taking one out 0.3 k (deques, from their front) to
        // 1.6 k (B-trees). (Not inside a mutation that set them aside already.)
        let rebuild = !self.global_orders_set_aside
            && !stored.is_empty()
            && self.chunks.len().saturating_mul(8) <= stored.len();
        if rebuild {
            self.set_global_orders_aside();
        }
        // The store-wide orders first, in the order given: they are deques that chunks
        // leave from an end in that order (oldest first), where an entity at a time would
        // take them from the middle.
        for chunk in stored.iter().filter(|stored| !stored.chunk.is_static()) {
            leave_global_orders(
                &mut self.temporal_by_row_id,
                &mut self.temporal_per_timeline,
                &mut self.num_outside_global_orders,
                self.global_orders_set_aside,
                chunk,
            );
        }
        if rebuild {
            self.restore_global_orders();
        }
        let mut slots: Vec<Option<StoredChunk>> = stored.into_iter().map(Some).collect();
        let mut recorded: Vec<Option<StoreEvent>> = Vec::new();
        recorded.resize_with(slots.len(), || None);
        let mut group_events = Vec::new();
        for path in paths {
            let positions = groups.remove(&path).unwrap_or_default();
            let mut chunks = SmallVec::with_capacity(positions.len());
            chunks.extend(positions.iter().filter_map(|&p| slots[p].take()));
            self.take_out_of_entity(
                &path,
                chunks,
                Holding::OutOfGlobalOrders,
                reason,
                &mut group_events,
            );
            // One deletion per chunk, in the order the chunks were given.
            debug_assert_eq!(group_events.len(), positions.len());
            for (&position, event) in positions.iter().zip(group_events.drain(..)) {
                recorded[position] = Some(event);
            }
        }
        events.extend(recorded.into_iter().flatten());
    }

    /// Takes a chunk already out of the chunk map out of everything else `holding` says
    /// holds it: see [`ChunkStore::take_out_of_entity`].
    pub(crate) fn take_out(
        &mut self,
        stored: StoredChunk,
        holding: Holding,
        reason: DeletionReason,
        events: &mut Vec<StoreEvent>,
    ) -> Arc<Chunk> {
        let chunk = Arc::clone(&stored.chunk);
        let path = chunk.entity_path().clone();
        self.take_out_of_entity(&path, smallvec::smallvec![stored], holding, reason, events);
        chunk
    }

    /// Takes chunks of the entity at `path`, already out of the chunk map, out of what
    /// `holding` says still holds them (indices, orders, compaction groups); always out of
    /// the entity's chunk set and the figures (the entity itself goes if left empty), and
    /// records each deletion. One lookup of the entity serves them all.
    fn take_out_of_entity(
        &mut self,
        path: &EntityPath,
        stored: SmallVec<[StoredChunk; 1]>,
        holding: Holding,
        reason: DeletionReason,
        events: &mut Vec<StoreEvent>,
    ) {
        let config = self.config;
        let mut store_stats = self.view.stats;
        let mut entity =
            super::entity_mut(&mut self.entities, &mut self.view.entities, path, false);
        let unindex = holding != Holding::FiguresOnly;
        let still_grouped = matches!(holding, Holding::Everywhere | Holding::OutOfGlobalOrders);
        let in_orders = holding != Holding::OutOfGlobalOrders;
        // Buffered chunks first: out of the write buffer (unless compaction took them out
        // as a full fan), and in nothing else an entity holds.
        let mut num_buffered = 0;
        if unindex && let Some(entity) = entity.as_mut() {
            let mut buffered = stored.iter().filter(|stored| stored.buffered);
            for stored in buffered.clone() {
                entity.unbuffer(&stored.chunk, still_grouped);
                num_buffered += 1;
            }
            // Chunks compaction took out of the buffer are one full fan: one group, which
            // counted once among the components.
            if !still_grouped && let Some(first) = buffered.next() {
                debug_assert!(buffered.all(|s| s.chunk.has_same_layout(&first.chunk)));
                entity.remove_components(&first.chunk);
            }
        }
        // The indices and compaction groups all at once where a rewrite or a collection
        // takes many chunks of the entity out together; one at a time below.
        let together =
            unindex && stored.len() - num_buffered >= super::entity::BULK_REMOVAL_MIN_CHUNKS;
        if together && let Some(entity) = entity.as_mut() {
            let mut temporal: Vec<&Chunk> = Vec::with_capacity(stored.len());
            temporal.extend(
                stored
                    .iter()
                    .filter(|stored| !stored.buffered)
                    .map(|stored| &*stored.chunk)
                    .filter(|chunk| !chunk.is_static()),
            );
            let extra = entity.remove_temporal_many(&temporal, still_grouped);
            crate::stats::add_index_bytes(&mut store_stats, &mut entity.view.stats, extra);
        }
        // The figures once for all the chunks (a merge's fan is sixteen).
        let mut figures = crate::stats::FigureChange::default();
        for stored in stored {
            if unindex && !stored.chunk.is_static() {
                ClearIndex::remove_chunk(&mut self.view.clears, &stored.chunk);
                if in_orders {
                    leave_global_orders(
                        &mut self.temporal_by_row_id,
                        &mut self.temporal_per_timeline,
                        &mut self.num_outside_global_orders,
                        self.global_orders_set_aside,
                        &stored,
                    );
                }
            }
            let StoredChunk {
                chunk,
                ledgered,
                buffered,
                ..
            } = stored;
            let id = chunk.id();
            if let Some(entity) = entity.as_mut() {
                if unindex && chunk.is_static() {
                    entity.remove_static(id);
                } else if unindex && !together && !buffered {
                    let extra = entity.remove_temporal(&chunk, &config, still_grouped);
                    crate::stats::add_index_bytes(&mut store_stats, &mut entity.view.stats, extra);
                }
                if !buffered {
                    entity.index.chunk_ids.remove(&id);
                    entity.remove_components(&chunk);
                }
                figures.count(
                    &chunk,
                    ledgered,
                    false,
                    &mut self.ledgers,
                    &mut entity.index.ledger,
                );
            }
            events.push(StoreEvent::Deletion { chunk, reason });
        }
        if let Some(entity) = entity.as_mut() {
            figures.apply(false, &mut store_stats, &mut entity.view.stats);
            entity.view.buffered.refresh();
        }
        // Nothing left: the entity is forgotten, as if never inserted (its component types
        // included).
        let emptied = entity.is_some_and(|entity| entity.holds_no_chunks());
        if emptied {
            self.forget_entity(path);
            store_stats.heap_bytes = store_stats
                .heap_bytes
                .saturating_sub(crate::stats::ENTITY_BYTES);
        }
        self.view.stats = store_stats;
    }
}

/// Which of the store's orders and indices a temporal chunk joins on addition.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Joining {
    /// The store-wide orders and the indices: a chunk that stays.
    Settled,
    /// The indices only: a chunk compaction on insert keeps waiting for a fan to merge.
    Waiting,
    /// Neither: a chunk of the write buffer ([`EntityView::buffered`](super::EntityView)),
    /// which queries scan.
    Buffered,
}

/// Where a chunk leaving the store is still held, besides the chunk map.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Holding {
    /// In its indices and orders, and in its entity's compaction groups if compaction
    /// keeps it waiting or in a run.
    Everywhere,
    /// In its indices and orders: compaction on insert took it out of the groups (a fan or
    /// a tier it merges).
    TakenByCompaction,
    /// Only in its entity's chunk set and figures: an overwritten static chunk, whose
    /// Clears stay in the Clear index (SEMANTICS.md section 5).
    FiguresOnly,
    /// Everywhere but the store-wide orders, which [`ChunkStore::take_out_all`] leaves
    /// first, in the order the chunks go (the orders' outside count included).
    OutOfGlobalOrders,
}

/// Takes a temporal chunk out of the store-wide orders (unless they are
/// [set aside](ChunkStore::set_global_orders_aside)), or, if compaction kept it out of
/// them, out of the count of those outside.
fn leave_global_orders(
    by_row_id: &mut crate::ordered::OrderedSet<(crate::RowId, ChunkId)>,
    per_timeline: &mut SmallMap<Arc<str>, super::TimelineChunks>,
    num_outside: &mut usize,
    set_aside: bool,
    stored: &StoredChunk,
) {
    if stored.in_global_orders {
        if !set_aside {
            remove_from_global_orders(by_row_id, per_timeline, &stored.chunk);
        }
    } else {
        *num_outside -= 1;
    }
}

fn remove_from_global_orders(
    by_row_id: &mut crate::ordered::OrderedSet<(crate::RowId, ChunkId)>,
    per_timeline: &mut SmallMap<Arc<str>, super::TimelineChunks>,
    chunk: &Chunk,
) {
    by_row_id.remove(&super::row_id_order_key(chunk));
    for (name, by_min, by_max) in super::time_order_keys(chunk) {
        if let Some(chunks) = per_timeline.get_mut(name) {
            chunks.by_min_time.remove(&by_min);
            chunks.by_max_time.remove(&by_max);
            if chunks.by_min_time.is_empty() {
                per_timeline.remove(name);
            }
        }
    }
}
