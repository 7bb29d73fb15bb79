//! [`StoreView`]: everything a query reads, in a form a snapshot shares.
//!
//! The store keeps what readers need (per-entity indices and static winners, the Clear
//! index, the timeline types, the figures) apart from what only its writer needs (the
//! chunk map's bookkeeping, the garbage collector's orders, buffer ledgers, compaction's
//! waiting groups). The readers' part is made of persistent pieces: the entity map is a
//! directory of slots and a radix tree of views (`store/entity_table.rs`), each entity's
//! view and each of its temporal indices sit behind an `Arc`, and so do the Clear tree's
//! nodes. Cloning a `StoreView` is therefore O(1) (a few reference counts), and a mutation
//! copies only what it touches, and only while a snapshot still holds it
//! ([`Arc::make_mut`]): the entity's view (its small maps, small indices and write
//! buffer), a bounded part of each larger index it changes (see `index/mod.rs`), the
//! entity table's path to the entity's slot.
//! A store nobody snapshots owns every piece, so its writes copy nothing.

use std::sync::Arc;

use arrow_schema::DataType;

use super::buffer::WriteBuffer;
use super::entity_table::EntityTable;
use crate::clear::ClearIndex;
use crate::index::{IndexedChunk, TemporalComponentIndex};
use crate::sanity::{SanityError, Structure};
use crate::small_map::SmallMap;
use crate::stats::{EntityStats, StoreStats};
use crate::{Chunk, ChunkId, ComponentName, EntityPath, RowId, TimeRange, TimeType, Timeline};

/// The entity map: path to view, persistent so that a snapshot shares it and a write
/// copies little (see `store/entity_table.rs`).
pub(crate) type EntityViews = EntityTable<EntityView>;

/// The static cell that currently answers for one (entity, component).
#[derive(Clone, Debug)]
pub(crate) struct StaticWinner {
    pub row_id: RowId,
    pub chunk: Arc<Chunk>,
    pub component_column: u32,
    pub row: u32,
}

/// What queries read of one entity.
#[derive(Clone, Debug, Default)]
pub(crate) struct EntityView {
    /// The element type of each component the entity holds chunks of (static or
    /// temporal). Behind an `Arc`: it changes only when a component appears or goes.
    ///
    /// A small map (see [`EntityIndex`](super::entity::EntityIndex)'s `element_types`).
    pub component_types: Arc<SmallMap<ComponentName, DataType>>,
    pub static_winners: SmallMap<ComponentName, StaticWinner>,
    /// Each index inline (a query reaches its entries in as many steps as in a store
    /// without snapshots): a small index is one vector, copied with the view; a sequence
    /// (at most 16,384 entries) and a large index sit behind `Arc`s, so copying the view
    /// counts references there, and a write copies the sequence or a path through the
    /// large index's persistent B-trees (see `index/mod.rs`). (A small index behind an
    /// `Arc` too made writes under a snapshot cheaper and queries slower: see
    /// `docs/performance-log.md`, "Publishing per insert".)
    pub temporal_per_timeline_per_component:
        SmallMap<Arc<str>, SmallMap<ComponentName, TemporalComponentIndex>>,
    /// Temporal chunks with no non-null cell on any timeline: no index holds them, but
    /// they are the entity's rows all the same (the chunk table lists them).
    pub unindexed: Vec<Arc<Chunk>>,
    /// The write buffer: small temporal chunks compaction on insert will merge soon (those
    /// of its first level, fewer than `merge_fanout` rows each), in no index. Queries
    /// read them beside the indices (at most `merge_fanout - 1` per layout, each a few
    /// rows, grouped and summarized: see `store/buffer.rs`). A row arriving in its own
    /// chunk is thus buffered with a push here and merged with its fan's, rather than
    /// indexed under every (timeline, component) it has cells for and taken out again a
    /// few inserts later. See `compaction/mod.rs`.
    pub buffered: WriteBuffer,
    pub stats: EntityStats,
}

/// A read-only view of a store: every query, figure and listing that does not change it.
///
/// [`ChunkStore`](crate::ChunkStore) dereferences to its current view, the way a `String`
/// dereferences to a `str`, and a [`Snapshot`](crate::Snapshot) holds a view frozen at the
/// moment it was taken; a function that only reads can take `&StoreView` and serve both.
/// Nothing in a `StoreView` can be changed: its only methods take `&self`.
///
/// Cloning a view is O(1): it shares every index with the store it came from (see the
/// module docs of `store/view.rs` for what a later write copies).
///
/// ```
/// use chunkstore::{ChunkStore, StoreView};
///
/// fn count_entities(view: &StoreView) -> usize {
///     view.entity_paths().len()
/// }
/// let store = ChunkStore::new();
/// assert_eq!(count_entities(&store), 0);
/// ```
#[derive(Clone, Debug, Default)]
pub struct StoreView {
    pub(crate) entities: EntityViews,
    pub(crate) clears: Arc<ClearIndex>,
    /// A small map: a store has a few timelines, whose names every insert and many
    /// queries look up (hashing the name was 1.1% of `insert_streaming`'s instructions).
    pub(crate) time_types: Arc<SmallMap<Arc<str>, TimeType>>,
    pub(crate) stats: StoreStats,
}

