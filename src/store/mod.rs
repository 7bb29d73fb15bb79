//! [`ChunkStore`]: owns the chunks and every index over them.
//!
//! The store's core lives here, below everything that changes or reads it through its
//! methods elsewhere (insertion in [`crate::insert`], compaction, garbage collection,
//! drops, queries). Every mutation goes through two primitives of [`membership`],
//! `add_chunk` and `remove_chunk`, which keep the indices, the figures and the event list
//! in step; [`sanity`] checks that they did.

mod buffer;
use buffer::BufferColumns;
pub(crate) use buffer::Fan;
mod config;
mod entity;
mod entity_table;
mod events;
mod membership;
mod pending;
mod sanity;
mod view;

use std::fmt;
use std::sync::Arc;

use crate::ordered::OrderedSet;
use crate::small_map::SmallMap;
use crate::stats::StoreLedgers;
use crate::{Chunk, ChunkId, EntityPath, RowId, TimeInt, TimeRange};

pub use config::{ConfigError, StoreConfig};
pub(crate) use entity::{EntityIndex, EntityMut};
use events::Subscribers;
pub use events::{DeletionReason, StoreEvent};
pub(crate) use membership::Joining;
pub(crate) use pending::{RewriteMark, SettledRun};
pub use view::StoreView;
pub(crate) use view::{EntityView, EntityViews};

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
    /// Is it in its entity's write buffer (`store/buffer.rs`)? Then it is in no index and
    /// no other compaction group, and it leaves the buffer only as part of a full fan, or
    /// when collected or dropped.
    pub buffered: bool,
    /// The on-demand compaction that wrote the chunk, if one did: `compact()` leaves alone
    /// a group that is exactly what one of its rewrites made (see
    /// [`RewriteMark`]).
    pub rewritten_by: Option<RewriteMark>,
}

/// Temporal chunks of one timeline by least and greatest time, across entities: what
/// time-ordered garbage collection and range drops walk.
#[derive(Clone, Debug, Default)]
pub(crate) struct TimelineChunks {
    pub by_min_time: OrderedSet<(TimeInt, ChunkId)>,
    pub by_max_time: OrderedSet<(TimeInt, ChunkId)>,
}

/// A temporal chunk's key in the store-wide order by least row id.
pub(crate) fn row_id_order_key(chunk: &Chunk) -> (RowId, ChunkId) {
    (chunk.row_id_range().0, chunk.id())
}

/// A temporal chunk's keys in its timelines' orders: per time column, the timeline's name
/// and the chunk's keys by least and by greatest time. What the orders are kept, taken
/// apart and rebuilt by (`store/membership.rs`).
pub(crate) fn time_order_keys(
    chunk: &Chunk,
) -> impl Iterator<Item = (&Arc<str>, (TimeInt, ChunkId), (TimeInt, ChunkId))> + '_ {
    let id = chunk.id();
    chunk.time_columns().iter().map(move |column| {
        let bounds = column.time_range();
        (
            column.timeline().name_arc(),
            (bounds.min(), id),
            (bounds.max(), id),
        )
    })
}

/// The writer's part of each entity by path. A hashbrown map for its `entry_ref`: a write
/// finds or makes its entity in one lookup. Keyed by ahash, drawn per process, not by the
/// path's own public-seeded hash (see `docs/performance-log.md` on `PathMap`).
pub(crate) type EntityMap = hashbrown::HashMap<EntityPath, EntityIndex, ahash::RandomState>;

/// An in-memory store of chunks, answering latest-at and range queries.
///
/// Every query is a method of [`StoreView`], which the store dereferences to (as `String`
/// does to `str`); [`ChunkStore::snapshot`] freezes that view in O(1), and
/// [`SharedStore`](crate::SharedStore) publishes one after every write for readers on
/// other threads. See the crate documentation for examples.
#[derive(Clone, Debug, Default)]
pub struct ChunkStore {
    pub(crate) config: StoreConfig,
    /// What queries read: shared with snapshots, copied on write where they still hold it.
    pub(crate) view: StoreView,
    pub(crate) chunks: ahash::HashMap<ChunkId, StoredChunk>,
    /// The writer's part of each entity (its view is in `view.entities`).
    pub(crate) entities: EntityMap,
    /// Temporal chunks by least row id: the garbage collector's default order.
    pub(crate) temporal_by_row_id: OrderedSet<(RowId, ChunkId)>,
    /// Temporal chunks by least and by greatest time, per timeline (a store has few: a
    /// short vector, no hashing of the name per chunk that joins or leaves).
    pub(crate) temporal_per_timeline: SmallMap<Arc<str>, TimelineChunks>,
    /// Temporal chunks outside the store-wide orders (see [`StoredChunk::in_global_orders`]).
    pub(crate) num_outside_global_orders: usize,
    /// Are the store-wide orders set aside, empty, while one mutation moves most chunks
    /// ([`ChunkStore::set_global_orders_aside`])? Never between mutations.
    pub(crate) global_orders_set_aside: bool,
    /// How many rewrites `compact()` has made (it numbers them; see [`RewriteMark`]).
    pub(crate) num_rewrites: u64,
    pub(crate) ledgers: StoreLedgers,
    /// Public mutations made so far: the debug sanity check's schedule.
    pub(crate) num_mutations: u64,
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

