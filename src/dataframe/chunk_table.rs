//! The raw chunk table: one row per stored chunk row, across entities, streamed as record
//! batches (what the Parquet export of a store writes, and what SQL over "all chunks"
//! reads).

use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap, HashMap};
use std::sync::Arc;

use arrow_array::builder::{FixedSizeBinaryBuilder, StringBuilder};
use arrow_array::{Array, ArrayRef, RecordBatch, RecordBatchReader};
use arrow_schema::{ArrowError, DataType, Field, FieldRef, Schema, SchemaRef};

use super::cell_runs::ColumnCells;
use super::cells::{Cell, ListColumnBuilder, Sources};
use super::{DEFAULT_BATCH_CELLS, DataframeError, EntityPathFilter};
use crate::{Chunk, EntityPath, RowId, StoreView, TimeInt, TimeRange, Timeline};

/// Which chunk rows a [`StoreView::chunk_table`] holds and in which order.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct ChunkTableQuery {
    index: Option<Arc<str>>,
    contents: Option<EntityPathFilter>,
    batch_rows: Option<usize>,
    row_entities: Option<Arc<[EntityPath]>>,
    rows_overlapping: Option<(Arc<str>, TimeRange)>,
    columns: Option<Arc<[String]>>,
}

impl ChunkTableQuery {
    /// Every chunk row of every entity (`/__properties` included), chunk by chunk.
    pub fn new() -> Self {
        Self::default()
    }

    /// Rows ordered by `(time on index, row id)` across all chunks (so that a file's row
    /// groups are ordered by it); rows without a time there (static data, chunks of other
    /// timelines) come first, chunk by chunk.
    #[must_use]
    pub fn with_index(mut self, index: impl Into<Arc<str>>) -> Self {
        self.index = Some(index.into());
        self
    }

    /// Only the entities `contents` selects.
    #[must_use]
    pub fn with_contents(mut self, contents: EntityPathFilter) -> Self {
        self.contents = Some(contents);
        self
    }

    /// At most `rows` rows per batch (default: about [`DEFAULT_BATCH_CELLS`] cells).
    #[must_use]
    pub fn with_batch_rows(mut self, rows: usize) -> Self {
        self.batch_rows = Some(rows);
        self
    }

    /// Only the rows of these entities. Unlike [`Self::with_contents`], the table keeps
    /// the columns of every entity `contents` selects: a narrowed table has the whole
    /// table's schema (what a SQL scan that pushes a filter down needs).
    #[must_use]
    pub fn with_row_entities(mut self, entities: impl IntoIterator<Item = EntityPath>) -> Self {
        let mut entities: Vec<EntityPath> = entities.into_iter().collect();
        entities.sort();
        entities.dedup();
        self.row_entities = Some(entities.into());
        self
    }

    /// Only the rows of chunks that hold a time in `range` on `timeline` (every row of
    /// such a chunk, in the range or not: a caller wanting exactly the range filters the
    /// rows again). Chunks without that timeline, static ones included, are left out. The
    /// columns stay the whole table's, as with [`Self::with_row_entities`].
    #[must_use]
    pub fn with_rows_overlapping(
        mut self,
        timeline: impl Into<Arc<str>>,
        range: TimeRange,
    ) -> Self {
        self.rows_overlapping = Some((timeline.into(), range));
        self
    }

    /// Only these columns in the batches (names of the whole table's schema), in the
    /// table's order; the columns left out are never built. The rows stay the same. An
    /// empty list keeps the rows and no column (what `SELECT count(*)` asks for). A name
    /// the table does not have is refused when the table is made.
    #[must_use]
    pub fn with_columns<S: Into<String>>(mut self, columns: impl IntoIterator<Item = S>) -> Self {
        self.columns = Some(columns.into_iter().map(Into::into).collect());
        self
    }

    /// Does `chunk` pass the row filters ([`Self::with_row_entities`],
    /// [`Self::with_rows_overlapping`])?
    fn keeps_rows_of(&self, chunk: &Chunk) -> bool {
        let entity_kept = self
            .row_entities
            .as_ref()
            .is_none_or(|entities| entities.binary_search(chunk.entity_path()).is_ok());
        let time_kept = self
            .rows_overlapping
            .as_ref()
            .is_none_or(|(timeline, range)| {
                chunk.time_column(timeline).is_some_and(|column| {
                    let bounds = column.time_range();
                    let (least, greatest) = (bounds.min(), bounds.max());
                    range.intersects(TimeRange::new(least, greatest))
                })
            });
        entity_kept && time_kept
    }
}

