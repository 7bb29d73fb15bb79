//! [`ChunkStore`]: owns the chunks and every index over them. Insertion validates the whole
//! chunk against the store first and only then mutates, so a rejected chunk leaves no trace.
//! Every mutation goes through two primitives, [`ChunkStore::add_chunk`] and
//! [`ChunkStore::remove_chunk`], which keep the indices, the statistics and the event list
//! in step; compaction ([`crate::compaction`]) and garbage collection ([`crate::gc`]) are
//! built on them.

use std::collections::BTreeMap;
use std::fmt;
use std::sync::Arc;

use arrow_array::Array;
use arrow_schema::DataType;

use crate::chunk::RowSource;
use crate::clear::ClearIndex;
use crate::compaction::{PendingGroups, RewriteMark, StoreConfig};
use crate::error::{ConfigError, InsertError};
use crate::held::NewRows;
use crate::index::{
    IndexedChunk, LARGE_INDEX_BYTES_PER_ENTRY, SMALL_INDEX_BYTES_PER_ENTRY, TemporalComponentIndex,
};
use crate::ordered::OrderedSet;
use crate::small_map::SmallMap;
use crate::stats::{BufferLedger, EntityStats, StoreLedgers, StoreStats};
use crate::{Chunk, ChunkId, ComponentName, EntityPath, RowId, TimeInt, TimeType, Timeline};

/// Debug builds check the whole store after every insert while it holds at most this many
/// chunks, and after inserts that bring the rows inserted to a power of two (amortized
/// O(1) per row) beyond.
const DEBUG_SANITY_CHECK_MAX_CHUNKS: usize = 64;

/// What [`ChunkStore::validate`] learned of a valid chunk.
struct Validated {
    /// Does the store already know every timeline of the chunk?
    timelines_known: bool,
    /// Could the store hold one of its rows already (see [`crate::held`])? Not when none
    /// of its row ids is within those of its entity.
    may_hold_rows: bool,
}

/// Why a chunk left the store.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum DeletionReason {
    /// Garbage collection removed it.
    Gc,
    /// Compaction merged it into another chunk.
    Compaction,
    /// Newer static data shadows all of it, so no query can see it any more.
    Overwrite,
    /// The caller dropped it (a time range or an entity).
    Drop,
}

/// One change to the set of chunks a store holds. Replaying every event a store returned,
/// in order, on an empty set yields exactly the store's chunks.
#[derive(Clone, Debug)]
pub enum StoreEvent {
    /// The chunk entered the store.
    Addition(Arc<Chunk>),
    /// The chunk left the store.
    Deletion {
        /// The chunk.
        chunk: Arc<Chunk>,
        /// Why.
        reason: DeletionReason,
    },
}

impl StoreEvent {
    /// The chunk added or removed.
    pub fn chunk(&self) -> &Arc<Chunk> {
        match self {
            Self::Addition(chunk) | Self::Deletion { chunk, .. } => chunk,
        }
    }
}

/// A callback that sees every batch of events a store's mutations return.
pub type EventSubscriber = Arc<dyn Fn(&[StoreEvent]) + Send + Sync>;

/// The store's subscribers. A clone of a store starts without any: a subscriber watches
/// the store it subscribed to.
#[derive(Default)]
struct Subscribers(Vec<EventSubscriber>);

impl Clone for Subscribers {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl fmt::Debug for Subscribers {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} subscribers", self.0.len())
    }
}

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

/// A chunk as the store holds it.
#[derive(Clone, Debug)]
pub(crate) struct StoredChunk {
    pub chunk: Arc<Chunk>,
    /// Does the chunk's memory go through the buffer ledgers (it shares buffers)? Decided
    /// once, on addition, so removal undoes exactly what addition did.
    pub ledgered: bool,
    /// Is a temporal chunk in the store-wide orders (`temporal_by_row_id`,
    /// `temporal_per_timeline`)? A chunk compaction will soon merge away enters them only
    /// if it stops waiting: streamed rows would otherwise pass through those orders one
    /// by one. Garbage collection and range drops read waiting chunks from the entities'
    /// compaction groups instead. Always true for static chunks (which no order holds).
    pub in_global_orders: bool,
    /// The on-demand compaction that wrote the chunk, if one did: `compact()` leaves alone
    /// a group that is exactly what one of its rewrites made (see
    /// [`crate::compaction::RewriteMark`]).
    pub rewritten_by: Option<RewriteMark>,
}

