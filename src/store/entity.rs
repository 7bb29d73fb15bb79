//! [`EntityIndex`]: what the store's writer knows about one entity (its component types
//! and counts, its static chunks, its chunk ids, the chunks compaction keeps waiting, its
//! buffer ledger), and [`EntityMut`], which changes it together with the entity's
//! [`EntityView`] (its static winners and temporal indices). Together they own the
//! invariant that each index holds exactly the entity's chunks with cells there.

use std::sync::Arc;

use arrow_schema::DataType;

use super::pending::PendingGroups;
use super::view::{EntityView, StaticWinner};
use crate::chunk::ComponentTimeBounds;
use crate::index::{
    IndexedChunk, LARGE_INDEX_BYTES_PER_ENTRY, SMALL_INDEX_BYTES_PER_ENTRY, TemporalComponentIndex,
};
use crate::small_map::SmallMap;
use crate::stats::BufferLedger;
use crate::{Chunk, ChunkId, ComponentName, RowId};

/// What only the store's writer knows of one entity; what queries read is its
/// [`EntityView`], in the store's view.
#[derive(Clone, Debug, Default)]
pub(crate) struct EntityIndex {
    /// Where the entity's view is in the view's entity table (`store/entity_table.rs`).
    pub slot: u32,
    /// Each component the entity holds chunks of (static or temporal), with its element
    /// type (that of its first data) and how many of the entity's chunks have its column:
    /// a component is forgotten with the last of them, so that what the store accepts
    /// depends only on what it holds (not on whether compaction rewrote the chunks that
    /// held a component's first data).
    ///
    /// A small map, not a B-tree: a B-tree's first node is 544 bytes for one or two
    /// components, a third of an entity's bookkeeping in a store of many small entities.
    pub element_types: SmallMap<ComponentName, ComponentType>,
    /// How many components each static chunk of this entity answers for; a chunk that
    /// answers for none is invisible and leaves the store.
    ///
    /// A small map: an entity usually has one static chunk or none, which then costs no
    /// allocation (a hash map's first table is 148 bytes).
    pub static_chunks: SmallMap<ChunkId, (Arc<Chunk>, usize)>,
    /// Every chunk of the entity the store holds outside its write buffer (unordered:
    /// `drop_entity` sorts them). The buffered ones are the view's `buffered`: a row
    /// streamed one at a time passes through the buffer and into a merge without entering
    /// and leaving this set (a hash insertion and removal, 4% of `insert_streaming`'s
    /// instructions).
    pub chunk_ids: ahash::HashSet<ChunkId>,
    /// At least the greatest row id of any chunk the entity holds (it never decreases while
    /// the entity exists): a chunk whose row ids are all greater holds no row the entity
    /// holds, which spares most inserts the search of [`crate::dedup`].
    pub max_row_id: RowId,
    /// Temporal chunks still small enough for compaction on insert to grow.
    pub pending: PendingGroups,
    /// What the large indices add to the heap, kept as they change
    /// ([`EntityView::extra_index_heap_bytes`] recounts it).
    pub large_index_bytes: u64,
    pub ledger: BufferLedger,
    /// The rows of the view's write buffer, group by group, in columns
    /// (`store/buffer.rs`): the writer's alone, so a write under a snapshot copies none.
    pub buffer_columns: super::BufferColumns,
}

impl EntityIndex {
    /// Every chunk the store holds of this entity: those of its chunk set (found in the
    /// store's `chunks`) and those of its write buffer (`view.buffered`), which are in no
    /// set. The one definition of an entity's chunks, for whatever must list them all.
    pub(crate) fn held_chunks<'a>(
        &'a self,
        view: &'a EntityView,
        chunks: &'a ahash::HashMap<ChunkId, super::StoredChunk>,
    ) -> impl Iterator<Item = &'a Arc<Chunk>> + 'a {
        self.set_chunks(chunks).chain(view.buffered.chunks())
    }

    /// The chunks of the entity's chunk set (all it holds outside its write buffer), found
    /// in the store's `chunks`.
    pub(crate) fn set_chunks<'a>(
        &'a self,
        chunks: &'a ahash::HashMap<ChunkId, super::StoredChunk>,
    ) -> impl Iterator<Item = &'a Arc<Chunk>> + 'a {
        self.chunk_ids
            .iter()
            .filter_map(|id| chunks.get(id).map(|stored| &stored.chunk))
    }
}

