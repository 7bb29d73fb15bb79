//! Streaming a planned dataframe: columns merged into rows, rows gathered into batches.

use std::collections::BTreeMap;
use std::sync::Arc;

use arrow_array::{ArrayRef, RecordBatch, RecordBatchReader};
use arrow_schema::{ArrowError, SchemaRef};

use super::cells::{Cell, ColumnCells, FinishScratch};
use super::column::{ColumnState, Kind, column_state, exact_cell, row_bytes, visible_cell};
use super::schema::{Selection, TablePlan};
use super::{DEFAULT_BATCH_BYTES, DEFAULT_BATCH_CELLS, DataframeQuery};
use crate::{LatestAtQuery, Snapshot, StoreView, TimeInt, TimeRange};

/// The rows of a dataframe view, as Arrow record batches of at most the query's batch
/// size, in ascending order of the index (or in the order of the sampled values). The
/// schema is known before the first batch. Reads one state of the store: it borrows the
/// store ([`StoreView::dataframe`]), or holds a snapshot ([`Snapshot::into_dataframe`],
/// a `DataframeStream<'static>` that can cross threads and outlive the store's handle).
///
/// Implements [`RecordBatchReader`], so it can be handed to any Arrow writer as it is.
pub struct DataframeStream<'a> {
    store: ViewRef<'a>,
    plan: TablePlan,
    selection: Selection,
    columns: Vec<ColumnState>,
    rows: Rows,
    batch_rows: usize,
    /// Per index column, this batch's values.
    index_values: Vec<Vec<Option<i64>>>,
    /// Per data column, this batch's cells (padded lazily: see [`ColumnCells`]).
    cells: Vec<ColumnCells>,
    /// Scratch: the greatest time on each index column among one row's cells.
    maxima: Vec<Option<i64>>,
    /// Set once the stream has ended (its last batch, or an error, was handed out).
    done: bool,
}

/// The state a [`DataframeStream`] reads: borrowed, or frozen and owned.
pub(super) enum ViewRef<'a> {
    Borrowed(&'a StoreView),
    Owned(Snapshot),
}

impl std::ops::Deref for ViewRef<'_> {
    type Target = StoreView;

    fn deref(&self) -> &StoreView {
        match self {
            Self::Borrowed(view) => view,
            Self::Owned(snapshot) => snapshot,
        }
    }
}

impl std::fmt::Debug for DataframeStream<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DataframeStream")
            .field("schema", &self.selection.schema)
            .field("batch_rows", &self.batch_rows)
            .finish_non_exhaustive()
    }
}

/// Where rows come from.
enum Rows {
    /// A row per distinct index value any column has an event at.
    Merge { next: NextEvents, fill: bool },
    /// A row per sampled value; `exact`: only what the sparse view has at that time.
    Sample {
        values: Arc<[TimeInt]>,
        next: usize,
        exact: bool,
    },
}

/// Each temporal column's next event time, the columns grouped by it: columns logged at
/// the same times (many entities on one clock) move together, one map operation per
/// distinct time instead of a heap operation per column. With every time distinct it is
/// a k-way merge like a heap's.
#[derive(Default)]
struct NextEvents {
    by_time: BTreeMap<TimeInt, Vec<u32>>,
    /// Emptied groups, reused so that a steady merge allocates nothing.
    spare: Vec<Vec<u32>>,
}

impl NextEvents {
    fn push(&mut self, time: TimeInt, column: u32) {
        let Self { by_time, spare } = self;
        by_time
            .entry(time)
            .or_insert_with(|| spare.pop().unwrap_or_default())
            .push(column);
    }

    fn recycle(&mut self, mut group: Vec<u32>) {
        group.clear();
        self.spare.push(group);
    }
}

