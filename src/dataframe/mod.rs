//! Dataframe views (SEMANTICS.md section 9): the store as a table on one index timeline,
//! streamed as Arrow record batches of bounded size.
//!
//! A query is planned once ([`schema`]: which columns, in which order, with which types),
//! then streamed ([`stream`]) a batch at a time, and a batch is built a column at a time.
//! Each temporal column walks its own range result (a
//! [`RangeCursor`](crate::query::RangeCursor), already merged across its chunks in
//! `(time, row id)` order) beside the Clears that apply to it. A batch first gathers its
//! row times: every column's coming times, looked at without being consumed, merged into
//! the first `batch_rows` distinct ones (a column whose times the batch already has, as
//! with many entities on one clock, costs a search per time). Then each column in turn
//! consumes its events up to the batch's last time and writes its cells straight into a
//! list array ([`cells`]): offsets and validity per cell, the values as slices of the
//! chunks' own arrays (usually one zero-copy slice per batch), repeated fill cells of one
//! chunk with one `take`. One column's state, sources and output are all that a pass
//! touches, so a table of thousands of columns does not miss the cache on every cell.
//!
//! A stream that owns a snapshot ([`Snapshot::into_dataframe`], as SQL's scans and the
//! Python package read) leaves the rows it gathered with the snapshot when it ends
//! ([`kept_rows`]); a later query of the same view over that range or a part of it takes
//! its rows from there and reads only the columns it outputs.

mod batch_times;
mod cell_runs;
mod cells;
mod chunk_table;
mod column;
mod filter;
mod kept_rows;
mod schema;
mod stream;

use std::fmt;
use std::sync::Arc;

use arrow_schema::ArrowError;

use crate::{Snapshot, StoreView, TimeInt, TimeRange, UnknownTimeline};

pub use chunk_table::{ChunkTableQuery, ChunkTableStream};
pub use filter::{EntityPathFilter, EntityPathFilterError};
pub use stream::DataframeStream;

/// The name of the column that says which recording a row comes from, in a table of
/// several (a dataset's, SQL over several recordings): the name Rerun's catalog gives it.
pub const SEGMENT_ID_COLUMN: &str = "rerun_segment_id";

/// Cells per batch when [`DataframeQuery::with_batch_rows`] is not given: a batch holds
/// about this many cells, whatever the number of columns (at least one row, at most 65,536).
pub const DEFAULT_BATCH_CELLS: usize = 1 << 20;

/// Bytes per batch, about, when [`DataframeQuery::with_batch_rows`] is not given: a batch
/// of large cells (images, a static map repeated on every row) holds fewer rows than
/// [`DEFAULT_BATCH_CELLS`] allows, so that a table streams in bounded memory whatever
/// its cells hold.
pub const DEFAULT_BATCH_BYTES: usize = 32 << 20;

/// Most rows of a batch sized by cells (unless more are asked for): a narrow table's
/// batches stay short enough to stream.
pub(crate) const MAX_BATCH_ROWS_BY_CELLS: usize = 65_536;

/// A dataframe view of the store (SEMANTICS.md section 9): rows on one index timeline,
/// one column per selected (entity, component).
///
/// ```
/// # use std::sync::Arc;
/// # use arrow_array::{ArrayRef, Float64Array};
/// use chunkstore::*;
/// # let frame = Timeline::sequence("frame");
/// # let v = |x: f64| Arc::new(Float64Array::from(vec![x])) as ArrayRef;
/// # let mut store = ChunkStore::new();
/// # for (entity, t, x) in [("/robot/arm", 1, 0.5), ("/robot/leg", 2, 1.5), ("/robot/arm", 3, 2.5)] {
/// #     store.insert(ChunkBuilder::new(ChunkId::new(), EntityPath::parse(entity)?)
/// #         .with_row(RowId::new(), [(frame.clone(), t)], [("angle", v(x))]).build()?)?;
/// # }
/// // Every value of the robot's parts from frame 1 to 3, gaps filled with the latest value.
/// let query = DataframeQuery::new("frame")
///     .with_contents(EntityPathFilter::parse(["/robot/**"])?)
///     .with_range(TimeRange::new(TimeInt::new(1).unwrap(), TimeInt::new(3).unwrap()))
///     .with_fill_latest_at(true);
/// let stream = store.dataframe(&query)?;
/// let names: Vec<_> = stream.schema().fields().iter().map(|f| f.name().clone()).collect();
/// assert_eq!(names, ["frame", "/robot/arm:angle", "/robot/leg:angle"]);
/// let rows: usize = stream.map(|batch| batch.unwrap().num_rows()).sum();
/// assert_eq!(rows, 3);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct DataframeQuery {
    index: Arc<str>,
    contents: EntityPathFilter,
    range: TimeRange,
    index_values: Option<Arc<[TimeInt]>>,
    fill_latest_at: bool,
    batch_rows: Option<usize>,
    min_batch_rows: usize,
    batch_bytes: usize,
    columns: Option<Arc<[String]>>,
    kept: KeptColumns,
    exact_index_values: bool,
}

