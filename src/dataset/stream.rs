//! A dataset's dataframe: each segment's own dataframe (SEMANTICS.md section 9, fill within
//! the segment), its segment id prepended, its columns placed in the dataset's table, the
//! segments one after another in id order.
//!
//! The table's columns are the union of the segments' (planned once, before the first
//! row: a stream's schema comes first), in the order a dataframe orders its columns: the
//! segment id, then the index and every other timeline by name, then the data columns by
//! entity (part by part, in natural order) and component. A column a segment lacks is
//! null in its rows. Planning loads each segment whose data is on the index (a segment
//! without it gives no rows, as a dataframe of it would be refused, and is never loaded);
//! the segment cache keeps what fits for the rows' pass.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::sync::atomic::AtomicU64;
use std::thread::JoinHandle;

use arrow_array::{ArrayRef, RecordBatch, RecordBatchReader, StringArray, new_null_array};
use arrow_schema::{ArrowError, DataType, Field, FieldRef, Schema, SchemaRef};

use super::{Dataset, DatasetError};
use crate::{
    ComponentName, DataframeQuery, DataframeStream, EntityPath, SEGMENT_ID_COLUMN, UnknownTimeline,
};

impl Dataset {
    /// The dataframe of every segment on `query`'s index, as one table: see the module
    /// docs of `dataset/stream.rs`. The columns [`DataframeQuery::with_columns`] names are
    /// names of this table (the segment id column is always first).
    ///
    /// # Errors
    /// An index no segment has, a column two segments give different types, a column
    /// named that the table does not have, a segment that cannot be loaded (unless
    /// skipped, [`DatasetOptions::skip_bad`](super::DatasetOptions::skip_bad)).
    pub fn dataframe(&self, query: &DataframeQuery) -> Result<DatasetStream, DatasetError> {
        let index = query.index();
        let with_index: Vec<usize> = (0..self.segments().len())
            .filter(|&n| self.segments()[n].time_type(index).is_some())
            .collect();
        if with_index.is_empty() {
            return Err(DatasetError::UnknownIndex(UnknownTimeline::new(
                index,
                &self.timelines(),
            )));
        }
        let full = query.clone().without_columns();
        // Segments are planned on several threads; what planning read is kept for the
        // rows' pass while it fits the budget (`Dataset::segment_for`).
        let room = AtomicU64::new(self.options().memory_budget);
        let plans = super::in_parallel(&with_index, self.options().threads, |&number| {
            let segment_id = &self.segments()[number].id;
            let (snapshot, keep) = match self.segment_for(number, &full, Some(&room)) {
                Ok(read) => read,
                Err(error) if self.options().skip_bad => {
                    self.warn(format!("skipped segment {segment_id:?}: {error}"));
                    return Ok(None);
                }
                Err(error) => return Err(error),
            };
            let schema =
                snapshot
                    .dataframe_schema(&full)
                    .map_err(|error| DatasetError::Dataframe {
                        segment: segment_id.clone(),
                        error,
                    })?;
            Ok(Some((number, schema, keep.then_some(snapshot))))
        });
        let mut union = SchemaUnion::default();
        let mut planned = Vec::with_capacity(plans.len());
        for plan in plans {
            if let Some((number, schema, kept)) = plan? {
                union.add(&self.segments()[number].id, &schema)?;
                planned.push((number, schema, kept));
            }
        }
        let table = union.schema();
        let schema = match query.columns() {
            None => table,
            Some(names) => project(&table, names)?,
        };
        // Each segment's query asks for the output's columns it has (its rows stay its
        // whole view's).
        let segments = planned
            .into_iter()
            .map(|(number, own, kept)| {
                let columns: Vec<String> = schema
                    .fields()
                    .iter()
                    .skip(1)
                    .filter(|f| own.field_with_name(f.name()).is_ok())
                    .map(|f| f.name().clone())
                    .collect();
                (number, full.clone().with_columns(columns), kept)
            })
            .collect();
        Ok(DatasetStream {
            dataset: self.clone(),
            schema,
            segments,
            next: 0,
            current: None,
            ahead: VecDeque::new(),
        })
    }

    fn warn(&self, warning: String) {
        self.inner.warnings.lock().push(warning);
    }
}

/// The union of the segments' dataframe schemas, each column's field from the first
/// segment (in id order) that has it.
#[derive(Default)]
struct SchemaUnion {
    /// Index columns by name, with the segment that gave each.
    index: HashMap<String, (FieldRef, String)>,
    /// Data columns by name, with their (entity, component) and the segment that gave each.
    data: HashMap<String, (FieldRef, EntityPath, ComponentName, String)>,
}

