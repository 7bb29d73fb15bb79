//! Insertion (SEMANTICS.md sections 2, 5 and 6): [`ChunkStore::insert`] validates the whole
//! chunk against the store first and only then mutates, so a rejected chunk leaves no
//! trace; rows the store already holds are left out ([`crate::dedup`]); a temporal chunk
//! goes through compaction on insert ([`crate::compaction`]) unless it is off.

use std::sync::Arc;

use arrow_array::Array;
use arrow_schema::DataType;

use crate::chunk::RowSource;
use std::fmt;

use crate::dedup::NewRows;
use crate::{Chunk, ChunkStore, StoreEvent};
use crate::{ChunkId, EntityPath, TimeType};

/// What [`ChunkStore::validate`] learned of a valid chunk.
struct Validated {
    /// Does the store already know every timeline of the chunk?
    timelines_known: bool,
    /// Could the store hold one of its rows already (see [`crate::dedup`])? Not when none
    /// of its row ids is within those of its entity.
    may_hold_rows: bool,
}

impl ChunkStore {
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
        chunk.touch_for_insert();
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
                if self.view.time_types.get(timeline.name()).is_none() {
                    Arc::make_mut(&mut self.view.time_types)
                        .insert(Arc::clone(timeline.name_arc()), timeline.time_type());
                }
            }
        }
        self.view.stats.rows_inserted += chunk.num_rows() as u64;
        self.view.stats.payload_bytes_inserted += chunk.payload_bytes();

        let mut events = Vec::with_capacity(1);
        if chunk.is_static() || !self.config.compact_on_insert {
            self.add_chunk(chunk, &mut events);
        } else {
            self.insert_compacting(chunk, &mut events);
        }
        Ok(self.finish_mutation(events))
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
                && !crate::chunk::equal_element_types(existing, incoming)
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

/// A valid chunk could not be inserted because it conflicts with the store's contents.
/// The store is left unchanged.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub enum InsertError {
    /// The chunk uses a timeline name with another type than the store knows it by.
    TimelineTypeConflict {
        /// The chunk.
        chunk_id: ChunkId,
        /// The timeline.
        timeline: String,
        /// The type the store knows.
        existing: TimeType,
        /// The type in the chunk.
        incoming: TimeType,
    },
    /// The chunk's data for a component has another Arrow type than that entity's earlier
    /// data for it.
    ComponentTypeConflict {
        /// The chunk.
        chunk_id: ChunkId,
        /// The entity.
        entity_path: EntityPath,
        /// The component.
        component: String,
        /// The element type the store knows.
        existing: DataType,
        /// The element type in the chunk.
        incoming: DataType,
    },
    /// A `Clear:is_recursive` column whose elements are not booleans.
    ClearNotBoolean {
        /// The chunk.
        chunk_id: ChunkId,
        /// The element type found.
        data_type: DataType,
    },
    /// A `Clear:is_recursive` cell that is not exactly one boolean: a Clear says once
    /// whether it is recursive (a null cell, meaning "no Clear in this row", is fine).
    MalformedClear {
        /// The chunk.
        chunk_id: ChunkId,
        /// Its entity.
        entity_path: EntityPath,
        /// The row (0-based).
        row: usize,
        /// How many instances the cell holds (not 1).
        instances: usize,
    },
    /// A `Clear:is_recursive` cell whose one boolean is null: neither flat nor recursive.
    NullClearFlag {
        /// The chunk.
        chunk_id: ChunkId,
        /// Its entity.
        entity_path: EntityPath,
        /// The row (0-based).
        row: usize,
    },
    /// The store holds a chunk with this id and other contents. Chunk ids name one chunk:
    /// the same chunk inserted again changes nothing, another one under its id is refused.
    ChunkIdConflict {
        /// The id both chunks carry.
        chunk_id: ChunkId,
        /// The entity of the chunk the store holds.
        held_entity: EntityPath,
        /// The entity of the chunk refused.
        incoming_entity: EntityPath,
    },
}

impl fmt::Display for InsertError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::TimelineTypeConflict {
                chunk_id,
                timeline,
                existing,
                incoming,
            } => write!(
                f,
                "{chunk_id}: timeline {timeline:?} is {incoming:?} here but {existing:?} in the store"
            ),
            Self::ComponentTypeConflict {
                chunk_id,
                entity_path,
                component,
                existing,
                incoming,
            } => {
                write!(
                    f,
                    "{chunk_id}: component {component:?} of {entity_path} has element type \
                     {incoming} here but {existing} in the store"
                )
            }
            Self::ClearNotBoolean {
                chunk_id,
                data_type,
            } => write!(
                f,
                "{chunk_id}: `Clear:is_recursive` must hold booleans, found {data_type}"
            ),
            Self::MalformedClear {
                chunk_id,
                entity_path,
                row,
                instances,
            } => write!(
                f,
                "{chunk_id} ({entity_path}): the `Clear:is_recursive` cell of row {row} holds \
                 {instances} booleans, not one"
            ),
            Self::NullClearFlag {
                chunk_id,
                entity_path,
                row,
            } => write!(
                f,
                "{chunk_id} ({entity_path}): the `Clear:is_recursive` cell of row {row} holds a \
                 null boolean"
            ),
            Self::ChunkIdConflict {
                chunk_id,
                held_entity,
                incoming_entity,
            } => write!(
                f,
                "{chunk_id}: the store holds another chunk with this id (of {held_entity}); \
                 refused the one of {incoming_entity}"
            ),
        }
    }
}

impl std::error::Error for InsertError {}