/// Temporal chunks of one timeline by least and greatest time, across entities: what
/// time-ordered garbage collection and range drops walk.
#[derive(Clone, Debug, Default)]
pub(crate) struct TimelineChunks {
    pub by_min_time: OrderedSet<(TimeInt, ChunkId)>,
    pub by_max_time: OrderedSet<(TimeInt, ChunkId)>,
}

/// An in-memory store of chunks, answering latest-at and range queries.
///
/// See the crate documentation for an example.
#[derive(Clone, Debug, Default)]
pub struct ChunkStore {
    pub(crate) config: StoreConfig,
    pub(crate) chunks: ahash::HashMap<ChunkId, StoredChunk>,
    time_types: ahash::HashMap<Arc<str>, TimeType>,
    pub(crate) entities: ahash::HashMap<EntityPath, EntityIndex>,
    pub(crate) clears: ClearIndex,
    /// Temporal chunks by least row id: the garbage collector's default order.
    pub(crate) temporal_by_row_id: OrderedSet<(RowId, ChunkId)>,
    pub(crate) temporal_per_timeline: ahash::HashMap<Arc<str>, TimelineChunks>,
    /// Temporal chunks outside the store-wide orders (see [`StoredChunk::in_global_orders`]).
    pub(crate) num_outside_global_orders: usize,
    /// How many rewrites `compact()` has made (it numbers them; see [`RewriteMark`]).
    pub(crate) num_rewrites: u64,
    pub(crate) stats: StoreStats,
    pub(crate) ledgers: StoreLedgers,
    subscribers: Subscribers,
}

impl ChunkStore {
    /// An empty store with the default configuration ([`StoreConfig::DEFAULT`]:
    /// compaction on insert).
    pub fn new() -> Self {
        Self::default()
    }

    /// An empty store with this configuration.
    ///
    /// # Errors
    /// If a threshold of the configuration is zero.
    pub fn with_config(config: StoreConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        Ok(Self {
            config,
            ..Self::default()
        })
    }

    /// The configuration the store was created with.
    pub fn config(&self) -> &StoreConfig {
        &self.config
    }

    /// Calls `subscriber` with the events of every later mutation, after the mutation and
    /// before it returns the same events. A store without subscribers pays nothing.
    pub fn subscribe(&mut self, subscriber: impl Fn(&[StoreEvent]) + Send + Sync + 'static) {
        self.subscribers.0.push(Arc::new(subscriber));
    }

    /// Hands a mutation's events to the subscribers, and back to the caller.
    pub(crate) fn notify(&self, events: Vec<StoreEvent>) -> Vec<StoreEvent> {
        if !events.is_empty() {
            for subscriber in &self.subscribers.0 {
                subscriber(&events);
            }
        }
        events
    }

