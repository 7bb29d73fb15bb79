//! [`ChunkStore`]: owns the chunks and every index over them. Insertion validates the whole
//! chunk against the store first and only then mutates, so a rejected chunk leaves no trace.

use std::collections::BTreeMap;
use std::fmt;
use std::sync::Arc;

use arrow_schema::DataType;

use crate::clear::ClearIndex;
use crate::error::InsertError;
use crate::index::{IndexedChunk, TemporalComponentIndex};
use crate::{Chunk, ChunkId, ComponentName, EntityPath, RowId, TimeType};

/// Debug builds check the whole store after an insert while it holds at most this many
/// chunks.
const DEBUG_SANITY_CHECK_MAX_CHUNKS: usize = 1024;

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
    /// The element type each component was first seen with (static and temporal).
    pub element_types: BTreeMap<ComponentName, DataType>,
    pub static_winners: ahash::HashMap<ComponentName, StaticWinner>,
    /// How many components each static chunk of this entity answers for; a chunk that
    /// answers for none is invisible and leaves the store.
    pub static_chunks: ahash::HashMap<ChunkId, (Arc<Chunk>, usize)>,
    pub temporal_per_timeline_per_component:
        ahash::HashMap<Arc<str>, ahash::HashMap<ComponentName, TemporalComponentIndex>>,
}

/// Totals, kept up to date by every mutation, O(1) to read.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StoreStats {
    /// Static chunks held.
    pub num_static_chunks: u64,
    /// Rows in static chunks.
    pub num_static_rows: u64,
    /// Heap bytes of static chunks.
    pub static_heap_bytes: u64,
    /// Temporal chunks held.
    pub num_temporal_chunks: u64,
    /// Rows in temporal chunks.
    pub num_temporal_rows: u64,
    /// Heap bytes of temporal chunks.
    pub temporal_heap_bytes: u64,
}

impl StoreStats {
    fn add(&mut self, chunk: &Chunk, sign: i64) {
        let apply = |total: &mut u64, amount: u64| {
            *total = if sign > 0 {
                *total + amount
            } else {
                total.saturating_sub(amount)
            };
        };
        let (chunks, rows, bytes) = if chunk.is_static() {
            (
                &mut self.num_static_chunks,
                &mut self.num_static_rows,
                &mut self.static_heap_bytes,
            )
        } else {
            (
                &mut self.num_temporal_chunks,
                &mut self.num_temporal_rows,
                &mut self.temporal_heap_bytes,
            )
        };
        apply(chunks, 1);
        apply(rows, chunk.num_rows() as u64);
        apply(bytes, chunk.heap_size_bytes());
    }
}

/// An in-memory store of chunks, answering latest-at and range queries.
///
/// See the crate documentation for an example.
#[derive(Clone, Debug, Default)]
pub struct ChunkStore {
    chunks: ahash::HashMap<ChunkId, Arc<Chunk>>,
    time_types: ahash::HashMap<Arc<str>, TimeType>,
    pub(crate) entities: ahash::HashMap<EntityPath, EntityIndex>,
    pub(crate) clears: ClearIndex,
    stats: StoreStats,
}

impl ChunkStore {
    /// An empty store.
    pub fn new() -> Self {
        Self::default()
    }

    /// Inserts a chunk and returns what changed: its addition, and the deletion of any
    /// static chunk it made invisible (possibly itself, if newer static data shadows it).
    /// Inserting a chunk id the store already holds changes nothing.
    ///
    /// # Errors
    /// If the chunk's timelines or component types conflict with the store; the store is
    /// then unchanged.
    pub fn insert(&mut self, chunk: impl Into<Arc<Chunk>>) -> Result<Vec<StoreEvent>, InsertError> {
        let chunk = chunk.into();
        if self.chunks.contains_key(&chunk.id()) {
            return Ok(Vec::new());
        }
        self.validate(&chunk)?;

        for column in chunk.time_columns() {
            let timeline = column.timeline();
            self.time_types
                .entry(Arc::clone(timeline.name_arc()))
                .or_insert(timeline.time_type());
        }
        let entity = self
            .entities
            .entry(chunk.entity_path().clone())
            .or_default();
        for column in chunk.components() {
            entity
                .element_types
                .entry(column.name().clone())
                .or_insert_with(|| column.element_type().clone());
        }
        self.clears.insert_chunk(&chunk);
        self.chunks.insert(chunk.id(), Arc::clone(&chunk));
        self.stats.add(&chunk, 1);

        let mut events = vec![StoreEvent::Addition(Arc::clone(&chunk))];
        if chunk.is_static() {
            for overwritten in entity.insert_static(&chunk) {
                self.chunks.remove(&overwritten.id());
                self.stats.add(&overwritten, -1);
                events.push(StoreEvent::Deletion {
                    chunk: overwritten,
                    reason: DeletionReason::Overwrite,
                });
            }
        } else {
            entity.insert_temporal(&chunk);
        }
        // The full check costs O(store): debug builds run it while the store is small, which
        // is where unit tests live; the model test calls it after every step regardless.
        if cfg!(debug_assertions) && self.chunks.len() <= DEBUG_SANITY_CHECK_MAX_CHUNKS {
            debug_assert!(self.sanity_check().is_ok(), "{:?}", self.sanity_check());
        }
        Ok(events)
    }