impl SchemaUnion {
    fn add(&mut self, segment: &str, schema: &Schema) -> Result<(), DatasetError> {
        for field in schema.fields() {
            let metadata = field.metadata();
            let conflict = |first: &str| DatasetError::ColumnTypeConflict {
                column: field.name().clone(),
                first: first.to_owned(),
                second: segment.to_owned(),
            };
            if metadata.get("rerun:kind").map(String::as_str) == Some("index") {
                match self.index.get(field.name()) {
                    Some((held, first)) if held.data_type() != field.data_type() => {
                        return Err(conflict(first));
                    }
                    Some(_) => {}
                    None => {
                        self.index.insert(
                            field.name().clone(),
                            (Arc::clone(field), segment.to_owned()),
                        );
                    }
                }
                continue;
            }
            match self.data.get(field.name()) {
                Some((held, .., first)) if held.data_type() != field.data_type() => {
                    return Err(conflict(first));
                }
                Some(_) => {}
                None => {
                    let entity = metadata
                        .get("rerun:entity_path")
                        .and_then(|path| EntityPath::parse(path).ok())
                        .unwrap_or_else(EntityPath::root);
                    let component = ComponentName::new(
                        metadata
                            .get("rerun:component")
                            .map_or_else(|| field.name().as_str(), String::as_str),
                    );
                    self.data.insert(
                        field.name().clone(),
                        (Arc::clone(field), entity, component, segment.to_owned()),
                    );
                }
            }
        }
        Ok(())
    }

    /// The segment id, the index columns by name, the data columns as a dataframe orders
    /// them (entity part by part in natural order, then component).
    fn schema(self) -> SchemaRef {
        let mut index: Vec<FieldRef> = self.index.into_values().map(|(f, _)| f).collect();
        index.sort_by(|a, b| a.name().cmp(b.name()));
        let mut data: Vec<(FieldRef, EntityPath, ComponentName)> = self
            .data
            .into_values()
            .map(|(f, e, c, _)| (f, e, c))
            .collect();
        data.sort_by(|a, b| a.1.cmp_natural(&b.1).then_with(|| a.2.cmp(&b.2)));
        let mut fields: Vec<FieldRef> = vec![Arc::new(Field::new(
            SEGMENT_ID_COLUMN,
            DataType::Utf8,
            false,
        ))];
        fields.extend(index);
        fields.extend(data.into_iter().map(|(f, ..)| f));
        Arc::new(Schema::new(fields))
    }
}

/// `table` with only the columns `names` names (and the segment id, always first), in
/// the table's order.
fn project(table: &SchemaRef, names: &[String]) -> Result<SchemaRef, DatasetError> {
    if let Some(missing) = names
        .iter()
        .find(|name| table.field_with_name(name).is_err())
    {
        return Err(DatasetError::UnknownColumn {
            name: missing.clone(),
            num_columns: table.fields().len(),
        });
    }
    let kept: Vec<usize> = (0..table.fields().len())
        .filter(|&i| i == 0 || names.contains(table.field(i).name()))
        .collect();
    let projected = table
        .project(&kept)
        .map_err(|_| DatasetError::UnknownColumn {
            name: names.join(", "),
            num_columns: table.fields().len(),
        })?;
    Ok(Arc::new(projected))
}

/// The rows of a [`Dataset::dataframe`]: record batches of one segment each, in segment
/// order. A segment that fails to load while streaming (its file changed or vanished
/// since the dataset opened) is an error naming it, or with `skip_bad` skipped with a
/// warning.
pub struct DatasetStream {
    dataset: Dataset,
    schema: SchemaRef,
    /// The segments that give rows (by number), with each one's own query, and what
    /// planning read of it if that was kept.
    segments: Vec<(usize, DataframeQuery, Option<crate::Snapshot>)>,
    next: usize,
    /// The segment being streamed: its id as a column value, and its stream.
    current: Option<(Arc<str>, DataframeStream<'static>)>,
    /// The next segments' loads, on threads of their own while this one streams (one fewer
    /// than [`DatasetOptions::threads`](super::DatasetOptions::threads)), by position.
    ahead: VecDeque<(usize, JoinHandle<Result<crate::Snapshot, DatasetError>>)>,
}

/// The stream of `query`'s rows in what was read of segment `segment`: of the columns
/// `query` names, those the store holds (what was read for the rows alone may lack a
/// column, which holds no cell in the rows); `None` if it holds nothing on the index.
fn rows_of(
    snapshot: crate::Snapshot,
    query: &DataframeQuery,
    segment: &str,
) -> Result<Option<DataframeStream<'static>>, DatasetError> {
    let failed = |error| DatasetError::Dataframe {
        segment: segment.to_owned(),
        error,
    };
    let every_column = query.clone().without_columns();
    let own = match snapshot.dataframe_schema(&every_column) {
        Ok(own) => own,
        Err(crate::DataframeError::UnknownIndex(_)) => return Ok(None),
        Err(error) => return Err(failed(error)),
    };
    let present: Vec<String> = query
        .columns()
        .unwrap_or_default()
        .iter()
        .filter(|name| own.field_with_name(name).is_ok())
        .cloned()
        .collect();
    snapshot
        .into_dataframe(&every_column.with_columns(present))
        .map(Some)
        .map_err(failed)
}

