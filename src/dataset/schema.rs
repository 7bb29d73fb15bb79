//! The dataset's tables' columns: the union of its segments' (SEMANTICS.md section 15),
//! planned from what each segment's footer lets a query read of it, and each segment's
//! batches placed in them.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::sync::Arc;

use arrow_array::{ArrayRef, RecordBatch, StringArray, new_null_array};
use arrow_schema::{ArrowError, DataType, Field, FieldRef, Schema, SchemaRef};

use super::{Dataset, DatasetError};
use crate::{ChunkTableQuery, ComponentName, DataframeQuery, EntityPath, SEGMENT_ID_COLUMN};

/// The columns of a dataset's tables ([`Dataset::tables`]), each with
/// [`SEGMENT_ID_COLUMN`] first.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct DatasetTables {
    /// Per timeline (by name), the schema of the dataframe on it: the one
    /// [`Dataset::dataframe`] streams for a query of every column.
    pub timelines: BTreeMap<String, SchemaRef>,
    /// The schema of the chunk table (every stored row, `StoreView::chunk_table`): the
    /// chunk, row and entity columns, every timeline, every component by name.
    pub chunks: SchemaRef,
}

impl Dataset {
    /// The columns of the dataset's tables, planned once (and kept) from one chunk of each
    /// (entity, component, timeline) of each segment that adds a column to one of its
    /// tables (by the manifests), read through its footer (a segment without one, or
    /// opened with `skip_bad`, is read whole), on the dataset's threads. A column that a
    /// segment not read here gives another type is the error of the query that reaches
    /// that segment.
    ///
    /// # Errors
    /// A column two segments read here give different types, a segment that cannot be
    /// read (unless skipped, [`DatasetOptions::skip_bad`](super::DatasetOptions::skip_bad)).
    pub fn tables(&self) -> Result<Arc<DatasetTables>, DatasetError> {
        if let Some(tables) = &*self.inner.tables.lock() {
            return Ok(Arc::clone(tables));
        }
        let numbers = self.segments_adding_columns();
        let schemas = super::threads::in_parallel(&numbers, self.options().threads, |&number| {
            let segment = &self.segments()[number];
            match self.segment_tables(number) {
                Ok(tables) => Ok(Some(tables)),
                Err(error) if self.options().skip_bad => {
                    self.warn(format!("skipped segment {:?}: {error}", segment.id));
                    Ok(None)
                }
                Err(error) => Err(error),
            }
        });
        let mut timelines: BTreeMap<String, SchemaUnion> = BTreeMap::new();
        let mut chunks = SchemaUnion::default();
        for (number, schemas) in numbers.iter().zip(schemas) {
            let Some((own_timelines, own_chunks)) = schemas? else {
                continue;
            };
            let id = &self.segments()[*number].id;
            for (timeline, schema) in own_timelines {
                timelines.entry(timeline).or_default().add(id, &schema)?;
            }
            chunks.add(id, &own_chunks)?;
        }
        let tables = Arc::new(DatasetTables {
            timelines: timelines
                .into_iter()
                .map(|(timeline, union)| (timeline, union.schema()))
                .collect(),
            chunks: chunks.chunks_schema(),
        });
        *self.inner.tables.lock() = Some(Arc::clone(&tables));
        Ok(tables)
    }