impl<'a> DataframeStream<'a> {
    pub(super) fn new(
        store: ViewRef<'a>,
        query: &DataframeQuery,
        plan: TablePlan,
        selection: Selection,
    ) -> Result<Self, ArrowError> {
        let sampling = query.index_values.clone();
        let range = if sampling.is_some() {
            TimeRange::EVERYTHING
        } else {
            query.range
        };
        let mut columns = Vec::with_capacity(plan.columns.len());
        let mut next = NextEvents::default();
        for (number, column) in plan.columns.iter().enumerate() {
            let state = column_state(&store, &plan, column, range, query, sampling.is_none())?;
            if let Kind::Temporal(temporal) = &state.kind
                && let Some(time) = temporal.next_time()
            {
                next.push(time, u32::try_from(number).unwrap_or(u32::MAX));
            }
            columns.push(state);
        }
        let rows = match sampling {
            Some(values) => Rows::Sample {
                values,
                next: 0,
                exact: query.exact_index_values,
            },
            None => Rows::Merge {
                next,
                fill: query.fill_latest_at,
            },
        };
        let batch_rows = query.batch_rows.unwrap_or_else(|| {
            let least = query.min_batch_rows;
            let by_cells = DEFAULT_BATCH_CELLS / plan.columns.len().max(1);
            // Bytes bound a batch too: a static cell (a 5,000-point map) is copied into
            // every row, and an image column's cells are large; counting cells alone once
            // made batches of gigabytes.
            let by_bytes = DEFAULT_BATCH_BYTES / row_bytes(&columns, &selection.data).max(1);
            // The bytes bound wins over the least rows asked for (which only amortizes a
            // fixed cost per batch).
            by_cells
                .max(least)
                .min(by_bytes)
                .clamp(1, least.max(super::MAX_BATCH_ROWS_BY_CELLS))
        });
        Ok(Self {
            store,
            index_values: vec![Vec::new(); plan.index_columns.len()],
            cells: plan
                .columns
                .iter()
                .map(|_| ColumnCells::default())
                .collect(),
            maxima: vec![None; plan.index_columns.len()],
            plan,
            selection,
            columns,
            rows,
            batch_rows,
            done: false,
        })
    }

    /// The table's schema: index columns (sorted by timeline name), then one list column
    /// per (entity, component) with data, ordered by entity path, then component (only
    /// those [`DataframeQuery::with_columns`] kept, if it was given).
    pub fn schema(&self) -> SchemaRef {
        Arc::clone(&self.selection.schema)
    }

    /// How many distinct chunks the stream reads: those of its columns that overlap the
    /// range (their times decide the rows; the selected columns' cells are copied from
    /// them), plus, when filling or sampling, the chunks of latest-at answers found so
    /// far. A query the index can narrow (a short range, a few entities) reads few.
    pub fn num_chunks_read(&self) -> usize {
        let mut ids: Vec<crate::ChunkId> = self
            .columns
            .iter()
            .flat_map(|column| column.sources.chunk_ids())
            .collect();
        ids.sort_unstable();
        ids.dedup();
        ids.len()
    }

    /// How many (chunk, column) sources the columns have registered: it grows only when
    /// filling or sampling finds a chunk not seen yet, so a caller reporting
    /// [`Self::num_chunks_read`] as the stream goes recounts only when this changed (the
    /// SQL scan's `chunks_read`).
    #[cfg(feature = "datafusion")]
    pub(crate) fn num_sources(&self) -> usize {
        self.columns.iter().map(|c| c.sources.num_sources()).sum()
    }

    /// How many rows a batch holds at most.
    pub fn batch_rows(&self) -> usize {
        self.batch_rows
    }

    /// Appends one merged row at `time`; `false` when there is none left.
    fn merge_row(&mut self, num_rows: usize) -> bool {
        let Rows::Merge { next, fill } = &mut self.rows else {
            return false;
        };
        let Some((time, group)) = next.by_time.pop_first() else {
            return false;
        };
        self.maxima.fill(None);
        for &number in &group {
            let state = &mut self.columns[number as usize];
            let Kind::Temporal(column) = &mut state.kind else {
                continue;
            };
            let (cell, latest) = column.take_events_at(time);
            if let Some(cell) = cell {
                state.sources.raise_times(cell, &mut self.maxima);
            }
            if self.selection.data[number as usize] {
                let cells = &mut self.cells[number as usize];
                cells.pad(if *fill { column.fill } else { None }, num_rows);
                cells.push(cell);
            }
            if *fill && !column.hidden_by_static_clear {
                match cell {
                    // A Clear's mark: what came before is hidden (a data component), or
                    // still answers (the Clear component, which no Clear hides), the
                    // entity's own Clear at this time included.
                    Some(Cell::Empty) if column.hides => column.fill = None,
                    Some(Cell::Empty) | None => {
                        if !column.hides && latest.is_some() {
                            column.fill = latest;
                        }
                    }
                    Some(row) => column.fill = Some(row),
                }
            }
            if let Some(time) = column.next_time() {
                next.push(time, number);
            }
        }
        next.recycle(group);
        self.push_index_values(time);
        true
    }