    /// Inserts a chunk and returns what changed: its addition (or, if compaction split it,
    /// the additions of its parts), the deletion of any static chunk it made invisible
    /// (possibly itself, if newer static data shadows it), and whatever compaction merged
    /// (deletions of the merged chunks, addition of the result).
    ///
    /// Ingest is idempotent (SEMANTICS.md section 6): rows the store already holds are not
    /// stored twice, whether it holds them in this very chunk or in chunks compaction made
    /// from it. A chunk the store holds entirely changes nothing and returns no event; one
    /// it holds in part adds a chunk of its other rows (under a new id).
    ///
    /// ```
    /// # use std::sync::Arc;
    /// # use arrow_array::{ArrayRef, Float64Array};
    /// # use chunkstore::*;
    /// let value = Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
    /// let chunk = Arc::new(
    ///     ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/e").unwrap())
    ///         .with_row(RowId::new(), [(Timeline::sequence("frame"), 1)], [("x", value)])
    ///         .build()?,
    /// );
    /// let mut store = ChunkStore::new();
    /// assert_eq!(store.insert(Arc::clone(&chunk))?.len(), 1);
    /// assert!(store.insert(chunk)?.is_empty(), "the second insert changes nothing");
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    ///
    /// # Errors
    /// If the chunk's timelines, component types or Clear cells conflict with the store or
    /// its rules, or the store holds another chunk under its id; the store is then
    /// unchanged.
    pub fn insert(&mut self, chunk: impl Into<Arc<Chunk>>) -> Result<Vec<StoreEvent>, InsertError> {
        let chunk = chunk.into();
        if let Some(held) = self.chunks.get(&chunk.id()) {
            if Arc::ptr_eq(&held.chunk, &chunk) || held.chunk.has_same_contents(&chunk) {
                return Ok(Vec::new());
            }
            return Err(InsertError::ChunkIdConflict {
                chunk_id: chunk.id(),
                held_entity: held.chunk.entity_path().clone(),
                incoming_entity: chunk.entity_path().clone(),
            });
        }
        let Validated {
            timelines_known,
            may_hold_rows,
        } = self.validate(&chunk)?;
        let new_rows = if may_hold_rows {
            self.new_rows(&chunk)
        } else {
            NewRows::All
        };
        let chunk = match new_rows {
            NewRows::All => chunk,
            NewRows::None => return Ok(Vec::new()),
            NewRows::Some(rows) => {
                let rows: Vec<RowSource> = rows.into_iter().map(|row| (0, row)).collect();
                match Chunk::gather(&[&chunk], &rows) {
                    Ok(rest) => Arc::new(rest),
                    Err(error) => {
                        // Copying rows of a valid chunk does not fail; if it ever did, the
                        // whole chunk goes in rather than losing its new rows.
                        debug_assert!(false, "gathering the new rows of {}: {error}", chunk.id());
                        chunk
                    }
                }
            }
        };
        if !timelines_known {
            for column in chunk.time_columns() {
                let timeline = column.timeline();
                self.time_types
                    .entry(Arc::clone(timeline.name_arc()))
                    .or_insert(timeline.time_type());
            }
        }
        self.stats.rows_inserted += chunk.num_rows() as u64;
        self.stats.payload_bytes_inserted += chunk.payload_bytes();

        let mut events = Vec::with_capacity(1);
        if chunk.is_static() || !self.config.compact_on_insert {
            self.add_chunk(chunk, &mut events);
        } else {
            self.insert_compacting(chunk, &mut events);
        }
        // The full check costs O(store): debug builds run it while the store is small, which
        // is where unit tests live, and ever more rarely as it grows; the model test calls it
        // after every step regardless.
        if cfg!(debug_assertions)
            && (self.chunks.len() <= DEBUG_SANITY_CHECK_MAX_CHUNKS
                || self.stats.rows_inserted.is_power_of_two())
        {
            debug_assert!(self.sanity_check().is_ok(), "{:?}", self.sanity_check());
        }
        Ok(self.notify(events))
    }

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
        let entity = self
            .entities
            .entry(chunk.entity_path().clone())
            .or_default();
        // An entity leaves the map with its last chunk, so one without chunks is new.
        if entity.chunk_ids.is_empty() {
            self.stats.heap_bytes += crate::stats::ENTITY_BYTES;
            entity.stats.heap_bytes += crate::stats::ENTITY_BYTES;
        }
        for column in chunk.components() {
            if let Some(known) = entity.element_types.get_mut(column.name()) {
                known.num_chunks += 1;
            } else {
                let known = ComponentType {
                    element_type: column.element_type().clone(),
                    num_chunks: 1,
                };
                entity.element_types.insert(column.name().clone(), known);
            }
        }
        entity.chunk_ids.insert(chunk.id());
        entity.max_row_id = entity.max_row_id.max(chunk.row_id_range().1);
        crate::stats::account(
            &chunk,
            ledgered,
            true,
            &mut self.stats,
            &mut self.ledgers,
            &mut entity.stats,
            &mut entity.ledger,
        );
        self.clears.insert_chunk(&chunk);
        events.push(StoreEvent::Addition(Arc::clone(&chunk)));
        if chunk.is_static() {
            let overwritten = entity.insert_static(&chunk);
            let stored = StoredChunk {
                chunk,
                ledgered,
                in_global_orders: true,
                rewritten_by: None,
            };
            self.chunks.insert(stored.chunk.id(), stored);
            for overwritten in overwritten {
                // An overwritten static Clear keeps hiding what it hid: its index entry
                // stays, as the static winner semantics of section 5 ask.
                if let Some(stored) = self.chunks.remove(&overwritten.id()) {
                    self.take_out(stored, false, DeletionReason::Overwrite, events);
                }
            }
        } else {
            let extra = entity.insert_temporal(&chunk);
            crate::stats::add_index_bytes(&mut self.stats, &mut entity.stats, extra);
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
            self.clears.remove_chunk(&chunk);
            if in_global_orders {
                self.remove_from_global_orders(&chunk);
            } else {
                self.num_outside_global_orders -= 1;
            }
        }
        if let Some(entity) = self.entities.get_mut(chunk.entity_path()) {
            if unindex {
                if chunk.is_static() {
                    entity.remove_static(id);
                } else {
                    let extra = entity.remove_temporal(&chunk, &self.config);
                    crate::stats::add_index_bytes(&mut self.stats, &mut entity.stats, extra);
                }
            }
            entity.chunk_ids.remove(&id);
            for column in chunk.components() {
                if let Some(known) = entity.element_types.get_mut(column.name()) {
                    known.num_chunks -= 1;
                    if known.num_chunks == 0 {
                        entity.element_types.remove(column.name());
                    }
                }
            }
            crate::stats::account(
                &chunk,
                ledgered,
                false,
                &mut self.stats,
                &mut self.ledgers,
                &mut entity.stats,
                &mut entity.ledger,
            );
            if entity.chunk_ids.is_empty() {
                // Nothing left: the entity is forgotten, as if never inserted (its
                // component types included).
                self.entities.remove(chunk.entity_path());
                self.stats.heap_bytes = self
                    .stats
                    .heap_bytes
                    .saturating_sub(crate::stats::ENTITY_BYTES);
            }
        }
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

