//! Range: every cell of a component at an entity within a time range, in ascending
//! `(time, row id)` order across all chunks.
//!
//! Each contributing chunk gives one run of positions in its `(time, row id)` order. Runs
//! are sorted by their first index and swept into clusters of really overlapping runs; a
//! lone run is taken as it is, only a cluster pays for a k-way merge.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::sync::Arc;

use arrow_array::ArrayRef;

use crate::index::IndexedChunk;
use crate::{Chunk, ComponentColumn, EntityPath, RowId, StoreView, TimeColumn, TimeInt, TimeRange};

/// "Everything in `range` (inclusive) on `timeline`".
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RangeQuery {
    timeline: Arc<str>,
    range: TimeRange,
}

impl RangeQuery {
    /// A query on the named timeline over `range`, both ends included.
    pub fn new(timeline: impl Into<Arc<str>>, range: TimeRange) -> Self {
        Self {
            timeline: timeline.into(),
            range,
        }
    }

    /// Everything ever logged on the timeline.
    pub fn everything(timeline: impl Into<Arc<str>>) -> Self {
        Self::new(timeline, TimeRange::EVERYTHING)
    }

    /// The timeline's name.
    pub fn timeline(&self) -> &str {
        &self.timeline
    }

    /// The inclusive range.
    pub fn range(&self) -> TimeRange {
        self.range
    }
}

/// A chunk contributing to a range result.
#[derive(Debug)]
pub(super) struct Source {
    pub(super) chunk: Arc<Chunk>,
    /// `None` for the static answer: positions are then rows.
    pub(super) time_column: Option<u32>,
    pub(super) component_column: u32,
}

/// Consecutive positions `start..end` of one source, in its `(time, row id)` order.
#[derive(Clone, Copy, Debug)]
pub(super) struct PositionRun {
    pub(super) source: u32,
    pub(super) start: u32,
    pub(super) end: u32,
}

/// The rows a range query answered with, in ascending `(time, row id)` order. Rows whose
/// cell is null are skipped while iterating. Holds the chunks it points into alive.
#[derive(Debug, Default)]
pub struct RangeResult {
    pub(super) sources: Vec<Source>,
    pub(super) runs: Vec<PositionRun>,
}

/// One row of a range result.
#[derive(Clone, Copy, Debug)]
pub struct RangeRow<'a> {
    chunk: &'a Arc<Chunk>,
    column: &'a ComponentColumn,
    row: usize,
    time: Option<TimeInt>,
    row_id: RowId,
}

impl<'a> RangeRow<'a> {
    /// The chunk holding the row.
    pub fn chunk(&self) -> &'a Arc<Chunk> {
        self.chunk
    }

    /// The row within its chunk.
    pub fn row(&self) -> usize {
        self.row
    }

    /// Its time on the queried timeline; `None` for static data.
    pub fn time(&self) -> Option<TimeInt> {
        self.time
    }

    /// Its row id.
    pub fn row_id(&self) -> RowId {
        self.row_id
    }

    /// The component column.
    pub fn column(&self) -> &'a ComponentColumn {
        self.column
    }

    /// The cell's instances, sharing the chunk's buffers.
    pub fn cell(&self) -> ArrayRef {
        self.column.list_array().value(self.row)
    }
}

/// Consecutive rows of one chunk in a range result, in ascending `(time, row id)` order:
/// what a consumer that reads Arrow columns in bulk iterates instead of single rows (one
/// downcast per run rather than per row).
///
/// ```
/// # use std::sync::Arc;
/// # use arrow_array::{cast::AsArray, types::Float64Type, Array, ArrayRef, Float64Array};
/// # use chunkstore::*;
/// # let frame = Timeline::sequence("frame");
/// # let e = EntityPath::parse("e").unwrap();
/// # let v = |x: f64| Arc::new(Float64Array::from(vec![x])) as ArrayRef;
/// # let mut store = ChunkStore::new();
/// # store.insert(ChunkBuilder::new(ChunkId::new(), e.clone())
/// #     .with_row(RowId::new(), [(frame.clone(), 1)], [("speed", v(1.5))])
/// #     .with_row(RowId::new(), [(frame, 2)], [("speed", v(2.5))])
/// #     .build()?)?;
/// let result = store.range(&RangeQuery::everything("frame"), &e, "speed");
/// let mut sum = 0.0;
/// for run in result.runs() {
///     let list = run.column().list_array();
///     let values = list.values().as_primitive::<Float64Type>();
///     for row in run.rows().filter(|&row| list.is_valid(row)) {
///         sum += values.value(list.value_offsets()[row] as usize);
///     }
/// }
/// assert_eq!(sum, 4.0);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct RangeRun<'a> {
    chunk: &'a Arc<Chunk>,
    column: &'a ComponentColumn,
    /// `None` for the static answer.
    times: Option<&'a TimeColumn>,
    start: u32,
    end: u32,
}