    /// Appends the row sampled at the next value; `false` when there is none left.
    fn sample_row(&mut self) -> bool {
        let Rows::Sample {
            values,
            next,
            exact,
        } = &mut self.rows
        else {
            return false;
        };
        let Some(&at) = values.get(*next) else {
            return false;
        };
        *next += 1;
        self.maxima.fill(None);
        let query = LatestAtQuery::new(Arc::clone(self.plan.index.name_arc()), at);
        for (((state, plan), cells), &selected) in self
            .columns
            .iter_mut()
            .zip(&self.plan.columns)
            .zip(&mut self.cells)
            .zip(&self.selection.data)
        {
            let cell = match &mut state.kind {
                Kind::Static(cell) => *cell,
                Kind::Temporal(column) => {
                    let answer = self
                        .store
                        .latest_at_unfiltered(&query, &plan.entity, plan.component.as_str())
                        .and_then(|answer| {
                            let source = state
                                .sources
                                .find_or_push(
                                    answer.chunk(),
                                    answer.component_column_index(),
                                    &self.plan.index_columns,
                                    Some(self.plan.index_position),
                                )
                                .ok()?;
                            let index = (answer.time()?, answer.row_id());
                            let row = u32::try_from(answer.row()).ok()?;
                            Some((index, Cell::Row { source, row }))
                        });
                    let cell = if *exact {
                        exact_cell(answer, &column.clears, at, column.hidden_by_static_clear)
                    } else if column.hides {
                        let visible = column.clears.partition_point(|&(t, _)| t <= at);
                        let latest_clear = visible.checked_sub(1).map(|i| column.clears[i]);
                        visible_cell(answer, latest_clear, column.hidden_by_static_clear)
                    } else {
                        answer.map(|(_, cell)| cell)
                    };
                    if let Some(cell) = cell {
                        state.sources.raise_times(cell, &mut self.maxima);
                    }
                    cell
                }
            };
            if selected {
                cells.push(cell);
            }
        }
        self.push_index_values(at);
        true
    }

    fn push_index_values(&mut self, time: TimeInt) {
        self.maxima[self.plan.index_position] = Some(time.as_i64());
        for (values, max) in self.index_values.iter_mut().zip(&self.maxima) {
            values.push(*max);
        }
    }

    fn next_batch(&mut self) -> Result<Option<RecordBatch>, ArrowError> {
        let mut num_rows = 0;
        while num_rows < self.batch_rows && (self.merge_row(num_rows) || self.sample_row()) {
            num_rows += 1;
        }
        if num_rows == 0 {
            return Ok(None);
        }
        let fill = matches!(self.rows, Rows::Merge { fill: true, .. });
        let mut arrays: Vec<ArrayRef> = Vec::with_capacity(self.selection.schema.fields().len());
        for ((timeline, values), &selected) in self
            .plan
            .index_columns
            .iter()
            .zip(&mut self.index_values)
            .zip(&self.selection.index)
        {
            let values = std::mem::take(values);
            if selected {
                arrays.push(timeline.time_type().array(values));
            }
        }
        let mut scratch = FinishScratch::default();
        for ((state, cells), &selected) in self
            .columns
            .iter()
            .zip(&mut self.cells)
            .zip(&self.selection.data)
        {
            if !selected {
                continue;
            }
            let pad = match &state.kind {
                Kind::Static(cell) => *cell,
                Kind::Temporal(column) if fill => column.fill,
                Kind::Temporal(_) => None,
            };
            cells.pad(pad, num_rows);
            arrays.push(cells.finish(&state.sources, num_rows, &mut scratch)?);
        }
        // With no column kept, the batch still says how many rows it stands for.
        let options = arrow_array::RecordBatchOptions::new().with_row_count(Some(num_rows));
        RecordBatch::try_new_with_options(Arc::clone(&self.selection.schema), arrays, &options)
            .map(Some)
    }
}

impl Iterator for DataframeStream<'_> {
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

impl RecordBatchReader for DataframeStream<'_> {
    fn schema(&self) -> SchemaRef {
        Arc::clone(&self.selection.schema)
    }
}