    /// Every check `insert` makes before touching anything.
    fn validate(&self, chunk: &Chunk) -> Result<Validated, InsertError> {
        let mut timelines_known = true;
        for column in chunk.time_columns() {
            let timeline = column.timeline();
            match self.time_types.get(timeline.name()) {
                Some(&existing) if existing != timeline.time_type() => {
                    return Err(InsertError::TimelineTypeConflict {
                        chunk_id: chunk.id(),
                        timeline: timeline.name().to_owned(),
                        existing,
                        incoming: timeline.time_type(),
                    });
                }
                Some(_) => {}
                None => timelines_known = false,
            }
        }
        let entity = self.entities.get(chunk.entity_path());
        for column in chunk.components() {
            let incoming = column.element_type();
            if column.name().is_clear() {
                check_clear_cells(chunk, column)?;
            }
            if let Some(existing) = entity
                .and_then(|e| e.element_types.get(column.name()))
                .map(|known| &known.element_type)
                && !existing.equals_datatype(incoming)
            {
                return Err(InsertError::ComponentTypeConflict {
                    chunk_id: chunk.id(),
                    entity_path: chunk.entity_path().clone(),
                    component: column.name().to_string(),
                    existing: existing.clone(),
                    incoming: incoming.clone(),
                });
            }
        }
        Ok(Validated {
            timelines_known,
            may_hold_rows: entity.is_some_and(|e| chunk.row_id_range().0 <= e.max_row_id),
        })
    }

    /// The chunk with this id, if the store holds it.
    pub fn chunk(&self, id: ChunkId) -> Option<&Arc<Chunk>> {
        self.chunks.get(&id).map(|stored| &stored.chunk)
    }

    /// Every chunk, in no particular order.
    pub fn chunks(&self) -> impl Iterator<Item = &Arc<Chunk>> {
        self.chunks.values().map(|stored| &stored.chunk)
    }

    /// Number of chunks, static and temporal.
    pub fn num_chunks(&self) -> usize {
        self.chunks.len()
    }

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
    /// once seen, even after all its data is gone; [`ChunkStore::time_range`] tells whether
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

