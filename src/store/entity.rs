//! [`EntityIndex`]: everything the store knows about one entity (its static winners, its
//! per-timeline, per-component temporal indices, its component types, the chunks
//! compaction keeps waiting, and its figures). It owns the invariant that each of its
//! indices holds exactly the entity's chunks with cells there.

use std::collections::BTreeMap;
use std::sync::Arc;

use arrow_schema::DataType;

use super::pending::PendingGroups;
use crate::index::{
    IndexedChunk, LARGE_INDEX_BYTES_PER_ENTRY, SMALL_INDEX_BYTES_PER_ENTRY, TemporalComponentIndex,
};
use crate::small_map::SmallMap;
use crate::stats::{BufferLedger, EntityStats};
use crate::{Chunk, ChunkId, ComponentName, RowId};

/// The static cell that currently answers for one (entity, component).
#[derive(Clone, Debug)]
pub(crate) struct StaticWinner {
    pub row_id: RowId,
    pub chunk: Arc<Chunk>,
    pub component_column: u32,
    pub row: u32,
}

/// Everything the store knows about one entity.
#[derive(Clone, Debug, Default)]
pub(crate) struct EntityIndex {
    /// Each component the entity holds chunks of (static or temporal), with its element
    /// type (that of its first data) and how many of the entity's chunks have its column:
    /// a component is forgotten with the last of them, so that what the store accepts
    /// depends only on what it holds (not on whether compaction rewrote the chunks that
    /// held a component's first data).
    pub element_types: BTreeMap<ComponentName, ComponentType>,
    pub static_winners: SmallMap<ComponentName, StaticWinner>,
    /// How many components each static chunk of this entity answers for; a chunk that
    /// answers for none is invisible and leaves the store.
    pub static_chunks: ahash::HashMap<ChunkId, (Arc<Chunk>, usize)>,
    pub temporal_per_timeline_per_component:
        SmallMap<Arc<str>, SmallMap<ComponentName, TemporalComponentIndex>>,
    /// Every chunk of the entity the store holds (unordered: `drop_entity` sorts them).
    pub chunk_ids: ahash::HashSet<ChunkId>,
    /// At least the greatest row id of any chunk the entity holds (it never decreases while
    /// the entity exists): a chunk whose row ids are all greater holds no row the entity
    /// holds, which spares most inserts the search of [`crate::held`].
    pub max_row_id: RowId,
    /// Temporal chunks still small enough for compaction on insert to grow.
    pub pending: PendingGroups,
    /// What the large indices add to the heap, kept as they change
    /// ([`EntityIndex::extra_index_heap_bytes`] recounts it).
    pub large_index_bytes: u64,
    pub stats: EntityStats,
    pub ledger: BufferLedger,
}

/// A component's type at one entity, and how many of the entity's chunks have its column.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ComponentType {
    pub element_type: DataType,
    pub num_chunks: usize,
}