/// Which kinds of column a view keeps that Rerun's reader leaves out by default.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct KeptColumns {
    /// `Clear:is_recursive` columns.
    pub tombstones: bool,
    /// Columns whose every cell is null or empty.
    pub semantically_empty: bool,
}

impl DataframeQuery {
    /// Every selected row on the `index` timeline, sparse (cells only where data was
    /// logged), over all entities but `/__properties`.
    pub fn new(index: impl Into<Arc<str>>) -> Self {
        Self {
            index: index.into(),
            contents: EntityPathFilter::default(),
            range: TimeRange::EVERYTHING,
            index_values: None,
            fill_latest_at: false,
            batch_rows: None,
            min_batch_rows: 1,
            batch_bytes: DEFAULT_BATCH_BYTES,
            columns: None,
            kept: KeptColumns {
                tombstones: true,
                semantically_empty: true,
            },
            exact_index_values: false,
        }
    }

    /// With [`Self::with_index_values`]: each sampled row shows what the sparse view has at
    /// exactly that time (a row logged then, a Clear's mark, static data), null elsewhere,
    /// as Rerun's reader does with `using_index_values` and no `fill_latest_at`; by default
    /// (`false`) each cell is the latest-at answer there.
    #[must_use]
    pub fn with_exact_index_values(mut self, exact: bool) -> Self {
        self.exact_index_values = exact;
        self
    }

    /// Keep (`true`, the default) or leave out the `Clear:is_recursive` columns (Rerun's
    /// *tombstone* columns, which its `reader` leaves out unless
    /// `include_tombstone_columns=True`). Left out, a column is not in the view at all:
    /// its rows make no rows of the table (a Clear still hides what it hides, and marks
    /// the other columns of its entities).
    #[must_use]
    pub fn with_tombstone_columns(mut self, include: bool) -> Self {
        self.kept.tombstones = include;
        self
    }

    /// Keep (`true`, the default) or leave out the columns whose every stored cell is null
    /// or an empty list (Rerun's *semantically empty* columns, which its `reader` leaves
    /// out unless `include_semantically_empty_columns=True`). Leaving them out reads every
    /// chunk of each column's cells' validity and lengths when the query is planned.
    #[must_use]
    pub fn with_semantically_empty_columns(mut self, include: bool) -> Self {
        self.kept.semantically_empty = include;
        self
    }

    /// Only the entities `contents` selects.
    #[must_use]
    pub fn with_contents(mut self, contents: EntityPathFilter) -> Self {
        self.contents = contents;
        self
    }

    /// Only rows whose index lies in `range` (both ends included; an empty range gives no
    /// rows).
    #[must_use]
    pub fn with_range(mut self, range: TimeRange) -> Self {
        self.range = range;
        self
    }

    /// Sampling: exactly one row per value, in the order given (repeats included), each
    /// cell the latest-at answer at that value. The range and the fill flag then play no
    /// part.
    #[must_use]
    pub fn with_index_values(mut self, values: impl IntoIterator<Item = TimeInt>) -> Self {
        self.index_values = Some(values.into_iter().collect());
        self
    }

    /// Fill each null cell with the latest-at answer at its row's index value.
    #[must_use]
    pub fn with_fill_latest_at(mut self, fill: bool) -> Self {
        self.fill_latest_at = fill;
        self
    }

    /// At most `rows` rows per batch (default: about [`DEFAULT_BATCH_CELLS`] cells). Zero
    /// is refused when the query runs.
    #[must_use]
    pub fn with_batch_rows(mut self, rows: usize) -> Self {
        self.batch_rows = Some(rows);
        self
    }