/// A component's type at one entity, and how many of the entity's chunks have its column.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ComponentType {
    pub element_type: DataType,
    /// The entity's chunks outside its write buffer that have the component's column,
    /// plus the groups of its write buffer whose layout has it: a group's chunks share
    /// one layout, so the group counts once, from the chunk that opens it until its last
    /// chunk leaves (a full fan taken out to be merged leaves as one). A streamed row
    /// then joins and leaves its entity's components with no map lookup (two per
    /// component, 3.5% of `insert_streaming`'s instructions when it counted per chunk).
    pub num_chunks: usize,
}

/// An entity's writer part and its view, changed together: what every membership change
/// of one entity goes through. The view is the store's own here (`Arc::make_mut` copied it
/// if a snapshot shared it), and so is each index it changes.
pub(crate) struct EntityMut<'a> {
    pub index: &'a mut EntityIndex,
    pub view: &'a mut EntityView,
}

impl EntityMut<'_> {
    /// Does the store hold no chunk of the entity, in its chunk set or its write buffer?
    /// (A full fan compaction took out of the buffer is in neither until it leaves: the
    /// merge removes it before adding what it made.)
    pub(super) fn holds_no_chunks(&self) -> bool {
        self.index.chunk_ids.is_empty() && self.view.buffered.is_empty()
    }

    /// Counts `chunk`'s columns among the entity's components; a component's first column
    /// gives its type.
    pub(super) fn add_components(&mut self, chunk: &Chunk) {
        for column in chunk.components() {
            if let Some(known) = self.index.element_types.get_mut(column.name()) {
                known.num_chunks += 1;
            } else {
                let known = ComponentType {
                    element_type: column.element_type().clone(),
                    num_chunks: 1,
                };
                self.index
                    .element_types
                    .insert(column.name().clone(), known);
                Arc::make_mut(&mut self.view.component_types)
                    .insert(column.name().clone(), column.element_type().clone());
            }
        }
    }

    /// The mirror of [`EntityMut::add_components`]: a component goes with its last column.
    pub(super) fn remove_components(&mut self, chunk: &Chunk) {
        for column in chunk.components() {
            if let Some(known) = self.index.element_types.get_mut(column.name()) {
                known.num_chunks -= 1;
                if known.num_chunks == 0 {
                    self.index.element_types.remove(column.name());
                    Arc::make_mut(&mut self.view.component_types).remove(column.name());
                }
            }
        }
    }

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
            match self.view.static_winners.get_mut(column.name()) {
                // Equal row ids: the later insert wins, as it would in a later chunk.
                Some(current) if current.row_id > row_id => continue,
                Some(current) => losers.push(std::mem::replace(current, winner).chunk.id()),
                None => {
                    self.view
                        .static_winners
                        .insert(column.name().clone(), winner);
                }
            }
            num_won += 1;
        }
        let static_chunks = &mut self.index.static_chunks;
        static_chunks.insert(chunk.id(), (Arc::clone(chunk), num_won));
        let mut removed = Vec::new();
        for id in losers.into_iter().chain(std::iter::once(chunk.id())) {
            let Some((_, num_won)) = static_chunks.get_mut(&id) else {
                continue;
            };
            if id != chunk.id() {
                *num_won -= 1;
            }
            if *num_won == 0
                && let Some((loser, _)) = static_chunks.remove(&id)
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
        let mut indexed = false;
        for (time_position, time_column) in chunk.time_columns().iter().enumerate() {
            let per_component = self
                .view
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
                indexed = true;
                extra += signed_difference(index.extra_heap_bytes(), before);
            }
            if per_component.is_empty() {
                let name = time_column.timeline().name();
                self.view.temporal_per_timeline_per_component.remove(name);
            }
        }
        if !indexed {
            self.view.unindexed.push(Arc::clone(chunk));
        }
        self.index.large_index_bytes = self.index.large_index_bytes.saturating_add_signed(extra);
        extra
    }

    /// Forgets a static chunk: its winners go with it (only dropping the entity removes
    /// static data, so no other chunk needs to take over).
    pub(super) fn remove_static(&mut self, id: ChunkId) {
        self.index.static_chunks.remove(&id);
        self.view
            .static_winners
            .retain(|_, winner| winner.chunk.id() != id);
    }

    /// Forgets a temporal chunk from every (timeline, component) index and, if
    /// `still_grouped` (compaction has not taken it out already), from the entity's
    /// compaction groups. Returns how much the indices' extra heap grew (negative: shrank).
    /// Not for a buffered chunk: see [`EntityMut::unbuffer`].
    pub(super) fn remove_temporal(
        &mut self,
        chunk: &Chunk,
        config: &crate::StoreConfig,
        still_grouped: bool,
    ) -> i64 {
        if still_grouped {
            self.index.pending.remove(chunk, config);
        }
        self.unindex_temporal(chunk)
    }

    /// Forgets a buffered chunk: out of the write buffer, unless compaction took it out
    /// already (`still_buffered` false: a full fan it is merging, whose components the
    /// caller uncounts once, see [`ComponentType::num_chunks`]). A buffered chunk is in
    /// no index and no other compaction group.
    pub(super) fn unbuffer(&mut self, chunk: &Chunk, still_buffered: bool) {
        if still_buffered {
            let removed = self.view.buffered.remove(chunk.id());
            debug_assert!(removed.is_some(), "{} is buffered", chunk.id());
            if removed == Some(true) {
                self.remove_components(chunk);
            }
            self.index.buffer_columns.invalidate();
        }
    }

    /// Takes a temporal chunk that is not buffered out of its indices; returns how much the
    /// indices' extra heap grew.
    fn unindex_temporal(&mut self, chunk: &Chunk) -> i64 {
        let id = chunk.id();
        let mut extra = 0;
        let mut indexed = false;
        let per_timeline = &mut self.view.temporal_per_timeline_per_component;
        for (time_position, time_column) in chunk.time_columns().iter().enumerate() {
            let name = time_column.timeline().name();
            let Some(per_component) = per_timeline.get_mut(name) else {
                continue;
            };
            for column in chunk.components() {
                let Some(bounds) = column.bounds(time_position) else {
                    continue;
                };
                indexed = true;
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
                per_timeline.remove(name);
            }
        }
        if !indexed {
            self.view.unindexed.retain(|c| c.id() != id);
        }
        self.index.large_index_bytes = self.index.large_index_bytes.saturating_add_signed(extra);
        extra
    }

    /// [`EntityMut::remove_temporal`] for many temporal chunks of the entity at once:
    /// one pass over its compaction groups, and each index's entries removed together
    /// (indexed afresh where most of them go: see
    /// [`TemporalComponentIndex::remove_many`]). Returns how much the indices' extra heap
    /// grew (negative: shrank). `chunks` are not buffered; the buffered chunks leaving
    /// with them are out of the write buffer already (or were taken out by compaction).
    pub(super) fn remove_temporal_many(&mut self, chunks: &[&Chunk], still_grouped: bool) -> i64 {
        // Every temporal chunk the entity holds goes (a collection or a drop taking all of
        // its temporal data; the chunks are distinct and still in its chunk set, and its
        // write buffer is empty): its temporal structures empty at once rather than entry
        // by entry.
        let num_temporal = self
            .index
            .chunk_ids
            .len()
            .saturating_sub(self.index.static_chunks.len());
        if chunks.len() == num_temporal && self.view.buffered.is_empty() {
            if still_grouped {
                self.index.pending = super::pending::PendingGroups::default();
            }
            self.view.buffered = super::buffer::WriteBuffer::default();
            self.index.buffer_columns = super::BufferColumns::default();
            self.view.unindexed.clear();
            self.view.temporal_per_timeline_per_component = SmallMap::default();
            let freed = i64::try_from(self.index.large_index_bytes).unwrap_or(i64::MAX);
            self.index.large_index_bytes = 0;
            return -freed;
        }
        if still_grouped && !self.index.pending.is_empty() {
            let gone: ahash::HashSet<ChunkId> = chunks.iter().map(|c| c.id()).collect();
            self.index.pending.remove_many(&gone);
        }
        // Only indices in the three views gain from removals made together (a vector or
        // a sequence loses an entry for a shift), and an entity has such an index exactly
        // when it counts their extra heap: without one, no grouping is paid for.
        if self.index.large_index_bytes == 0 {
            return chunks
                .iter()
                .map(|chunk| self.unindex_temporal(chunk))
                .sum();
        }
        // Each index's removals, keyed by (timeline, component) names; an index holds a
        // chunk at most once.
        let mut per_index: ahash::HashMap<(&str, &str), Vec<(ChunkId, ComponentTimeBounds)>> =
            ahash::HashMap::default();
        let mut unindexed: ahash::HashSet<ChunkId> = ahash::HashSet::default();
        for chunk in chunks {
            let id = chunk.id();
            let mut indexed = false;
            for (time_position, time_column) in chunk.time_columns().iter().enumerate() {
                for column in chunk.components() {
                    let Some(bounds) = column.bounds(time_position) else {
                        continue;
                    };
                    indexed = true;
                    per_index
                        .entry((time_column.timeline().name(), column.name().as_str()))
                        .or_default()
                        .push((id, bounds));
                }
            }
            if !indexed {
                unindexed.insert(id);
            }
        }
        if !unindexed.is_empty() {
            self.view.unindexed.retain(|c| !unindexed.contains(&c.id()));
        }
        let mut extra = 0;
        let per_timeline = &mut self.view.temporal_per_timeline_per_component;
        for ((timeline, component), removed) in &per_index {
            let Some(per_component) = per_timeline.get_mut(*timeline) else {
                continue;
            };
            if let Some(index) = per_component.get_mut(*component) {
                let before = index.extra_heap_bytes();
                index.remove_many(removed);
                extra += signed_difference(index.extra_heap_bytes(), before);
                if index.is_empty() {
                    per_component.remove(*component);
                }
            }
            if per_component.is_empty() {
                per_timeline.remove(*timeline);
            }
        }
        self.index.large_index_bytes = self.index.large_index_bytes.saturating_add_signed(extra);
        extra
    }
}

/// A removal of this many chunks of one entity or more goes through
/// [`EntityMut::remove_temporal_many`]; below it, one at a time costs less than gathering
/// the removals.
pub(super) const BULK_REMOVAL_MIN_CHUNKS: usize = 8;

impl EntityView {
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
}

impl EntityIndex {
    /// What removing `chunk` would take off the large indices' extra heap, at most.
    pub(crate) fn extra_index_heap_bytes_of(&self, view: &EntityView, chunk: &Chunk) -> u64 {
        // Most entities have no large index: then no lookup by the chunk's names (whose
        // strings are cold, a cache miss each when planning a GC over many chunks).
        if self.large_index_bytes == 0 || view.buffered.contains(chunk.id()) {
            return 0; // (a buffered chunk is in no index)
        }
        let per_entry = LARGE_INDEX_BYTES_PER_ENTRY - SMALL_INDEX_BYTES_PER_ENTRY;
        let large = view
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