    /// The least and greatest time the store holds data at on `timeline`, or `None` if it
    /// holds none there.
    ///
    /// Cost: O(1) from the store-wide time orders, plus a look at the small chunks
    /// compaction keeps waiting (O(entities) when there are any).
    pub fn time_range(&self, timeline: &str) -> Option<(TimeInt, TimeInt)> {
        let ordered = self.temporal_per_timeline.get(timeline).and_then(|chunks| {
            let (min, _) = chunks.by_min_time.iter().next()?;
            let (max, _) = chunks.by_max_time.iter().next_back()?;
            Some((*min, *max))
        });
        self.chunks_outside_global_orders()
            .into_iter()
            .filter_map(|chunk| chunk.time_column(timeline))
            .map(crate::TimeColumn::time_range)
            .chain(ordered)
            .reduce(|(min, max), (lo, hi)| (min.min(lo), max.max(hi)))
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
            .map(|e| e.element_types.keys().cloned().collect())
            .unwrap_or_default()
    }

    /// The Arrow type of one element of a component's cells at an entity.
    pub fn element_type(&self, entity: &EntityPath, component: &str) -> Option<&DataType> {
        self.entities
            .get(entity)
            .and_then(|e| e.element_types.get(component))
            .map(|known| &known.element_type)
    }

    /// Only a temporal chunk compaction waits for may be left out of the store-wide
    /// orders (part of [`ChunkStore::sanity_check`]).
    fn check_outside_global_orders(&self, chunk: &Arc<Chunk>) -> Result<(), String> {
        let waiting = self
            .entities
            .get(chunk.entity_path())
            .is_some_and(|e| e.pending.chunks().any(|c| Arc::ptr_eq(c, chunk)));
        if chunk.is_static() || !waiting {
            return Err(format!(
                "{}: only a temporal chunk compaction waits for is left out of the \
                 store-wide orders",
                chunk.id()
            ));
        }
        Ok(())
    }

    /// The store-wide orders hold exactly the expected chunks (part of
    /// [`ChunkStore::sanity_check`]).
    fn check_global_orders(
        &self,
        outside_global_orders: usize,
        expected_by_row_id: &OrderedSet<(RowId, ChunkId)>,
        expected_per_timeline: &BTreeMap<&str, TimelineChunks>,
    ) -> Result<(), String> {
        let Self {
            temporal_by_row_id,
            temporal_per_timeline,
            num_outside_global_orders,
            ..
        } = self;
        if outside_global_orders != *num_outside_global_orders {
            return Err(format!(
                "{num_outside_global_orders} chunks are counted outside the store-wide \
                 orders, {outside_global_orders} are"
            ));
        }
        temporal_by_row_id.sanity_check()?;
        if expected_by_row_id != temporal_by_row_id {
            return Err("the row-id order holds exactly the temporal chunks".into());
        }
        let timelines_match = expected_per_timeline.len() == temporal_per_timeline.len()
            && expected_per_timeline.iter().all(|(name, expected)| {
                temporal_per_timeline.get(*name).is_some_and(|kept| {
                    kept.by_min_time.sanity_check().is_ok()
                        && kept.by_max_time.sanity_check().is_ok()
                        && kept.by_min_time == expected.by_min_time
                        && kept.by_max_time == expected.by_max_time
                })
            });
        if !timelines_match {
            return Err("the per-timeline orders hold exactly the temporal chunks".into());
        }
        Ok(())
    }