    /// The segments (by number, in id order) whose columns the tables need read: those
    /// that, by their manifests, add a column (an entity's component on a timeline, or
    /// static) to a table of one of their timelines or to the chunk table. A segment whose
    /// every column the segments before it already give to each of its tables adds
    /// nothing to them (a table's field is the first segment's to have it), so a dataset of
    /// a thousand recordings of one shape reads one. A segment without a footer is always
    /// read (it was read whole on opening, and is usually in the cache).
    fn segments_adding_columns(&self) -> Vec<usize> {
        let numbers: Vec<usize> = (0..self.segments().len()).collect();
        let keys = self.column_keys(&numbers);
        let mut seen: HashMap<String, HashSet<ColumnKey>> = HashMap::new();
        let mut seen_anywhere: HashSet<ColumnKey> = HashSet::new();
        let mut adding = Vec::new();
        for (number, keys) in numbers.into_iter().zip(keys) {
            // A footer that cannot be read: the segment is read, so that its fault is
            // reported (or skipped) where it is.
            let segment = &self.segments()[number];
            let Some(keys) = keys else {
                adding.push(number);
                continue;
            };
            let covered = |given: &HashSet<ColumnKey>| keys.is_subset(given);
            let adds = !covered(&seen_anywhere)
                || segment
                    .timelines
                    .iter()
                    .any(|(t, _)| seen.get(t.name()).is_none_or(|given| !covered(given)));
            if adds {
                for (timeline, _) in &segment.timelines {
                    seen.entry(timeline.name().to_owned())
                        .or_default()
                        .extend(keys.iter().cloned());
                }
                seen_anywhere.extend(keys);
                adding.push(number);
            }
        }
        adding
    }

    /// Per segment (by number), the columns its footer's manifest says it has: each
    /// (entity, component, timeline) it holds, with no timeline for static data. `None`
    /// where the segment is read whole (no footer, or `skip_bad`) or its footer cannot be
    /// read (it is then read, so that its fault is reported, or skipped, where it is).
    /// A dataset in a bucket kept its segments' footers from opening: no request.
    pub(super) fn column_keys(&self, numbers: &[usize]) -> Vec<Option<HashSet<ColumnKey>>> {
        super::threads::in_parallel(numbers, self.options().threads, |&number| {
            self.columns_of(number)
        })
    }

    /// One segment's [`Dataset::column_keys`].
    pub(super) fn columns_of(&self, number: usize) -> Option<HashSet<ColumnKey>> {
        if !self.reads_in_part(number) {
            return None;
        }
        let lazy = self.footer(number).ok()??;
        let mut keys: HashSet<ColumnKey> = HashSet::new();
        for entry in &lazy.manifest().entries {
            for component in &entry.components {
                if entry.is_static || component.ranges.is_empty() {
                    keys.insert((entry.entity_path.clone(), component.name.clone(), None));
                }
                for range in &component.ranges {
                    keys.insert((
                        entry.entity_path.clone(),
                        component.name.clone(),
                        Some(range.timeline.name().to_owned()),
                    ));
                }
            }
        }
        Some(keys)
    }

    /// One segment's dataframe schema on each of its timelines, and its chunk table's.
    fn segment_tables(
        &self,
        number: usize,
    ) -> Result<(Vec<(String, SchemaRef)>, SchemaRef), DatasetError> {
        let segment = &self.segments()[number];
        let failed = |error| DatasetError::Dataframe {
            segment: segment.id.clone(),
            error,
        };
        let of = |snapshot: &crate::Snapshot| -> Result<_, DatasetError> {
            let mut timelines = Vec::with_capacity(segment.timelines.len());
            for (timeline, _) in &segment.timelines {
                let query = DataframeQuery::new(timeline.name());
                let schema = snapshot.dataframe_schema(&query).map_err(failed)?;
                timelines.push((timeline.name().to_owned(), schema));
            }
            let chunks = snapshot
                .chunk_table(&ChunkTableQuery::new().with_row_entities([]))
                .map_err(failed)?
                .schema();
            Ok((timelines, chunks))
        };
        // One chunk of each (entity, component, timeline) gives every column; a timeline
        // that no component is on needs the whole segment (its view's columns are those
        // other timelines give).
        let (snapshot, _) = self.segment_chunks(number, super::prune::columns)?;
        let complete = segment
            .timelines
            .iter()
            .all(|(timeline, _)| snapshot.time_type(timeline.name()).is_some());
        if complete {
            return of(&snapshot);
        }
        let (snapshot, _) = self.loaded_segment(number)?;
        of(&snapshot)
    }
}

/// A column as a segment's manifest names it: an entity's component on a timeline (`None`:
/// static).
pub(super) type ColumnKey = (EntityPath, ComponentName, Option<String>);