/// One chunk of the table, and where its columns go.
struct TableChunk {
    chunk: Arc<Chunk>,
    /// Per output timeline, the chunk's time column there.
    time_columns: Vec<Option<usize>>,
    /// `(output component column, source number there)` per component of the chunk,
    /// registered the first time a row of the chunk is written.
    components: Option<Vec<(usize, u32)>>,
    /// The chunk's time column on the index, when it has one (then it is merged).
    index_column: Option<usize>,
    /// The next position to write (in `(time, row id)` order on the index when merged,
    /// else row order).
    position: usize,
}

/// The rows of [`StoreView::chunk_table`]: `entity_path` (Utf8), `chunk_id` and
/// `row_id` (`FixedSizeBinary(16)`, big-endian), one column per timeline (sorted by name,
/// null where a row has no time there), then one list column per component name (sorted;
/// null where a row's chunk has no such column). Where entities use one component name
/// with different types, each further type gets its own column, named `<component>#2`,
/// `#3`… in the order of entity paths. [`ChunkTableQuery::with_columns`] keeps some of
/// these columns, in this order. Holds the chunks it reads (not the store): it may
/// outlive the borrow it was made from.
pub struct ChunkTableStream {
    schema: SchemaRef,
    /// Which of `entity_path`, `chunk_id` and `row_id` are built.
    ids: [bool; 3],
    chunks: Vec<TableChunk>,
    /// Chunks written whole in order, before the merge: their numbers, and the next one.
    unmerged: Vec<usize>,
    next_unmerged: usize,
    heap: BinaryHeap<Reverse<((TimeInt, RowId), usize)>>,
    timelines: Vec<Timeline>,
    /// `(component name, list type)` of each component column.
    component_columns: Vec<(Arc<str>, DataType)>,
    sources: Vec<Sources>,
    cells: Vec<ColumnCells>,
    batch_rows: usize,
    done: bool,
}

impl std::fmt::Debug for ChunkTableStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ChunkTableStream")
            .field("schema", &self.schema)
            .field("chunks", &self.chunks.len())
            .finish_non_exhaustive()
    }
}

impl StoreView {
    /// Every row of every selected chunk as one table (see [`ChunkTableStream`]): the
    /// store's raw contents, for files and for questions across entities.
    ///
    /// # Errors
    /// An index timeline the store has never seen, or a batch size of zero.
    pub fn chunk_table(&self, query: &ChunkTableQuery) -> Result<ChunkTableStream, DataframeError> {
        if query.batch_rows == Some(0) {
            return Err(DataframeError::ZeroBatchRows);
        }
        if let Some(index) = &query.index
            && self.time_type(index).is_none()
        {
            return Err(DataframeError::UnknownIndex(crate::UnknownTimeline::new(
                index,
                &self.timelines(),
            )));
        }
        // Sorted by entity then chunk id.
        let mut chunks: Vec<Arc<Chunk>> = self.chunks();
        if let Some(filter) = &query.contents {
            chunks.retain(|c| filter.matches(c.entity_path()));
        }
        let columns = table_columns(&chunks);
        let (columns, ids) = match &query.columns {
            Some(names) => select_columns(columns, names)?,
            None => (columns, [true; 3]),
        };
        chunks.retain(|c| query.keeps_rows_of(c));
        Ok(ChunkTableStream::new(columns, ids, chunks, query))
    }
}

impl ChunkTableStream {
    fn new(
        columns: TableColumns,
        ids: [bool; 3],
        chunks: Vec<Arc<Chunk>>,
        query: &ChunkTableQuery,
    ) -> Self {
        let (timelines, fields, component_columns, sources) = columns;
        let index = query.index.as_deref();
        let mut heap = BinaryHeap::new();
        let mut unmerged = Vec::new();
        let table_chunks: Vec<TableChunk> = chunks
            .into_iter()
            .enumerate()
            .map(|(number, chunk)| {
                let index_column = index.and_then(|name| {
                    chunk
                        .time_columns()
                        .iter()
                        .position(|c| c.timeline().name() == name)
                });
                match index_column {
                    Some(column) => {
                        let row = chunk.time_columns()[column].row_at(0);
                        heap.push(Reverse((chunk.index_of_row(column, row), number)));
                    }
                    None => unmerged.push(number),
                }
                TableChunk {
                    time_columns: timelines
                        .iter()
                        .map(|t| {
                            chunk
                                .time_columns()
                                .iter()
                                .position(|c| c.timeline().name() == t.name())
                        })
                        .collect(),
                    components: None,
                    index_column,
                    position: 0,
                    chunk,
                }
            })
            .collect();
        let num_columns = fields.len().max(1);
        let batch_rows = query.batch_rows.unwrap_or_else(|| {
            (DEFAULT_BATCH_CELLS / num_columns).clamp(1, super::MAX_BATCH_ROWS_BY_CELLS)
        });
        Self {
            schema: Arc::new(Schema::new(fields)),
            ids,
            chunks: table_chunks,
            unmerged,
            next_unmerged: 0,
            heap,
            timelines,
            cells: component_columns
                .iter()
                .map(|_| ColumnCells::default())
                .collect(),
            component_columns,
            sources,
            batch_rows,
            done: false,
        }
    }

