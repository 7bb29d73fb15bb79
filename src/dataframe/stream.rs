//! Streaming a planned dataframe: batches of rows, each built a column at a time.

use std::sync::Arc;

use arrow_array::{ArrayRef, RecordBatch, RecordBatchReader};
use arrow_schema::{ArrowError, SchemaRef};

use super::batch_times::{TimeSet, merge_times, position_from};
use super::cells::{Cell, ListColumnBuilder, Sources};
use super::column::{
    ColumnState, Kind, RowSink, TemporalColumn, column_state, exact_cell, row_bytes, visible_cell,
};
use super::kept_rows::{GivenRows, KeptRows, RowsKey, budget_times};
use super::schema::{Selection, TablePlan};
use super::{DEFAULT_BATCH_CELLS, DataframeQuery};
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
    /// The index values of this batch's rows, ascending (merging) or as sampled.
    times: Vec<TimeInt>,
    /// Scratch for gathering `times`.
    coming: Vec<TimeInt>,
    merged: Vec<TimeInt>,
    time_set: TimeSet,
    /// Per index column other than the index (whose values are `times`), this batch's
    /// values: the greatest time among each row's cells.
    index_values: Vec<Vec<Option<i64>>>,
    /// One column's cells while the batch builds it (columns are built one at a time).
    cells: ListColumnBuilder,
    /// Is an index column other than the index itself in the output? Then every column's
    /// cells raise its values, built or not.
    raises: bool,
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
    /// A row per distinct index value any column has an event at: kept by an earlier
    /// query of the snapshot (`given`), or gathered from the columns and, if the stream
    /// owns a snapshot, recorded to be kept when the stream ends.
    Merge {
        fill: bool,
        given: Option<GivenRows>,
        recording: Option<Recording>,
    },
    /// A row per sampled value; `exact`: only what the sparse view has at that time.
    Sample {
        values: Arc<[TimeInt]>,
        next: usize,
        exact: bool,
    },
}