impl StoreView {
    /// Totals of chunks, rows and heap bytes, and what compaction copied. O(1).
    pub fn stats(&self) -> StoreStats {
        self.stats
    }

    /// The figures of one entity (its own data, not its descendants'). O(1).
    pub fn entity_stats(&self, entity: &EntityPath) -> Option<EntityStats> {
        self.entities.get(entity).map(|e| e.stats)
    }

    /// The type a timeline has in this store, if any chunk used it.
    pub fn time_type(&self, timeline: &str) -> Option<TimeType> {
        self.time_types.get(timeline).copied()
    }

    /// Every timeline any inserted chunk used, sorted by name. (A timeline keeps its type
    /// once seen, even after all its data is gone; [`StoreView::time_range`] tells whether
    /// any is left.)
    pub fn timelines(&self) -> Vec<Timeline> {
        let mut timelines: Vec<Timeline> = self
            .time_types
            .iter()
            .map(|(name, &time_type)| Timeline::new(Arc::clone(name), time_type))
            .collect();
        timelines.sort();
        timelines
    }

    /// The least and greatest time the view holds data at on `timeline`, or `None` if it
    /// holds none there.
    ///
    /// Cost: O(n) over the indices' entries. A [`ChunkStore`](crate::ChunkStore) answers
    /// in O(1) from its writer's time orders.
    pub fn time_range(&self, timeline: &str) -> Option<TimeRange> {
        self.entities
            .values()
            .filter_map(|entity| entity.temporal_per_timeline_per_component.get(timeline))
            .flat_map(SmallMap::values)
            .flat_map(|index| index.chunks())
            .filter_map(|entry| entry.chunk.time_columns().get(entry.time_column as usize))
            .map(crate::TimeColumn::time_range)
            .chain(self.entities.values().flat_map(|entity| {
                entity
                    .unindexed
                    .iter()
                    .chain(entity.buffered.chunks())
                    .filter_map(|chunk| chunk.time_column(timeline))
                    .map(crate::TimeColumn::time_range)
            }))
            .reduce(TimeRange::union)
    }

    /// Every entity that holds data, sorted.
    pub fn entity_paths(&self) -> Vec<EntityPath> {
        let mut paths: Vec<EntityPath> = self.entities.keys().cloned().collect();
        paths.sort();
        paths
    }

    /// The components an entity holds chunks of (static or temporal), sorted by name.
    pub fn component_names(&self, entity: &EntityPath) -> Vec<ComponentName> {
        self.entities
            .get(entity)
            .map(|e| {
                let mut names: Vec<ComponentName> = e
                    .component_types
                    .iter()
                    .map(|(name, _)| name.clone())
                    .collect();
                names.sort();
                names
            })
            .unwrap_or_default()
    }

    /// The Arrow type of one element of a component's cells at an entity.
    pub fn element_type(&self, entity: &EntityPath, component: &str) -> Option<&DataType> {
        self.entities
            .get(entity)
            .and_then(|e| e.component_types.get(component))
    }

    /// Every chunk the view holds, sorted by entity then chunk id.
    ///
    /// Cost: O(n log n), gathered from the indices (a chunk indexed under several
    /// timelines and components is listed once). A [`ChunkStore`](crate::ChunkStore)'s
    /// `chunks_unordered()` walks its chunk map instead, in no particular order.
    pub fn chunks(&self) -> Vec<Arc<Chunk>> {
        let mut out = Vec::with_capacity(usize::try_from(self.stats.num_chunks()).unwrap_or(0));
        // Entities in path order, each one's chunks sorted by id: the list comes out
        // sorted without comparing paths per chunk (sorting the whole list by path was
        // most of a SQL query on one entity of a 100,000-chunk store).
        let mut entities: Vec<_> = self.entities.iter().collect();
        entities.sort_unstable_by(|a, b| a.0.cmp(b.0));
        for (_, entity) in entities {
            let first = out.len();
            out.extend(
                entity
                    .static_winners
                    .values()
                    .map(|winner| Arc::clone(&winner.chunk)),
            );
            for per_component in entity.temporal_per_timeline_per_component.values() {
                for index in per_component.values() {
                    out.extend(index.chunks().map(|entry| Arc::clone(&entry.chunk)));
                }
            }
            out.extend(entity.unindexed.iter().cloned());
            out.extend(entity.buffered.chunks().cloned());
            let mine = &mut out[first..];
            mine.sort_unstable_by_key(|chunk| chunk.id());
            let mut seen: Option<ChunkId> = None;
            let mut kept = first;
            for position in first..out.len() {
                let id = out[position].id();
                if seen != Some(id) {
                    out.swap(kept, position);
                    kept += 1;
                    seen = Some(id);
                }
            }
            out.truncate(kept);
        }
        debug_assert!(out.is_sorted_by_key(|chunk| (chunk.entity_path().clone(), chunk.id())));
        out
    }