impl<'a> RangeRun<'a> {
    /// The chunk holding the rows.
    pub fn chunk(&self) -> &'a Arc<Chunk> {
        self.chunk
    }

    /// The component column.
    pub fn column(&self) -> &'a ComponentColumn {
        self.column
    }

    /// The rows of the run within its chunk, in ascending `(time, row id)` order. Unlike
    /// [`RangeResult::iter`], rows whose cell is null are included: check
    /// [`ComponentColumn::is_valid`].
    pub fn rows(&self) -> RunRows<'a> {
        RunRows {
            order: self.times.and_then(TimeColumn::index_order),
            positions: self.start as usize..self.end as usize,
        }
    }

    /// The rows as one range of the chunk's rows, when the chunk's rows are already in
    /// `(time, row id)` order on the queried timeline (the common case: data logged in
    /// time order, and compacted chunks on their first timeline). Then a reader can slice
    /// the Arrow column itself.
    pub fn contiguous_rows(&self) -> Option<std::ops::Range<usize>> {
        let in_row_order = self.times.is_none_or(|t| t.index_order().is_none());
        in_row_order.then_some(self.start as usize..self.end as usize)
    }

    /// Number of rows, null cells included.
    pub fn len(&self) -> usize {
        (self.end - self.start) as usize
    }

    /// Is the run empty? (Never, for a run of a [`RangeResult`].)
    pub fn is_empty(&self) -> bool {
        self.start == self.end
    }

    /// Row `row` of the chunk, with its time (`None` for static data) and row id.
    fn row_at(&self, row: usize) -> RangeRow<'a> {
        RangeRow {
            chunk: self.chunk,
            column: self.column,
            row,
            time: self.times.map(|t| TimeInt::saturating(t.times()[row])),
            row_id: self.chunk.row_ids()[row],
        }
    }
}

/// The rows of a [`RangeRun`], in ascending `(time, row id)` order.
#[derive(Clone, Debug)]
pub struct RunRows<'a> {
    /// The chunk's `(time, row id)` order, when it is not row order.
    order: Option<&'a [u32]>,
    positions: std::ops::Range<usize>,
}

impl Iterator for RunRows<'_> {
    type Item = usize;

    #[inline]
    fn next(&mut self) -> Option<usize> {
        let pos = self.positions.next()?;
        Some(self.order.map_or(pos, |order| order[pos] as usize))
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        self.positions.size_hint()
    }
}

impl ExactSizeIterator for RunRows<'_> {}

impl RangeResult {
    /// The rows, in ascending `(time, row id)` order.
    pub fn iter(&self) -> impl Iterator<Item = RangeRow<'_>> + '_ {
        self.runs().flat_map(|run| {
            run.rows()
                .filter(move |&row| run.column.is_valid_in_bounds(row))
                .map(move |row| run.row_at(row))
        })
    }

    /// The rows as runs of consecutive rows of one chunk, in ascending `(time, row id)`
    /// order; null cells are not skipped (see [`RangeRun::rows`]).
    pub fn runs(&self) -> impl Iterator<Item = RangeRun<'_>> + '_ {
        self.runs.iter().map(move |run| {
            let source = &self.sources[run.source as usize];
            RangeRun {
                chunk: &source.chunk,
                column: &source.chunk.components()[source.component_column as usize],
                times: source
                    .time_column
                    .map(|t| &source.chunk.time_columns()[t as usize]),
                start: run.start,
                end: run.end,
            }
        })
    }

    /// Number of rows (counts by iterating: null cells are skipped lazily).
    pub fn num_rows(&self) -> usize {
        self.iter().count()
    }

    /// Are there no rows?
    pub fn is_empty(&self) -> bool {
        self.iter().next().is_none()
    }
}

/// A run plus its chunk and the indices of its first and last positions, while building.
struct PendingRun<'a> {
    entry: &'a IndexedChunk,
    run: PositionRun,
    first: (TimeInt, RowId),
    last: (TimeInt, RowId),
}

/// The index of position `pos` of a chunk's `(time, row id)` order on the indexed timeline.
fn index_at_position(entry: &IndexedChunk, pos: usize) -> (TimeInt, RowId) {
    let time_column = entry.time_column as usize;
    let row = entry.chunk.time_columns()[time_column].row_at(pos);
    entry.chunk.index_of_row(time_column, row)
}