impl EntityIndex {
    /// Makes `chunk`'s cells the static winners where their row ids are the greatest, and
    /// returns the static chunks left answering for nothing (possibly `chunk` itself).
    #[expect(
        clippy::cast_possible_truncation,
        reason = "columns < 2^32, checked in Chunk::from_raw"
    )]
    pub(super) fn insert_static(&mut self, chunk: &Arc<Chunk>) -> Vec<Arc<Chunk>> {
        let mut num_won = 0;
        let mut losers = Vec::new();
        for (position, column) in chunk.components().iter().enumerate() {
            let Some((row_id, row)) = column.max_row_id_cell(chunk.row_ids()) else {
                continue;
            };
            let winner = StaticWinner {
                row_id,
                chunk: Arc::clone(chunk),
                component_column: position as u32,
                row,
            };
            match self.static_winners.get_mut(column.name()) {
                // Equal row ids: the later insert wins, as it would in a later chunk.
                Some(current) if current.row_id > row_id => continue,
                Some(current) => losers.push(std::mem::replace(current, winner).chunk.id()),
                None => {
                    self.static_winners.insert(column.name().clone(), winner);
                }
            }
            num_won += 1;
        }
        self.static_chunks
            .insert(chunk.id(), (Arc::clone(chunk), num_won));
        let mut removed = Vec::new();
        for id in losers.into_iter().chain(std::iter::once(chunk.id())) {
            let Some((_, num_won)) = self.static_chunks.get_mut(&id) else {
                continue;
            };
            if id != chunk.id() {
                *num_won -= 1;
            }
            if *num_won == 0
                && let Some((loser, _)) = self.static_chunks.remove(&id)
            {
                removed.push(loser);
            }
        }
        removed
    }

    #[expect(
        clippy::cast_possible_truncation,
        reason = "columns < 2^32, checked in Chunk::from_raw"
    )]
    /// Indexes a temporal chunk under every (timeline, component) it has cells for;
    /// returns how much the indices' extra heap grew (see
    /// [`TemporalComponentIndex::extra_heap_bytes`]).
    pub(super) fn insert_temporal(&mut self, chunk: &Arc<Chunk>) -> i64 {
        let mut extra = 0;
        for (time_position, time_column) in chunk.time_columns().iter().enumerate() {
            let per_component = self
                .temporal_per_timeline_per_component
                .get_or_default(Arc::clone(time_column.timeline().name_arc()));
            for (component_position, column) in chunk.components().iter().enumerate() {
                let Some(bounds) = column.bounds(time_position) else {
                    continue;
                };
                let index = per_component.get_or_default(column.name().clone());
                let before = index.extra_heap_bytes();
                index.insert(IndexedChunk {
                    chunk: Arc::clone(chunk),
                    chunk_id: chunk.id(),
                    time_column: time_position as u32,
                    component_column: component_position as u32,
                    bounds,
                });
                extra += signed_difference(index.extra_heap_bytes(), before);
            }
        }
        self.large_index_bytes = self.large_index_bytes.saturating_add_signed(extra);
        extra
    }

    /// Forgets a static chunk: its winners go with it (only dropping the entity removes
    /// static data, so no other chunk needs to take over).
    pub(super) fn remove_static(&mut self, id: ChunkId) {
        self.static_chunks.remove(&id);
        self.static_winners
            .retain(|_, winner| winner.chunk.id() != id);
    }

    /// Forgets a temporal chunk from every (timeline, component) index and from the
    /// compaction candidates.
    /// Returns how much the indices' extra heap grew (negative: shrank).
    pub(super) fn remove_temporal(&mut self, chunk: &Chunk, config: &crate::StoreConfig) -> i64 {
        let id = chunk.id();
        let mut extra = 0;
        for (time_position, time_column) in chunk.time_columns().iter().enumerate() {
            let name = time_column.timeline().name();
            let Some(per_component) = self.temporal_per_timeline_per_component.get_mut(name) else {
                continue;
            };
            for column in chunk.components() {
                let Some(bounds) = column.bounds(time_position) else {
                    continue;
                };
                if let Some(index) = per_component.get_mut(column.name()) {
                    let before = index.extra_heap_bytes();
                    index.remove(id, &bounds);
                    extra += signed_difference(index.extra_heap_bytes(), before);
                    if index.is_empty() {
                        per_component.remove(column.name());
                    }
                }
            }
            if per_component.is_empty() {
                self.temporal_per_timeline_per_component.remove(name);
            }
        }
        self.pending.remove(chunk, config);
        self.large_index_bytes = self.large_index_bytes.saturating_add_signed(extra);
        extra
    }

    /// What the entity's large indices add to the heap (see
    /// [`TemporalComponentIndex::extra_heap_bytes`]).
    pub(crate) fn extra_index_heap_bytes(&self) -> u64 {
        self.temporal_per_timeline_per_component
            .values()
            .flat_map(SmallMap::values)
            .map(TemporalComponentIndex::extra_heap_bytes)
            .sum()
    }

    /// The indices holding `chunk`: one per (timeline, component) it has cells for.
    pub(crate) fn indices_of<'a>(
        &'a self,
        chunk: &'a Chunk,
    ) -> impl Iterator<Item = &'a TemporalComponentIndex> + 'a {
        chunk
            .time_columns()
            .iter()
            .enumerate()
            .filter_map(|(position, time_column)| {
                let per_component = self
                    .temporal_per_timeline_per_component
                    .get(time_column.timeline().name())?;
                Some((position, per_component))
            })
            .flat_map(move |(position, per_component)| {
                chunk
                    .components()
                    .iter()
                    .filter(move |column| column.bounds(position).is_some())
                    .filter_map(move |column| per_component.get(column.name()))
            })
    }

    /// What removing `chunk` would take off the large indices' extra heap, at most.
    pub(crate) fn extra_index_heap_bytes_of(&self, chunk: &Chunk) -> u64 {
        // Most entities have no large index: then no lookup by the chunk's names (whose
        // strings are cold, a cache miss each when planning a GC over many chunks).
        if self.large_index_bytes == 0 {
            return 0;
        }
        let per_entry = LARGE_INDEX_BYTES_PER_ENTRY - SMALL_INDEX_BYTES_PER_ENTRY;
        let large = self
            .indices_of(chunk)
            .filter(|index| index.extra_heap_bytes() > 0)
            .count();
        per_entry * large as u64
    }
}

/// `after − before` for byte counts far below `i64::MAX`.
pub(super) fn signed_difference(after: u64, before: u64) -> i64 {
    i64::try_from(i128::from(after) - i128::from(before)).unwrap_or(0)
}
