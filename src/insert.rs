//! Insertion (SEMANTICS.md sections 2, 5 and 6): [`ChunkStore::insert`] validates the whole
//! chunk against the store first and only then mutates, so a rejected chunk leaves no
//! trace; rows the store already holds are left out ([`crate::held`]); a temporal chunk
//! goes through compaction on insert ([`crate::compaction`]) unless it is off.

use std::sync::Arc;

use arrow_array::Array;
use arrow_schema::DataType;

use crate::chunk::RowSource;
use crate::error::InsertError;
use crate::held::NewRows;
use crate::{Chunk, ChunkStore, StoreEvent};

/// What [`ChunkStore::validate`] learned of a valid chunk.
struct Validated {
    /// Does the store already know every timeline of the chunk?
    timelines_known: bool,
    /// Could the store hold one of its rows already (see [`crate::held`])? Not when none
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
                Arc::make_mut(&mut self.view.time_types)
                    .entry(Arc::clone(timeline.name_arc()))
                    .or_insert(timeline.time_type());
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