    /// Checks every invariant of the store and its indices. Cheap enough for tests to call
    /// after every mutation; debug builds call it after every insert.
    ///
    /// # Errors
    /// A description of the first broken invariant: a bug in this crate.
    pub fn sanity_check(&self) -> Result<(), String> {
        let Self {
            config,
            chunks,
            time_types,
            entities,
            clears,
            temporal_by_row_id: _,
            temporal_per_timeline: _,
            num_outside_global_orders: _,
            num_rewrites,
            stats,
            ledgers: _,
            subscribers: _,
        } = self;
        config.validate().map_err(|e| e.to_string())?;
        // Recount every figure from scratch, through fresh ledgers.
        let mut expected = StoreStats::default();
        let mut ledgers = StoreLedgers::default();
        let mut expected_entities: ahash::HashMap<&EntityPath, (EntityStats, BufferLedger)> =
            ahash::HashMap::default();
        let mut expected_by_row_id = OrderedSet::default();
        let mut expected_per_timeline: BTreeMap<&str, TimelineChunks> = BTreeMap::new();
        let mut outside_global_orders = 0;
        let mut pieces_per_rewrite: ahash::HashMap<u64, usize> = ahash::HashMap::default();
        for (
            &id,
            StoredChunk {
                chunk,
                ledgered,
                in_global_orders,
                rewritten_by,
            },
        ) in chunks
        {
            chunk.sanity_check()?;
            if chunk.id() != id {
                return Err(format!("{id} is keyed by its id"));
            }
            if let Some(mark) = rewritten_by {
                check_rewrite_mark(chunk, *mark, *num_rewrites, &mut pieces_per_rewrite)?;
            }
            let (entity_stats, entity_ledger) =
                expected_entities.entry(chunk.entity_path()).or_default();
            crate::stats::account(
                chunk,
                *ledgered,
                true,
                &mut expected,
                &mut ledgers,
                entity_stats,
                entity_ledger,
            );
            for column in chunk.time_columns() {
                let timeline = column.timeline();
                if time_types.get(timeline.name()) != Some(&timeline.time_type()) {
                    return Err(format!("{id}: timeline {timeline:?} has the store's type"));
                }
                if *in_global_orders {
                    let (min, max) = column.time_range();
                    let per_timeline = expected_per_timeline.entry(timeline.name()).or_default();
                    per_timeline.by_min_time.insert((min, id));
                    per_timeline.by_max_time.insert((max, id));
                }
            }
            if !*in_global_orders {
                self.check_outside_global_orders(chunk)?;
                outside_global_orders += 1;
            } else if !chunk.is_static() {
                expected_by_row_id.insert((chunk.row_id_range().0, id));
            }
            if !entities.contains_key(chunk.entity_path()) {
                return Err(format!("{id}: its entity is indexed"));
            }
        }
        // Each entity's own bookkeeping, and large indices' extra heap, which the store
        // adds as indices grow and shrink.
        for (path, entity) in entities {
            let extra = entity.extra_index_heap_bytes();
            expected.heap_bytes += extra + crate::stats::ENTITY_BYTES;
            expected.temporal_heap_bytes += extra;
            if let Some((entity_stats, _)) = expected_entities.get_mut(path) {
                entity_stats.heap_bytes += extra + crate::stats::ENTITY_BYTES;
            }
        }
        if expected != stats.contents() {
            return Err(format!(
                "stats match the chunks: kept {stats:?}, counted {expected:?}"
            ));
        }
        self.check_global_orders(
            outside_global_orders,
            &expected_by_row_id,
            &expected_per_timeline,
        )?;
        self.check_entities(&expected_entities)?;
        clears.sanity_check()
    }

    /// Each entity's figures equal `expected` (a recount of its chunks), and its own
    /// sanity check passes (part of [`ChunkStore::sanity_check`]).
    fn check_entities(
        &self,
        expected: &ahash::HashMap<&EntityPath, (EntityStats, BufferLedger)>,
    ) -> Result<(), String> {
        for (path, entity) in &self.entities {
            let counted = expected.get(path).map(|e| e.0);
            let num_chunks = counted.map_or(0, |c| c.num_static_chunks + c.num_temporal_chunks);
            if num_chunks != entity.chunk_ids.len() as u64 {
                return Err(format!("{path}: chunk ids list all its chunks"));
            }
            if counted != Some(entity.stats) {
                return Err(format!(
                    "{path}: stats match its chunks: kept {:?}, counted {counted:?}",
                    entity.stats
                ));
            }
            entity.sanity_check(path, &self.chunks, &self.config)?;
        }
        Ok(())
    }
}