    /// Ends every public mutation: counts it, checks the whole store on the debug
    /// schedule ([`ChunkStore::debug_check_on_schedule`]), then hands its events to the
    /// subscribers, and back to the caller.
    pub(crate) fn finish_mutation(&mut self, events: Vec<StoreEvent>) -> Vec<StoreEvent> {
        self.num_mutations += 1;
        self.debug_check_on_schedule();
        self.announce(&events);
        events
    }

    /// Hands `events` to the subscribers (none if there are none): what
    /// [`ChunkStore::finish_mutation`] does last, and what a mutation reporting its events
    /// in parts does for each part.
    pub(crate) fn announce(&self, events: &[StoreEvent]) {
        if !events.is_empty() {
            for subscriber in &self.subscribers.0 {
                subscriber(events);
            }
        }
    }

    /// The chunk with this id, if the store holds it.
    pub fn chunk(&self, id: ChunkId) -> Option<&Arc<Chunk>> {
        self.chunks.get(&id).map(|stored| &stored.chunk)
    }

    /// Every chunk, in no particular order: the writer's chunk map, O(1) per chunk.
    /// ([`StoreView::chunks`], which a store also answers, lists them sorted, as a
    /// snapshot does.)
    pub fn chunks_unordered(&self) -> impl Iterator<Item = &Arc<Chunk>> {
        self.chunks.values().map(|stored| &stored.chunk)
    }

    /// Number of chunks, static and temporal.
    pub fn num_chunks(&self) -> usize {
        self.chunks.len()
    }

    /// The least and greatest time the store holds data at on `timeline`, or `None` if it
    /// holds none there.
    ///
    /// Cost: O(1) from the store-wide time orders, plus a look at the small chunks
    /// compaction keeps waiting (O(entities) when there are any). (A snapshot's
    /// [`StoreView::time_range`] has no such orders and walks its indices.)
    pub fn time_range(&self, timeline: &str) -> Option<TimeRange> {
        let ordered = self.temporal_per_timeline.get(timeline).and_then(|chunks| {
            let (min, _) = chunks.by_min_time.iter().next()?;
            let (max, _) = chunks.by_max_time.iter().next_back()?;
            Some(TimeRange::new(*min, *max))
        });
        self.chunks_outside_global_orders()
            .into_iter()
            .filter_map(|chunk| chunk.time_column(timeline))
            .map(crate::TimeColumn::time_range)
            .chain(ordered)
            .reduce(TimeRange::union)
    }

    /// An entity's writer part and its view, read-only: [`entity_mut`]'s one search by
    /// path (in the writer's map, whose part holds the view's slot), without the copy.
    #[expect(
        clippy::inline_always,
        reason = "measured: left to the compiler it stays a call of its own, 24 instructions \
                  more a candidate in a garbage collection's plan (callgrind, gc_half)"
    )]
    #[inline(always)]
    pub(crate) fn entity(&self, path: &EntityPath) -> Option<(&EntityIndex, &EntityView)> {
        let index = self.entities.get(path)?;
        let view = self.view.entities.at(index.slot)?;
        Some((index, &**view))
    }

    /// Forgets an entity, writer part and view.
    pub(crate) fn forget_entity(&mut self, path: &EntityPath) {
        self.entities.remove(path);
        self.view.entities.remove(path);
    }
}

/// An entity's writer part and its own view (copied first if a snapshot shares it), created
/// if `create` and missing. A function of the two maps rather than a method, so that the
/// caller keeps the rest of the store to borrow.
///
/// Only the writer's map is searched by path: its part of the entity holds the entity's
/// slot, by which the view's table is walked (see `store/entity_table.rs`), once per call.
pub(crate) fn entity_mut<'a>(
    entities: &'a mut EntityMap,
    views: &'a mut EntityViews,
    path: &EntityPath,
    create: bool,
) -> Option<EntityMut<'a>> {
    // One lookup either way; the path is cloned only for a new entity.
    let index = if create {
        entities.entry_ref(path).or_insert_with(|| EntityIndex {
            slot: views.add(path.clone()),
            ..EntityIndex::default()
        })
    } else {
        entities.get_mut(path)?
    };
    let view = views.at_mut(index.slot)?;
    Some(EntityMut {
        index,
        view: Arc::make_mut(view),
    })
}

/// Every query of the store is a method of its current view.
impl std::ops::Deref for ChunkStore {
    type Target = StoreView;

    fn deref(&self) -> &StoreView {
        &self.view
    }
}

/// A deterministic listing of the store's chunks, sorted by entity then chunk id, so that
/// changes to what a store holds are reviewable as text.
impl fmt::Display for ChunkStore {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut chunks: Vec<&Arc<Chunk>> = self.chunks_unordered().collect();
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
                let bounds = column.time_range();
                let (lo, hi) = (bounds.min(), bounds.max());
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