/// The union of the segments' dataframe schemas, each column's field from the first
/// segment (in id order) that has it.
#[derive(Default)]
pub(super) struct SchemaUnion {
    /// Index columns by name, with the segment that gave each.
    index: HashMap<String, (FieldRef, String)>,
    /// Data columns by name, with their (entity, component) and the segment that gave each.
    data: HashMap<String, (FieldRef, EntityPath, ComponentName, String)>,
}

impl SchemaUnion {
    pub(super) fn add(&mut self, segment: &str, schema: &Schema) -> Result<(), DatasetError> {
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
    pub(super) fn schema(self) -> SchemaRef {
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

    /// The segment id, a chunk table's id columns, its index columns by name, the
    /// components by name.
    pub(super) fn chunks_schema(self) -> SchemaRef {
        const IDS: [&str; 3] = ["entity_path", "chunk_id", "row_id"];
        let mut index: Vec<FieldRef> = self.index.into_values().map(|(f, _)| f).collect();
        index.sort_by(|a, b| a.name().cmp(b.name()));
        let mut data: Vec<FieldRef> = self.data.into_values().map(|(f, ..)| f).collect();
        data.sort_by_key(|f| {
            let id = IDS.iter().position(|name| f.name() == name);
            (id.is_none(), id, f.name().clone())
        });
        let ids = data
            .iter()
            .take_while(|f| IDS.contains(&f.name().as_str()))
            .count();
        let mut fields: Vec<FieldRef> = vec![Arc::new(Field::new(
            SEGMENT_ID_COLUMN,
            DataType::Utf8,
            false,
        ))];
        fields.extend(data.drain(..ids));
        fields.extend(index);
        fields.extend(data);
        Arc::new(Schema::new(fields))
    }
}

/// `table` with only the columns `names` names (and the segment id, always first), in
/// the table's order.
pub(super) fn project(table: &SchemaRef, names: &[String]) -> Result<SchemaRef, DatasetError> {
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

/// `batch` (one segment's, with some of `schema`'s columns by name) in `schema`: the
/// segment id first, null where the segment lacks a column.
fn place(
    schema: &SchemaRef,
    segment: &str,
    batch: &RecordBatch,
) -> Result<RecordBatch, ArrowError> {
    let rows = batch.num_rows();
    let mut columns: Vec<ArrayRef> = Vec::with_capacity(schema.fields().len());
    columns.push(Arc::new(StringArray::from_iter_values(
        std::iter::repeat_n(segment, rows),
    )));
    for field in schema.fields().iter().skip(1) {
        columns.push(match batch.column_by_name(field.name()) {
            Some(column) if column.data_type() != field.data_type() => {
                return Err(ArrowError::SchemaError(format!(
                    "column {:?} of segment {segment:?} is {}, where an earlier segment \
                     made it {}: the segments cannot be one table",
                    field.name(),
                    column.data_type(),
                    field.data_type()
                )));
            }
            Some(column) => Arc::clone(column),
            None => new_null_array(field.data_type(), rows),
        });
    }
    RecordBatch::try_new_with_options(
        Arc::clone(schema),
        columns,
        &arrow_array::RecordBatchOptions::new().with_row_count(Some(rows)),
    )
}

/// One segment's batches (`rows`, with some of `schema`'s columns by name) in `schema`,
/// each placed there: the segment's part of a dataset's table.
pub(crate) struct Placed<R> {
    rows: R,
    schema: SchemaRef,
    segment: Arc<str>,
}

impl<R> Placed<R> {
    pub(crate) fn new(rows: R, schema: SchemaRef, segment: Arc<str>) -> Self {
        Self {
            rows,
            schema,
            segment,
        }
    }
}

impl<R: Iterator<Item = Result<RecordBatch, ArrowError>>> Iterator for Placed<R> {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        let batch = self.rows.next()?;
        Some(batch.and_then(|batch| place(&self.schema, &self.segment, &batch)))
    }
}

impl<R: Iterator<Item = Result<RecordBatch, ArrowError>>> arrow_array::RecordBatchReader
    for Placed<R>
{
    fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }
}