/// The rows a stream over a snapshot has gathered so far, to keep once it has them all.
struct Recording {
    kept: Arc<KeptRows>,
    key: RowsKey,
    range: TimeRange,
    times: Vec<TimeInt>,
    /// Past this many, the rows will not be kept: recording stops.
    budget: usize,
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
        // A snapshot keeps its views' rows between queries (`kept_rows`).
        let (given, recording) = match (&store, &sampling) {
            (ViewRef::Owned(snapshot), None) => {
                let kept = snapshot.derived::<KeptRows>();
                let key = RowsKey::of(query);
                match kept.rows(&key, range) {
                    Some(given) => (Some(given), None),
                    None => (
                        None,
                        Some(Recording {
                            kept,
                            key,
                            range,
                            times: Vec::new(),
                            budget: budget_times(snapshot.stats().heap_bytes),
                        }),
                    ),
                }
            }
            _ => (None, None),
        };
        let raises = selection
            .index
            .iter()
            .enumerate()
            .any(|(position, &selected)| selected && position != plan.index_position);
        let columns = plan
            .columns
            .iter()
            .zip(&selection.data)
            .map(|(column, &selected)| {
                if given.is_some() && !selected && !raises {
                    // The kept rows hold its times, and it builds and raises nothing:
                    // it is not read at all.
                    return Ok(ColumnState {
                        sources: Sources::new(Arc::clone(&column.item_field)),
                        kind: Kind::Static(None),
                    });
                }
                column_state(&store, &plan, column, range, query, sampling.is_none())
            })
            .collect::<Result<Vec<_>, _>>()?;
        let rows = match sampling {
            Some(values) => Rows::Sample {
                values,
                next: 0,
                exact: query.exact_index_values,
            },
            None => Rows::Merge {
                fill: query.fill_latest_at,
                given,
                recording,
            },
        };
        let batch_rows = query.batch_rows.unwrap_or_else(|| {
            let least = query.min_batch_rows;
            let by_cells = DEFAULT_BATCH_CELLS / plan.columns.len().max(1);
            // Bytes bound a batch too: a static cell (a 5,000-point map) is copied into
            // every row, and an image column's cells are large; counting cells alone once
            // made batches of gigabytes.
            let by_bytes = query.batch_bytes / row_bytes(&columns, &selection.data).max(1);
            // The bytes bound wins over the least rows asked for (which only amortizes a
            // fixed cost per batch).
            by_cells
                .max(least)
                .min(by_bytes)
                .clamp(1, least.max(super::MAX_BATCH_ROWS_BY_CELLS))
        });
        Ok(Self {
            store,
            times: Vec::new(),
            coming: Vec::new(),
            merged: Vec::new(),
            time_set: TimeSet::default(),
            index_values: vec![Vec::new(); plan.index_columns.len()],
            cells: ListColumnBuilder::default(),
            raises,
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
    /// far. A query the index can narrow (a short range, a few entities) reads few. Over
    /// a snapshot whose earlier query kept the view's rows, the columns left out of the
    /// output are not read (unless another index column is in it: their cells raise it).
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

    /// Sets `times` to the next batch's row times: when merging, the first `batch_rows`
    /// distinct times at which any column (selected or not: every planned column's times
    /// decide the rows) has a row or a Clear still to come, gathered column by column
    /// without consuming anything (or the next of the rows the snapshot kept); when
    /// sampling, the next sampled values.
    fn next_times(&mut self) {
        self.times.clear();
        let cap = self.batch_rows;
        let Self {
            times,
            coming,
            merged,
            time_set,
            columns,
            rows,
            ..
        } = self;
        match rows {
            Rows::Merge {
                given: Some(given), ..
            } => given.take(cap, times),
            Rows::Merge { recording, .. } => {
                let mut set_is_current = false;
                // The last column found to add nothing to the batch as it is.
                let mut known: Option<&TemporalColumn> = None;
                for state in columns.iter() {
                    let Kind::Temporal(column) = &state.kind else {
                        continue;
                    };
                    let last = times.last().copied().filter(|_| times.len() >= cap);
                    // Once the batch is full, only earlier times can still join it; a
                    // column whose times the batch has adds nothing, which a look-up per
                    // time tells without gathering them, or, for an entity's components
                    // logged together, the previous column's answer.
                    if let Some(last) = last {
                        if !set_is_current {
                            time_set.rebuild(times);
                            set_is_current = true;
                        }
                        if known.is_some_and(|known| column.same_times_ahead(known, last))
                            || column.coming_times_known(last, times, |time| {
                                time_set.contains(times, time)
                            })
                        {
                            known = Some(column);
                            continue;
                        }
                    }
                    known = None;
                    column.coming_times(last, cap, coming, |new| {
                        set_is_current &= !merge_times(times, new, cap, merged);
                    });
                }
                if let Some(record) = recording {
                    if record.times.len() + times.len() > record.budget {
                        *recording = None;
                    } else {
                        record.times.extend_from_slice(times);
                    }
                }
            }
            Rows::Sample { values, next, .. } => {
                let end = values.len().min(next.saturating_add(cap));
                times.extend_from_slice(values.get(*next..end).unwrap_or_default());
                *next = end;
            }
        }
    }

    /// Column `number`'s cells on this batch's rows (the merge's events at or before the
    /// batch's last time consumed), finished in the batch's builder if it is selected.
    /// Its cells' times raise the batch's other index columns.
    fn merge_column(&mut self, number: usize, fill: bool) -> Result<(), ArrowError> {
        let selected = self.selection.data[number];
        let state = &mut self.columns[number];
        let cells = &mut self.cells;
        let num_rows = self.times.len();
        if selected {
            cells.reserve(num_rows);
        }
        let pad = match &mut state.kind {
            Kind::Static(cell) => *cell,
            Kind::Temporal(column) => {
                let Some(&last) = self.times.last() else {
                    return Ok(());
                };
                if !selected && !self.raises {
                    // Its times are in the batch's already, and it builds and raises
                    // nothing: a projection's other columns cost a search per run.
                    column.skip_through(last);
                    return Ok(());
                }
                let mut sink = MergeSink {
                    times: &self.times,
                    from: 0,
                    at: 0,
                    sources: &state.sources,
                    index_values: &mut self.index_values,
                    cells,
                    // With no other index column in the output, no cell raises one.
                    raises: self.raises,
                    selected,
                    fill,
                    fill_cell: column.fill,
                };
                column.take_rows_through(last, &mut sink);
                let MergeSink {
                    mut from,
                    fill_cell,
                    ..
                } = sink;
                column.fill = fill_cell;
                while let Some(time) = column.next_time().filter(|&time| time <= last) {
                    // Events come in ascending time, each on a later row.
                    let row = position_from(&self.times, from, time);
                    from = row + 1;
                    let (cell, latest) = column.take_events_at(time);
                    if let Some(cell) = cell {
                        state.sources.raise_times(cell, row, &mut self.index_values);
                    }
                    if selected {
                        let pad = if fill { column.fill } else { None };
                        cells.pad_and_push(&state.sources, pad, row, cell);
                    }
                    if fill && !column.hidden_by_static_clear {
                        match cell {
                            // A Clear's mark: what came before is hidden (a data
                            // component), or still answers (the Clear component, which no
                            // Clear hides), the entity's own Clear at this time included.
                            Some(Cell::Empty) if column.hides => column.fill = None,
                            Some(Cell::Empty) | None => {
                                if !column.hides && latest.is_some() {
                                    column.fill = latest;
                                }
                            }
                            Some(row) => column.fill = Some(row),
                        }
                    }
                }
                if fill { column.fill } else { None }
            }
        };
        if !selected {
            return Ok(());
        }
        cells.pad(&state.sources, pad, num_rows);
        cells.finish_column(&state.sources)
    }

    /// Column `number`'s cells at this batch's sampled values, finished in the batch's
    /// builder if it is selected: the latest-at answer at each (or, `exact`, only a row
    /// logged there).
    fn sample_column(
        &mut self,
        number: usize,
        queries: &[LatestAtQuery],
        exact: bool,
    ) -> Result<(), ArrowError> {
        let selected = self.selection.data[number];
        let state = &mut self.columns[number];
        let plan = &self.plan.columns[number];
        let cells = &mut self.cells;
        match &mut state.kind {
            Kind::Static(cell) => {
                if selected {
                    cells.pad(&state.sources, *cell, queries.len());
                }
            }
            Kind::Temporal(column) => {
                for (row, query) in queries.iter().enumerate() {
                    let at = query.at();
                    let answer = self
                        .store
                        .latest_at_unfiltered(query, &plan.entity, plan.component.as_str())
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
                    let cell = if exact {
                        exact_cell(answer, &column.clears, at, column.hidden_by_static_clear)
                    } else if column.hides {
                        let visible = column.clears.partition_point(|&(t, _)| t <= at);
                        let latest_clear = visible.checked_sub(1).map(|i| column.clears[i]);
                        visible_cell(answer, latest_clear, column.hidden_by_static_clear)
                    } else {
                        answer.map(|(_, cell)| cell)
                    };
                    if let Some(cell) = cell {
                        state.sources.raise_times(cell, row, &mut self.index_values);
                    }
                    if selected {
                        cells.push(&state.sources, cell);
                    }
                }
            }
        }
        if !selected {
            return Ok(());
        }
        cells.finish_column(&state.sources)
    }

    /// The next batch, built a column at a time: the batch's row times first, then each
    /// column's cells on them in one pass over that column's own state and sources, so
    /// that a wide table touches one column's memory at a time rather than every
    /// column's on every row.
    fn next_batch(&mut self) -> Result<Option<RecordBatch>, ArrowError> {
        self.next_times();
        let num_rows = self.times.len();
        if num_rows == 0 {
            // Every row was gathered: the snapshot keeps them for its later queries.
            if let Rows::Merge { recording, .. } = &mut self.rows
                && let Some(record) = recording.take()
            {
                record
                    .kept
                    .keep(record.key, record.range, record.times, record.budget);
            }
            return Ok(None);
        }
        for (i, values) in self.index_values.iter_mut().enumerate() {
            values.clear();
            // The index's own column is the batch's times (built from them below); no
            // cell raises it.
            if i != self.plan.index_position {
                values.resize(num_rows, None);
            }
        }
        match &self.rows {
            Rows::Merge { fill, .. } => {
                let fill = *fill;
                for number in 0..self.columns.len() {
                    self.merge_column(number, fill)?;
                }
            }
            Rows::Sample { exact, .. } => {
                let exact = *exact;
                let name = self.plan.index.name_arc();
                let queries: Vec<LatestAtQuery> = self
                    .times
                    .iter()
                    .map(|&at| LatestAtQuery::new(Arc::clone(name), at))
                    .collect();
                for number in 0..self.columns.len() {
                    self.sample_column(number, &queries, exact)?;
                }
            }
        }
        let data = self.cells.finish_batch()?;
        let mut arrays: Vec<ArrayRef> = Vec::with_capacity(self.selection.schema.fields().len());
        for (i, ((timeline, values), &selected)) in self
            .plan
            .index_columns
            .iter()
            .zip(&mut self.index_values)
            .zip(&self.selection.index)
            .enumerate()
        {
            if !selected {
                continue;
            }
            arrays.push(if i == self.plan.index_position {
                timeline
                    .time_type()
                    .dense_array(self.times.iter().map(|time| time.as_i64()).collect())
            } else {
                timeline.time_type().array(std::mem::take(values))
            });
        }
        arrays.extend(data);
        // With no column kept, the batch still says how many rows it stands for.
        let options = arrow_array::RecordBatchOptions::new().with_row_count(Some(num_rows));
        RecordBatch::try_new_with_options(Arc::clone(&self.selection.schema), arrays, &options)
            .map(Some)
    }
}

/// A column's rows as [`TemporalColumn::take_rows_through`] hands them, put on the batch's
/// rows: each at its time's row (the rows before it padded), raising the other index
/// columns in the output, its cell built if the column is selected.
struct MergeSink<'s> {
    times: &'s [TimeInt],
    /// The batch row after the last row taken.
    from: usize,
    /// Where the last `lead` found its first time.
    at: usize,
    sources: &'s Sources,
    index_values: &'s mut Vec<Vec<Option<i64>>>,
    cells: &'s mut ListColumnBuilder,
    raises: bool,
    selected: bool,
    fill: bool,
    /// The last cell taken (what fills the rows after it).
    fill_cell: Option<Cell>,
}

impl RowSink for MergeSink<'_> {
    #[inline]
    fn row(&mut self, time: TimeInt, cell: Cell) {
        let row = position_from(self.times, self.from, time);
        self.from = row + 1;
        if self.raises {
            self.sources.raise_times(cell, row, self.index_values);
        }
        if self.selected {
            let pad = if self.fill { self.fill_cell } else { None };
            self.cells.pad_and_push(self.sources, pad, row, Some(cell));
        }
        self.fill_cell = Some(cell);
    }

    fn lead(&mut self, times: &[i64]) -> usize {
        // A stretch is built at once; its cells would raise other index columns one by one.
        if !self.selected || self.raises {
            return 0;
        }
        let Some(&first) = times.first() else {
            return 0;
        };
        self.at = position_from(self.times, self.from, TimeInt::saturating(first));
        let ahead = self.times.get(self.at..).unwrap_or_default();
        crate::time::leading_equal(ahead, times)
    }

    fn stretch(&mut self, source: u32, rows: std::ops::Range<u32>) {
        let pad = if self.fill { self.fill_cell } else { None };
        self.cells.pad(self.sources, pad, self.at);
        self.from = self.at + rows.len();
        if let Some(last) = rows.end.checked_sub(1) {
            self.fill_cell = Some(Cell::Row { source, row: last });
        }
        self.cells
            .push_rows(self.sources, source, rows.start, rows.end);
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