    /// How many chunks the table's rows come from.
    pub fn num_chunks(&self) -> usize {
        self.chunks.len()
    }

    /// The table's schema.
    pub fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }

    /// The next `(chunk, row)` to write, in table order.
    fn next_row(&mut self) -> Option<(usize, usize)> {
        while let Some(&number) = self.unmerged.get(self.next_unmerged) {
            let chunk = &mut self.chunks[number];
            if chunk.position < chunk.chunk.num_rows() {
                chunk.position += 1;
                return Some((number, chunk.position - 1));
            }
            self.next_unmerged += 1;
        }
        let Reverse((_, number)) = self.heap.pop()?;
        let chunk = &mut self.chunks[number];
        let column = chunk.index_column?;
        let times = &chunk.chunk.time_columns()[column];
        let row = times.row_at(chunk.position);
        chunk.position += 1;
        if chunk.position < chunk.chunk.num_rows() {
            let next = times.row_at(chunk.position);
            self.heap
                .push(Reverse((chunk.chunk.index_of_row(column, next), number)));
        }
        Some((number, row))
    }

    /// Registers where each component of chunk `number` goes (its `components`), on the
    /// first row written from it.
    fn register_columns(&mut self, number: usize) -> Result<(), ArrowError> {
        if self.chunks[number].components.is_none() {
            let chunk = Arc::clone(&self.chunks[number].chunk);
            let mut columns = Vec::with_capacity(chunk.components().len());
            for (position, column) in chunk.components().iter().enumerate() {
                let data_type = column.list_array().data_type();
                let Some(output) = self
                    .component_columns
                    .iter()
                    .position(|(name, t)| **name == *column.name().as_str() && t == data_type)
                else {
                    continue;
                };
                let position = u32::try_from(position).unwrap_or(u32::MAX);
                let source = self.sources[output].push(&chunk, position, &[], None)?;
                columns.push((output, source));
            }
            self.chunks[number].components = Some(columns);
        }
        Ok(())
    }

    fn next_batch(&mut self) -> Result<Option<RecordBatch>, ArrowError> {
        let mut entity_paths = StringBuilder::new();
        let mut chunk_ids = FixedSizeBinaryBuilder::new(crate::ids::ID_BYTES);
        let mut row_ids = FixedSizeBinaryBuilder::new(crate::ids::ID_BYTES);
        let mut times: Vec<Vec<Option<i64>>> = vec![Vec::new(); self.timelines.len()];
        let mut num_rows = 0;
        let mut entity_text: Option<(usize, String)> = None;
        while num_rows < self.batch_rows {
            let Some((number, row)) = self.next_row() else {
                break;
            };
            self.register_columns(number)?;
            let chunk = &self.chunks[number];
            let [entity_path, chunk_id, row_id] = self.ids;
            if entity_path {
                if entity_text.as_ref().is_none_or(|(n, _)| *n != number) {
                    entity_text = Some((number, chunk.chunk.entity_path().to_string()));
                }
                entity_paths.append_value(entity_text.as_ref().map_or("", |(_, text)| text));
            }
            if chunk_id {
                chunk_ids.append_value(chunk.chunk.id().to_be_bytes())?;
            }
            if row_id {
                row_ids.append_value(chunk.chunk.row_ids()[row].to_be_bytes())?;
            }
            for (values, column) in times.iter_mut().zip(&chunk.time_columns) {
                values.push(column.map(|c| chunk.chunk.time_columns()[c].times()[row]));
            }
            let row = u32::try_from(row).unwrap_or(u32::MAX);
            for &(output, source) in chunk.components.as_deref().unwrap_or_default() {
                let cells = &mut self.cells[output];
                cells.pad(None, num_rows);
                cells.push(Some(Cell::Row { source, row }));
            }
            num_rows += 1;
        }
        if num_rows == 0 {
            return Ok(None);
        }
        let ids: [ArrayRef; 3] = [
            Arc::new(entity_paths.finish()),
            Arc::new(chunk_ids.finish()),
            Arc::new(row_ids.finish()),
        ];
        let mut arrays: Vec<ArrayRef> = kept(ids, &self.ids);
        for (timeline, values) in self.timelines.iter().zip(times) {
            arrays.push(timeline.time_type().array(values));
        }
        let mut builder = ListColumnBuilder::default();
        for (cells, sources) in self.cells.iter_mut().zip(&self.sources) {
            cells.pad(None, num_rows);
            cells.finish(sources, &mut builder)?;
        }
        arrays.extend(builder.finish_batch()?);
        // The row count matters when no column is kept (`count(*)`).
        let options = arrow_array::RecordBatchOptions::new().with_row_count(Some(num_rows));
        RecordBatch::try_new_with_options(Arc::clone(&self.schema), arrays, &options).map(Some)
    }
}