impl StoreView {
    /// Every non-null cell of `component` at `entity` with a time in the query's range, in
    /// ascending `(time, row id)` order across all chunks; or, if the entity has static
    /// data for the component, exactly the static winner. Clears do not filter ranges.
    #[expect(
        clippy::cast_possible_truncation,
        reason = "one source per chunk; rows < 2^32"
    )]
    pub fn range(&self, query: &RangeQuery, entity: &EntityPath, component: &str) -> RangeResult {
        let mut result = RangeResult::default();
        let Some(entity_index) = self.entities.get(entity) else {
            return result;
        };
        if let Some(winner) = entity_index.static_winners.get(component) {
            result.sources.push(Source {
                chunk: Arc::clone(&winner.chunk),
                time_column: None,
                component_column: winner.component_column,
            });
            result.runs.push(PositionRun {
                source: 0,
                start: winner.row,
                end: winner.row + 1,
            });
            return result;
        }
        let (min, max) = (query.range.min(), query.range.max());
        if min > max {
            return result;
        }
        let index = entity_index
            .temporal_per_timeline_per_component
            .get(query.timeline())
            .and_then(|per_component| per_component.get(component));
        // The write buffer's chunks, as the index entries they would have (the runs
        // borrow their entries while the result is built).
        let buffered = if entity_index.buffered.is_empty() {
            Vec::new()
        } else {
            entity_index.buffered_entries(query.timeline(), component)
        };
        if index.is_none() && buffered.is_empty() {
            return result;
        }

        let mut pending = Vec::new();
        let mut add = |entry| {
            let source = result.sources.len() as u32;
            if let Some(run) = run_in_chunk(entry, source, min, max) {
                result.sources.push(Source {
                    chunk: Arc::clone(&entry.chunk),
                    time_column: Some(entry.time_column),
                    component_column: entry.component_column,
                });
                pending.push(run);
            }
        };
        if let Some(index) = index {
            index.for_each_reaching_into(min, &mut add);
            index.for_each_starting_in(min, max, &mut add);
        }
        buffered.iter().for_each(&mut add);

        pending.sort_by_key(|p| p.first);
        let mut cluster_start = 0;
        let mut cluster_last = None;
        for i in 0..pending.len() {
            if cluster_last.is_some_and(|last| pending[i].first > last) {
                emit_cluster(&pending[cluster_start..i], &mut result.runs);
                cluster_start = i;
                cluster_last = None;
            }
            cluster_last = cluster_last.max(Some(pending[i].last));
        }
        emit_cluster(&pending[cluster_start..], &mut result.runs);
        result
    }
}

#[expect(
    clippy::cast_possible_truncation,
    reason = "rows < 2^32, checked in Chunk::from_raw"
)]
fn run_in_chunk(
    entry: &IndexedChunk,
    source: u32,
    min: TimeInt,
    max: TimeInt,
) -> Option<PendingRun<'_>> {
    let times = &entry.chunk.time_columns()[entry.time_column as usize];
    // A chunk wholly inside the range needs no search (and its time column is not even
    // read): most chunks of a long range are.
    let bounds = times.time_range();
    let (first_time, last_time) = (bounds.min(), bounds.max());
    let start = if min <= first_time {
        0
    } else {
        times.num_positions_before(min.as_i64())
    };
    let end = if last_time <= max {
        times.times().len()
    } else {
        times.num_positions_at_or_before(max.as_i64())
    };
    (start < end).then(|| PendingRun {
        entry,
        run: PositionRun {
            source,
            start: start as u32,
            end: end as u32,
        },
        first: index_at_position(entry, start),
        last: index_at_position(entry, end - 1),
    })
}

/// The next position of one run in a k-way merge: its index, which run, which position.
type MergeHead = ((TimeInt, RowId), usize, u32);

/// Appends a cluster's runs in global order: as they are for a lone run, merged otherwise.
fn emit_cluster(cluster: &[PendingRun<'_>], out: &mut Vec<PositionRun>) {
    if let [lone] = cluster {
        out.push(lone.run);
        return;
    }
    // Ties on the index (only possible with duplicated row ids) go to the earlier run.
    let mut heap: BinaryHeap<Reverse<MergeHead>> = cluster
        .iter()
        .enumerate()
        .map(|(i, p)| Reverse((p.first, i, p.run.start)))
        .collect();
    while let Some(Reverse((_, i, pos))) = heap.pop() {
        let run = cluster[i].run;
        match out.last_mut() {
            Some(last) if last.source == run.source && last.end == pos => last.end += 1,
            _ => out.push(PositionRun {
                source: run.source,
                start: pos,
                end: pos + 1,
            }),
        }
        if pos + 1 < run.end {
            heap.push(Reverse((
                index_at_position(cluster[i].entry, pos as usize + 1),
                i,
                pos + 1,
            )));
        }
    }
}