    /// Every check `insert` makes before touching anything.
    fn validate(&self, chunk: &Chunk) -> Result<(), InsertError> {
        for column in chunk.time_columns() {
            let timeline = column.timeline();
            if let Some(&existing) = self.time_types.get(timeline.name())
                && existing != timeline.time_type()
            {
                return Err(InsertError::TimelineTypeConflict {
                    chunk_id: chunk.id(),
                    timeline: timeline.name().to_owned(),
                    existing,
                    incoming: timeline.time_type(),
                });
            }
        }
        let entity = self.entities.get(chunk.entity_path());
        for column in chunk.components() {
            let incoming = column.element_type();
            if column.name().is_clear() && *incoming != DataType::Boolean {
                return Err(InsertError::ClearNotBoolean {
                    chunk_id: chunk.id(),
                    data_type: incoming.clone(),
                });
            }
            if let Some(existing) = entity.and_then(|e| e.element_types.get(column.name()))
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
        Ok(())
    }

    /// The chunk with this id, if the store holds it.
    pub fn chunk(&self, id: ChunkId) -> Option<&Arc<Chunk>> {
        self.chunks.get(&id)
    }

    /// Every chunk, in no particular order.
    pub fn chunks(&self) -> impl Iterator<Item = &Arc<Chunk>> {
        self.chunks.values()
    }

    /// Number of chunks, static and temporal.
    pub fn num_chunks(&self) -> usize {
        self.chunks.len()
    }

    /// Totals of chunks, rows and heap bytes.
    pub fn stats(&self) -> StoreStats {
        self.stats
    }

    /// The type a timeline has in this store, if any chunk used it.
    pub fn time_type(&self, timeline: &str) -> Option<TimeType> {
        self.time_types.get(timeline).copied()
    }

    /// Every entity that holds data, sorted.
    pub fn entity_paths(&self) -> Vec<EntityPath> {
        let mut paths: Vec<EntityPath> = self.entities.keys().cloned().collect();
        paths.sort();
        paths
    }

    /// The components an entity has data for (static or temporal), sorted by name.
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
    }

    /// Checks every invariant of the store and its indices. Cheap enough for tests to call
    /// after every mutation; debug builds call it after every insert.
    ///
    /// # Errors
    /// A description of the first broken invariant: a bug in this crate.
    pub fn sanity_check(&self) -> Result<(), String> {
        let Self {
            chunks,
            time_types,
            entities,
            clears,
            stats,
        } = self;
        let mut expected = StoreStats::default();
        for chunk in chunks.values() {
            chunk.sanity_check()?;
            expected.add(chunk, 1);
            for column in chunk.time_columns() {
                let timeline = column.timeline();
                if time_types.get(timeline.name()) != Some(&timeline.time_type()) {
                    return Err(format!(
                        "{}: timeline {:?} has the store's type",
                        chunk.id(),
                        timeline
                    ));
                }
            }
            if !entities.contains_key(chunk.entity_path()) {
                return Err(format!("{}: its entity is indexed", chunk.id()));
            }
        }
        if expected != *stats {
            return Err(format!(
                "stats match the chunks: kept {stats:?}, counted {expected:?}"
            ));
        }
        for (path, entity) in entities {
            entity.sanity_check(path, chunks)?;
        }
        clears.sanity_check()
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
            let Some((row_id, row)) = column.max_row_id_cell() else {
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
    fn insert_temporal(&mut self, chunk: &Arc<Chunk>) {
        for (time_position, time_column) in chunk.time_columns().iter().enumerate() {
            let per_component = self
                .temporal_per_timeline_per_component
                .entry(Arc::clone(time_column.timeline().name_arc()))
                .or_default();
            for (component_position, column) in chunk.components().iter().enumerate() {
                let Some(bounds) = column.bounds(time_position) else {
                    continue;
                };
                per_component
                    .entry(column.name().clone())
                    .or_default()
                    .insert(IndexedChunk {
                        chunk: Arc::clone(chunk),
                        time_column: time_position as u32,
                        component_column: component_position as u32,
                        bounds,
                    });
            }
        }
    }

    fn sanity_check(
        &self,
        path: &EntityPath,
        chunks: &ahash::HashMap<ChunkId, Arc<Chunk>>,
    ) -> Result<(), String> {
        let Self {
            element_types,
            static_winners,
            static_chunks,
            temporal_per_timeline_per_component,
        } = self;
        let mut wins: ahash::HashMap<ChunkId, usize> = ahash::HashMap::default();
        for (component, winner) in static_winners {
            *wins.entry(winner.chunk.id()).or_default() += 1;
            let column = winner
                .chunk
                .components()
                .get(winner.component_column as usize);
            if column.map(crate::ComponentColumn::name) != Some(component)
                || column.and_then(crate::ComponentColumn::max_row_id_cell)
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
        for (timeline, per_component) in temporal_per_timeline_per_component {
            for (component, index) in per_component {
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

/// A deterministic listing of the store's chunks, sorted by entity then chunk id, so that
/// changes to what a store holds are reviewable as text.
impl fmt::Display for ChunkStore {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut chunks: Vec<&Arc<Chunk>> = self.chunks.values().collect();
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