/// The segment a load ahead read, or its error; a panic (a bug) goes on in this thread.
fn joined(
    handle: JoinHandle<Result<crate::Snapshot, DatasetError>>,
) -> Result<crate::Snapshot, DatasetError> {
    handle
        .join()
        .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
}

impl std::fmt::Debug for DatasetStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DatasetStream")
            .field("segments", &self.segments.len())
            .field("next", &self.next)
            .finish_non_exhaustive()
    }
}

impl DatasetStream {
    /// The table's schema.
    pub fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }

    /// Segments that give rows (those whose data is on the index).
    pub fn num_segments(&self) -> usize {
        self.segments.len()
    }

    /// Starts loading, on threads of their own, the segments after `position` that
    /// planning did not keep, up to one fewer than the dataset's threads.
    fn load_ahead(&mut self, position: usize) {
        let threads = self.dataset.options().threads.max(1);
        let end = (position + threads).min(self.segments.len());
        for ahead in position + 1..end {
            let (number, query, kept) = &self.segments[ahead];
            if kept.is_some() || self.ahead.iter().any(|(p, _)| *p == ahead) {
                continue;
            }
            let (dataset, number, query) = (self.dataset.clone(), *number, query.clone());
            let handle = std::thread::spawn(move || {
                dataset
                    .segment_for(number, &query, None)
                    .map(|(snapshot, _)| snapshot)
            });
            self.ahead.push_back((ahead, handle));
        }
    }

    /// Starts the next segment's stream; `Ok(false)` when there is none.
    fn start_next(&mut self) -> Result<bool, DatasetError> {
        loop {
            let position = self.next;
            if position >= self.segments.len() {
                return Ok(false);
            }
            self.next += 1;
            self.load_ahead(position);
            let loaded_ahead = match self.ahead.front() {
                Some((p, _)) if *p == position => self.ahead.pop_front().map(|(_, h)| h),
                _ => None,
            };
            let (number, query, kept) = &mut self.segments[position];
            let number = *number;
            let id = self.dataset.segments()[number].id.clone();
            let snapshot = match (kept.take(), loaded_ahead) {
                (Some(snapshot), _) => Ok(snapshot),
                (None, Some(handle)) => joined(handle),
                (None, None) => self
                    .dataset
                    .segment_for(number, query, None)
                    .map(|(snapshot, _)| snapshot),
            };
            let query = &self.segments[position].1;
            let started = snapshot.and_then(|snapshot| rows_of(snapshot, query, &id));
            match started {
                Ok(Some(stream)) => {
                    self.current = Some((id.into(), stream));
                    return Ok(true);
                }
                Ok(None) => {} // nothing on the index: no rows
                Err(error) if self.dataset.options().skip_bad => {
                    self.dataset
                        .warn(format!("skipped segment {id:?}: {error}"));
                }
                Err(error) => return Err(error),
            }
        }
    }

    /// A segment's batch in the table's schema.
    fn place(&self, segment: &str, batch: &RecordBatch) -> Result<RecordBatch, ArrowError> {
        let rows = batch.num_rows();
        let mut columns: Vec<ArrayRef> = Vec::with_capacity(self.schema.fields().len());
        columns.push(Arc::new(StringArray::from_iter_values(
            std::iter::repeat_n(segment, rows),
        )));
        for field in self.schema.fields().iter().skip(1) {
            columns.push(match batch.column_by_name(field.name()) {
                Some(column) => Arc::clone(column),
                None => new_null_array(field.data_type(), rows),
            });
        }
        RecordBatch::try_new(Arc::clone(&self.schema), columns)
    }
}

impl Iterator for DatasetStream {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some((segment, stream)) = &mut self.current {
                match stream.next() {
                    Some(Ok(batch)) => {
                        let segment = Arc::clone(segment);
                        return Some(self.place(&segment, &batch));
                    }
                    Some(Err(error)) => return Some(Err(error)),
                    None => self.current = None,
                }
            }
            match self.start_next() {
                Ok(true) => {}
                Ok(false) => return None,
                Err(error) => return Some(Err(ArrowError::ExternalError(Box::new(error)))),
            }
        }
    }
}

impl RecordBatchReader for DatasetStream {
    fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }
}