    /// Checks what the view owns on its own: each entity's indices and small maps, and the
    /// Clear index. (What the view must agree with, the chunks, the store checks in
    /// [`ChunkStore::sanity_check`](crate::ChunkStore::sanity_check).)
    ///
    /// # Errors
    /// The first broken invariant: a bug in this crate.
    pub fn sanity_check(&self) -> Result<(), SanityError> {
        let Self {
            entities,
            clears,
            time_types, // and against the chunks by the store
            stats: _,   // recounted by the store
        } = self;
        time_types.sanity_check()?;
        entities.sanity_check()?;
        for (path, entity) in entities.iter() {
            entity.sanity_check(path)?;
        }
        clears.sanity_check()
    }
}

impl EntityView {
    /// Is `chunk` (one of the entity's temporal chunks, indexed or buffered) among the
    /// `n` chunks with the greatest indices `(time, row id)` for some (timeline,
    /// component) it has cells for? What garbage collection's `protect_latest` keeps.
    pub(crate) fn is_among_latest(&self, chunk: &Chunk, n: usize) -> bool {
        let id = chunk.id();
        chunk
            .time_columns()
            .iter()
            .enumerate()
            .any(|(time_position, time_column)| {
                let timeline = time_column.timeline().name();
                let per_component = self.temporal_per_timeline_per_component.get(timeline);
                chunk.components().iter().any(|column| {
                    let Some(bounds) = column.bounds(time_position) else {
                        return false;
                    };
                    let key = bounds.max_index_key(id);
                    let mut after = per_component
                        .and_then(|per_component| per_component.get(column.name()))
                        .map_or(0, |index| index.count_after(key, n));
                    if after < n && !self.buffered.is_empty() {
                        self.buffered.for_each(
                            timeline,
                            column.name().as_str(),
                            |other, _, _, bounds| {
                                after += usize::from(bounds.max_index_key(other.id()) > key);
                            },
                        );
                    }
                    after < n
                })
            })
    }

    /// [`WriteBuffer::for_each`] as the index entries the chunks would have.
    pub(crate) fn buffered_entries(&self, timeline: &str, component: &str) -> Vec<IndexedChunk> {
        let mut entries = Vec::new();
        self.buffered.for_each(
            timeline,
            component,
            |chunk, time_column, component_column, bounds| {
                entries.push(IndexedChunk {
                    chunk: Arc::clone(chunk),
                    chunk_id: chunk.id(),
                    time_column,
                    component_column,
                    bounds,
                });
            },
        );
        entries
    }

    /// The view's own invariants: its small maps hold, each index holds, is non-empty and
    /// typed, and holds only the entity's chunks.
    pub(crate) fn sanity_check(&self, path: &EntityPath) -> Result<(), SanityError> {
        let fail = |invariant| SanityError::new(Structure::Entity, invariant).at(path);
        let Self {
            component_types,
            static_winners,
            temporal_per_timeline_per_component,
            unindexed,
            buffered,
            stats: _, // recounted by the store
        } = self;
        static_winners.sanity_check()?;
        temporal_per_timeline_per_component.sanity_check()?;
        for (timeline, per_component) in temporal_per_timeline_per_component.iter() {
            per_component.sanity_check()?;
            for (component, index) in per_component.iter() {
                index.sanity_check()?;
                if component_types.get(component).is_none() || index.is_empty() {
                    return Err(fail("a temporal index is typed and non-empty")
                        .at(format_args!("{path}: {component} on {timeline}")));
                }
                if index
                    .chunks()
                    .any(|entry| entry.chunk.entity_path() != path)
                {
                    return Err(fail("an indexed chunk is the entity's own"));
                }
                if index
                    .chunks()
                    .any(|entry| buffered.contains(entry.chunk_id))
                {
                    return Err(fail("a buffered chunk is in no index"));
                }
            }
        }
        for chunk in unindexed {
            let has_bounds = (0..chunk.time_columns().len())
                .any(|t| chunk.components().iter().any(|c| c.bounds(t).is_some()));
            if chunk.is_static() || has_bounds || chunk.entity_path() != path {
                return Err(fail(
                    "an unindexed chunk is a temporal chunk of the entity without cells",
                )
                .at(chunk.id()));
            }
        }
        buffered.sanity_check(path)?;
        if buffered
            .chunks()
            .any(|b| unindexed.iter().any(|u| u.id() == b.id()))
        {
            return Err(fail("a buffered chunk is not also unindexed"));
        }
        Ok(())
    }
}