    /// Without [`Self::with_batch_rows`]: batches of about [`DEFAULT_BATCH_CELLS`] cells
    /// as usual, but never fewer than `rows` rows (at most 65,536, or `rows` if more). A
    /// wide table's batches are short by default (349 rows at 3,000 columns); a caller
    /// that pays a fixed cost per batch and column (a foreign-language binding importing
    /// each array) wants them longer, and the memory of a batch grows with them.
    #[must_use]
    pub fn with_min_batch_rows(mut self, rows: usize) -> Self {
        self.min_batch_rows = rows.max(1);
        self
    }

    /// Without [`Self::with_batch_rows`]: batches of about `bytes` at most (default
    /// [`DEFAULT_BATCH_BYTES`]; at least one row each, and this wins over
    /// [`Self::with_min_batch_rows`]). Whoever holds several batches at once (a reader
    /// ahead of its consumer) bounds its memory with it.
    #[must_use]
    pub fn with_batch_bytes(mut self, bytes: usize) -> Self {
        self.batch_bytes = bytes.max(1);
        self
    }

    /// Only these columns in the batches (names of the full view's schema, index columns
    /// included), in the full view's order. The rows stay the full view's: every selected
    /// entity's times still decide which rows there are (SEMANTICS.md section 9), but the
    /// cells of the columns left out are never read or built. An empty list keeps the
    /// rows and no column (what `SELECT count(*)` asks for). A name the view does not
    /// have is refused when the query runs.
    #[must_use]
    pub fn with_columns<S: Into<String>>(mut self, columns: impl IntoIterator<Item = S>) -> Self {
        self.columns = Some(columns.into_iter().map(Into::into).collect());
        self
    }

    /// Does it keep the columns whose every cell is null or empty (which only every chunk
    /// of a column can tell)?
    #[cfg(feature = "rrd")]
    pub(crate) fn keeps_semantically_empty_columns(&self) -> bool {
        self.kept.semantically_empty
    }

    /// The same query over every column (a dataset asks each segment for its own).
    #[cfg(feature = "rrd")]
    pub(crate) fn without_columns(mut self) -> Self {
        self.columns = None;
        self
    }

    /// The columns asked for by [`Self::with_columns`], if any.
    pub fn columns(&self) -> Option<&[String]> {
        self.columns.as_deref()
    }

    /// The index timeline's name.
    pub fn index(&self) -> &str {
        &self.index
    }

    /// The entities selected.
    pub fn contents(&self) -> &EntityPathFilter {
        &self.contents
    }

    /// The range of index values kept.
    pub fn range(&self) -> TimeRange {
        self.range
    }

    /// The sampled index values, if sampling.
    pub fn index_values(&self) -> Option<&[TimeInt]> {
        self.index_values.as_deref()
    }

    /// Are null cells filled?
    pub fn fill_latest_at(&self) -> bool {
        self.fill_latest_at
    }

    /// The rows per batch asked for, if any.
    pub fn batch_rows(&self) -> Option<usize> {
        self.batch_rows
    }

    /// The least rows per batch when batches are sized by cells (1 unless asked).
    pub fn min_batch_rows(&self) -> usize {
        self.min_batch_rows
    }

    /// The most bytes per batch, about, without [`Self::with_batch_rows`].
    pub fn batch_bytes(&self) -> usize {
        self.batch_bytes
    }
}

/// A dataframe query the store cannot answer.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub enum DataframeError {
    /// The index timeline is not one the store has seen.
    UnknownIndex(UnknownTimeline),
    /// A batch of zero rows was asked for.
    ZeroBatchRows,
    /// [`DataframeQuery::with_columns`] or [`ChunkTableQuery::with_columns`] named a
    /// column the table does not have.
    UnknownColumn {
        /// The name asked for.
        name: String,
        /// How many columns the table has.
        num_columns: usize,
    },
    /// A column's chunks could not be read as one list type.
    Column(Arc<ArrowError>),
}