/// The columns of `columns` that `names` names, in the table's order, and which of the
/// three id columns are kept.
fn select_columns(
    columns: TableColumns,
    names: &[String],
) -> Result<(TableColumns, [bool; 3]), DataframeError> {
    let (timelines, fields, component_columns, sources) = columns;
    let num_columns = fields.len();
    let mut keep = vec![false; num_columns];
    for name in names {
        let position = fields
            .iter()
            .position(|field| field.name() == name)
            .ok_or_else(|| DataframeError::UnknownColumn {
                name: name.clone(),
                num_columns,
            })?;
        keep[position] = true;
    }
    let ids = [keep[0], keep[1], keep[2]];
    let (timeline_keep, component_keep) = keep[3..].split_at(timelines.len());
    let timelines = kept(timelines, timeline_keep);
    let (component_columns, sources) =
        kept(component_columns.into_iter().zip(sources), component_keep)
            .into_iter()
            .unzip();
    let fields = kept(fields, &keep);
    Ok(((timelines, fields, component_columns, sources), ids))
}

/// The items of `items` whose flag in `keep` is set.
fn kept<T>(items: impl IntoIterator<Item = T>, keep: &[bool]) -> Vec<T> {
    items
        .into_iter()
        .zip(keep)
        .filter_map(|(item, &kept)| kept.then_some(item))
        .collect()
}

/// The timelines, fields, component columns and their sources of a table of `chunks`.
type TableColumns = (
    Vec<Timeline>,
    Vec<Field>,
    Vec<(Arc<str>, DataType)>,
    Vec<Sources>,
);

fn table_columns(chunks: &[Arc<Chunk>]) -> TableColumns {
    let mut timelines: BTreeMap<String, Timeline> = BTreeMap::new();
    // Component columns by name, then one per distinct list type in entity order.
    let mut by_name: BTreeMap<Arc<str>, Vec<(DataType, FieldRef)>> = BTreeMap::new();
    // Every chunk is looked at (a query's table has every selected entity's columns), so
    // a name is allocated only the first time it is seen: an entity's chunks mostly
    // repeat the same columns.
    for chunk in chunks {
        for column in chunk.time_columns() {
            let timeline = column.timeline();
            if !timelines.contains_key(timeline.name()) {
                timelines.insert(timeline.name().to_owned(), timeline.clone());
            }
        }
        for column in chunk.components() {
            let data_type = column.list_array().data_type();
            let DataType::List(item) = data_type else {
                continue;
            };
            let name = column.name().as_str();
            let types = match by_name.get_mut(name) {
                Some(types) => types,
                None => by_name.entry(name.into()).or_default(),
            };
            if !types.iter().any(|(t, _)| t == data_type) {
                types.push((data_type.clone(), Arc::clone(item)));
            }
        }
    }
    let timelines: Vec<Timeline> = timelines.into_values().collect();
    let mut fields = vec![
        Field::new("entity_path", DataType::Utf8, false),
        Field::new("chunk_id", crate::ids::ID_DATA_TYPE, false),
        Field::new("row_id", crate::ids::ID_DATA_TYPE, false),
    ];
    fields.extend(timelines.iter().map(|t| {
        Field::new(t.name(), t.time_type().to_arrow(), true).with_metadata(HashMap::from([
            ("rerun:kind".to_owned(), "index".to_owned()),
            ("rerun:index_name".to_owned(), t.name().to_owned()),
        ]))
    }));
    let mut component_columns = Vec::new();
    let mut sources = Vec::new();
    for (name, types) in by_name {
        for (n, (data_type, item)) in types.into_iter().enumerate() {
            let column_name = if n == 0 {
                name.to_string()
            } else {
                format!("{name}#{}", n + 1)
            };
            fields.push(
                Field::new(column_name, data_type.clone(), true).with_metadata(HashMap::from([
                    ("rerun:kind".to_owned(), "data".to_owned()),
                    ("rerun:component".to_owned(), name.to_string()),
                ])),
            );
            sources.push(Sources::new(item));
            component_columns.push((Arc::clone(&name), data_type));
        }
    }
    (timelines, fields, component_columns, sources)
}

impl Iterator for ChunkTableStream {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let batch = self.next_batch();
        if !matches!(batch, Ok(Some(_))) {
            self.done = true;
        }
        batch.transpose()
    }
}

impl RecordBatchReader for ChunkTableStream {
    fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }
}