impl EntityIndex {
    /// Makes `chunk`'s cells the static winners where their row ids are the greatest, and
    /// returns the static chunks left answering for nothing (possibly `chunk` itself).
    #[expect(
        clippy::cast_possible_truncation,
        reason = "columns < 2^32, checked in Chunk::from_raw"
    )]
    fn insert_static(&mut self, chunk: &Arc<Chunk>) -> Vec<Arc<Chunk>> {
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
    fn insert_temporal(&mut self, chunk: &Arc<Chunk>) -> i64 {
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
    fn remove_static(&mut self, id: ChunkId) {
        self.static_chunks.remove(&id);
        self.static_winners
            .retain(|_, winner| winner.chunk.id() != id);
    }

    /// Forgets a temporal chunk from every (timeline, component) index and from the
    /// compaction candidates.
    /// Returns how much the indices' extra heap grew (negative: shrank).
    fn remove_temporal(&mut self, chunk: &Chunk, config: &crate::StoreConfig) -> i64 {
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

    fn sanity_check(
        &self,
        path: &EntityPath,
        chunks: &ahash::HashMap<ChunkId, StoredChunk>,
        config: &StoreConfig,
    ) -> Result<(), String> {
        let Self {
            element_types,
            static_winners,
            static_chunks,
            temporal_per_timeline_per_component,
            chunk_ids,
            max_row_id,
            pending,
            large_index_bytes,
            stats: _,
            ledger: _,
        } = self;
        let counted = self.extra_index_heap_bytes();
        if *large_index_bytes != counted {
            return Err(format!(
                "{path}: large indices' bytes are kept up to date ({large_index_bytes} kept, \
                 {counted} counted)"
            ));
        }
        if chunk_ids.is_empty()
            || chunk_ids
                .iter()
                .any(|id| chunks.get(id).is_none_or(|s| s.chunk.entity_path() != path))
        {
            return Err(format!("{path}: its chunk ids are non-empty and its own"));
        }
        if chunk_ids
            .iter()
            .filter_map(|id| chunks.get(id))
            .any(|s| s.chunk.row_id_range().1 > *max_row_id)
        {
            return Err(format!(
                "{path}: max_row_id bounds the row ids of its chunks"
            ));
        }
        check_component_types(path, element_types, chunk_ids, chunks)?;
        pending.sanity_check(path, chunks, config)?;
        let mut wins: ahash::HashMap<ChunkId, usize> = ahash::HashMap::default();
        for (component, winner) in static_winners.iter() {
            *wins.entry(winner.chunk.id()).or_default() += 1;
            let column = winner
                .chunk
                .components()
                .get(winner.component_column as usize);
            if column.map(crate::ComponentColumn::name) != Some(component)
                || column.and_then(|c| c.max_row_id_cell(winner.chunk.row_ids()))
                    != Some((winner.row_id, winner.row))
            {
                return Err(format!(
                    "{path}: static winner of {component} is its chunk's best cell"
                ));
            }
        }
        for (id, (chunk, num_won)) in static_chunks {
            if wins.get(id).copied().unwrap_or(0) != *num_won || *num_won == 0 {
                return Err(format!(
                    "{path}: static chunk {id} answers for the components it is counted for"
                ));
            }
            if !chunks.contains_key(id) || !chunk.is_static() || chunk.entity_path() != path {
                return Err(format!(
                    "{path}: static chunk {id} is a static chunk of the store"
                ));
            }
        }
        for (timeline, per_component) in temporal_per_timeline_per_component.iter() {
            for (component, index) in per_component.iter() {
                index.sanity_check()?;
                if !element_types.contains_key(component) || index.is_empty() {
                    return Err(format!(
                        "{path}: index of {component} on {timeline} is typed and non-empty"
                    ));
                }
                for entry in index.chunks() {
                    if !chunks.contains_key(&entry.chunk.id()) || entry.chunk.entity_path() != path
                    {
                        return Err(format!(
                            "{path}: indexed chunk {} is the store's",
                            entry.chunk.id()
                        ));
                    }
                }
            }
        }
        Ok(())
    }
}

/// A chunk marked by a rewrite of `compact()` is temporal and one of at most as many as
/// that rewrite made (part of [`ChunkStore::sanity_check`]; `seen` counts per rewrite).
fn check_rewrite_mark(
    chunk: &Chunk,
    mark: RewriteMark,
    num_rewrites: u64,
    seen: &mut ahash::HashMap<u64, usize>,
) -> Result<(), String> {
    let pieces = seen.entry(mark.rewrite).or_insert(0);
    *pieces += 1;
    if chunk.is_static() || *pieces > mark.num_pieces || mark.rewrite >= num_rewrites {
        return Err(format!(
            "{}: a rewrite's mark is on at most as many temporal chunks as it made",
            chunk.id()
        ));
    }
    Ok(())
}

/// Each component an entity knows has the type of its chunks' columns and is counted once
/// per chunk that has its column; no other is known (part of the entity's sanity check).
fn check_component_types(
    path: &EntityPath,
    element_types: &BTreeMap<ComponentName, ComponentType>,
    chunk_ids: &ahash::HashSet<ChunkId>,
    chunks: &ahash::HashMap<ChunkId, StoredChunk>,
) -> Result<(), String> {
    let mut columns_per_component: BTreeMap<&ComponentName, (&DataType, usize)> = BTreeMap::new();
    for stored in chunk_ids.iter().filter_map(|id| chunks.get(id)) {
        for column in stored.chunk.components() {
            let counted = columns_per_component
                .entry(column.name())
                .or_insert((column.element_type(), 0));
            counted.1 += 1;
        }
    }
    let types_match = columns_per_component.len() == element_types.len()
        && columns_per_component
            .iter()
            .all(|(name, (data_type, count))| {
                element_types.get(*name).is_some_and(|known| {
                    known.num_chunks == *count && known.element_type.equals_datatype(data_type)
                })
            });
    if types_match {
        Ok(())
    } else {
        Err(format!(
            "{path}: the component types are those of its chunks' columns, each counted once \
             per chunk"
        ))
    }
}

/// A Clear column holds booleans, and each of its non-null cells exactly one non-null
/// boolean (SEMANTICS.md section 5): the only shape that says whether a Clear is recursive.
fn check_clear_cells(chunk: &Chunk, column: &crate::ComponentColumn) -> Result<(), InsertError> {
    let list = column.list_array();
    if *column.element_type() != DataType::Boolean {
        return Err(InsertError::ClearNotBoolean {
            chunk_id: chunk.id(),
            data_type: column.element_type().clone(),
        });
    }
    let offsets = list.value_offsets();
    for row in (0..list.len()).filter(|&row| list.is_valid(row)) {
        let (start, end) = (offsets[row], offsets[row + 1]);
        let instances = usize::try_from(end - start).unwrap_or(0);
        let problem = if instances != 1 {
            Some(InsertError::MalformedClear {
                chunk_id: chunk.id(),
                entity_path: chunk.entity_path().clone(),
                row,
                instances,
            })
        } else if usize::try_from(start).is_ok_and(|flag| list.values().is_null(flag)) {
            Some(InsertError::NullClearFlag {
                chunk_id: chunk.id(),
                entity_path: chunk.entity_path().clone(),
                row,
            })
        } else {
            None
        };
        if let Some(problem) = problem {
            return Err(problem);
        }
    }
    Ok(())
}

/// A deterministic listing of the store's chunks, sorted by entity then chunk id, so that
/// changes to what a store holds are reviewable as text.
impl fmt::Display for ChunkStore {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut chunks: Vec<&Arc<Chunk>> = self.chunks().collect();
        chunks.sort_by(|a, b| (a.entity_path(), a.id()).cmp(&(b.entity_path(), b.id())));
        writeln!(f, "ChunkStore: {} chunks", chunks.len())?;
        for chunk in chunks {
            write!(
                f,
                "  {} {} rows={}",
                chunk.entity_path(),
                chunk.id(),
                chunk.num_rows()
            )?;
            for column in chunk.time_columns() {
                let (lo, hi) = column.time_range();
                write!(f, " {}=[{lo}, {hi}]", column.timeline().name())?;
            }
            let names: Vec<&str> = chunk
                .components()
                .iter()
                .map(|c| c.name().as_str())
                .collect();
            writeln!(f, " components={names:?}")?;
        }
        Ok(())
    }
}

/// `after − before` for byte counts far below `i64::MAX`.
fn signed_difference(after: u64, before: u64) -> i64 {
    i64::try_from(i128::from(after) - i128::from(before)).unwrap_or(0)
}