/// Arrow's errors have no equality: two are equal if they say the same.
impl PartialEq for DataframeError {
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Self::UnknownIndex(a), Self::UnknownIndex(b)) => a == b,
            (Self::ZeroBatchRows, Self::ZeroBatchRows) => true,
            (
                Self::UnknownColumn {
                    name: a,
                    num_columns: m,
                },
                Self::UnknownColumn {
                    name: b,
                    num_columns: n,
                },
            ) => a == b && m == n,
            (Self::Column(a), Self::Column(b)) => a.to_string() == b.to_string(),
            _ => false,
        }
    }
}

impl Eq for DataframeError {}

impl fmt::Display for DataframeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::UnknownIndex(unknown) => write!(f, "{unknown}"),
            Self::ZeroBatchRows => write!(f, "a dataframe batch must hold at least one row"),
            Self::UnknownColumn { name, num_columns } => write!(
                f,
                "the table has no column {name:?} (it has {num_columns} columns)"
            ),
            Self::Column(error) => write!(f, "dataframe column: {error}"),
        }
    }
}

impl std::error::Error for DataframeError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::UnknownIndex(unknown) => Some(unknown),
            Self::Column(error) => Some(&**error),
            Self::ZeroBatchRows | Self::UnknownColumn { .. } => None,
        }
    }
}

impl StoreView {
    /// The dataframe view `query` asks for: its schema at once
    /// ([`DataframeStream::schema`]), its rows as a stream of record batches.
    ///
    /// Cost: planning visits the selected entities' indices once; streaming reads only
    /// the chunks of the selected columns that overlap the range, merged in one pass, and
    /// holds one batch at a time.
    ///
    /// # Errors
    /// An index timeline the store has never seen, or a batch size of zero.
    pub fn dataframe(&self, query: &DataframeQuery) -> Result<DataframeStream<'_>, DataframeError> {
        let plan = self.plan_dataframe(query)?;
        let selection = plan.selection(query)?;
        DataframeStream::new(stream::ViewRef::Borrowed(self), query, plan, selection)
            .map_err(column_error)
    }

    /// The schema [`StoreView::dataframe`] would stream for `query`, without setting up
    /// the stream (which reads every selected column's index).
    ///
    /// # Errors
    /// As [`StoreView::dataframe`].
    pub fn dataframe_schema(
        &self,
        query: &DataframeQuery,
    ) -> Result<arrow_schema::SchemaRef, DataframeError> {
        let plan = self.plan_dataframe(query)?;
        Ok(plan.selection(query)?.schema)
    }

    fn plan_dataframe(&self, query: &DataframeQuery) -> Result<schema::TablePlan, DataframeError> {
        if query.batch_rows == Some(0) {
            return Err(DataframeError::ZeroBatchRows);
        }
        // A store without temporal data answers on any timeline (static data answers on
        // every one): an index of no type is a sequence, with no rows.
        let time_type = match self.time_type(&query.index) {
            Some(time_type) => time_type,
            None if self.timelines().is_empty() => crate::TimeType::Sequence,
            None => {
                return Err(DataframeError::UnknownIndex(UnknownTimeline::new(
                    &query.index,
                    &self.timelines(),
                )));
            }
        };
        Ok(schema::TablePlan::new(self, query, time_type))
    }
}

fn column_error(error: ArrowError) -> DataframeError {
    DataframeError::Column(Arc::new(error))
}

impl Snapshot {
    /// [`StoreView::dataframe`] over this snapshot, owning it: the stream is `'static` and
    /// `Send`, so it can be handed to another thread or to a foreign caller (a Python
    /// `RecordBatchReader`) while the store it came from goes on changing.
    ///
    /// ```
    /// use chunkstore::{ChunkStore, DataframeQuery};
    ///
    /// let store = ChunkStore::new();
    /// // A store without temporal data answers on any timeline (static data answers on
    /// // every one), with no rows.
    /// let stream = store.snapshot().into_dataframe(&DataframeQuery::new("frame"))?;
    /// let rows: usize = stream.map(|batch| batch.map(|b| b.num_rows())).sum::<Result<_, _>>()?;
    /// assert_eq!(rows, 0);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    ///
    /// # Errors
    /// As [`StoreView::dataframe`].
    pub fn into_dataframe(
        self,
        query: &DataframeQuery,
    ) -> Result<DataframeStream<'static>, DataframeError> {
        let plan = self.plan_dataframe(query)?;
        let selection = plan.selection(query)?;
        DataframeStream::new(stream::ViewRef::Owned(self), query, plan, selection)
            .map_err(column_error)
    }
}
