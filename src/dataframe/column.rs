//! A dataframe column while it streams: its sources, and its static cell or its range
//! cursor beside the Clears that apply to it (SEMANTICS.md sections 5 and 9), with the
//! cell rules of the sparse, exact and filled views.

use std::sync::Arc;

use arrow_schema::ArrowError;

use super::DataframeQuery;
use super::cells::{Cell, Sources};
use super::schema::{ColumnPlan, TablePlan};
use crate::clear::ColumnClears;
use crate::query::{RangeCursor, RangeQuery};
use crate::{LatestAtQuery, RowId, StoreView, TimeInt, TimeRange};

pub(super) struct ColumnState {
    pub(super) sources: Sources,
    pub(super) kind: Kind,
}

pub(super) enum Kind {
    /// The entity holds static data for the component: every row shows this cell (null,
    /// when a static Clear hides it: no answer, as latest-at gives none).
    Static(Option<Cell>),
    Temporal(TemporalColumn),
}

/// Fewer rows than this go one at a time even where they form a stretch.
const MIN_STRETCH: usize = 2;

/// Where [`TemporalColumn::take_rows_through`] hands the rows it takes.
pub(super) trait RowSink {
    /// The row `cell` shows at `time`.
    fn row(&mut self, time: TimeInt, cell: Cell);

    /// How many of `times` (a chunk's next rows, in order) show, one for one, on the
    /// batch's next rows from where the first goes: the rows a following
    /// [`Self::stretch`] will take. `0` where the sink takes no stretches.
    fn lead(&mut self, times: &[i64]) -> usize;

    /// Rows `rows` of source `source`, as many as the last [`Self::lead`] counted or
    /// fewer, each the cell of the next of those batch rows.
    fn stretch(&mut self, source: u32, rows: std::ops::Range<u32>);
}

pub(super) struct TemporalColumn {
    /// The column's rows in the range, in `(time, row id)` order (merge mode only). Its
    /// source chunks are registered first among the column's [`Sources`], in the same
    /// order, so a row's source number is the column's.
    pub(super) cursor: Option<RangeCursor>,
    /// Temporal Clears that apply, ascending (in the range, or all of them when
    /// sampling), and the next one to merge.
    pub(super) clears: Vec<(TimeInt, RowId)>,
    pub(super) next_clear: usize,
    /// A static Clear applies: every temporal value is hidden, whenever it was logged.
    pub(super) hidden_by_static_clear: bool,
    /// Do the `clears` hide the column's values (a data component), or only mark where
    /// an ancestor's recursive Clear happened (the `Clear:is_recursive` component, which
    /// no Clear hides: SEMANTICS.md section 5)?
    pub(super) hides: bool,
    /// The latest-at answer at the last row merged (fill mode).
    pub(super) fill: Option<Cell>,
}

impl TemporalColumn {
    /// The time of the column's next event (a row or a Clear) in the merge.
    pub(super) fn next_time(&self) -> Option<TimeInt> {
        let row = self
            .cursor
            .as_ref()
            .and_then(RangeCursor::peek)
            .map(|r| r.time);
        let clear = self.clears.get(self.next_clear).map(|&(time, _)| time);
        match (row, clear) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Replaces `out` with the distinct times of the column's coming rows, then of its
    /// coming Clears (each list ascending), that are at most `bound` (any, if `None`),
    /// at most `cap` of each, calling `merge` with each list: what a batch's row times
    /// are gathered from without consuming anything.
    pub(super) fn coming_times(
        &self,
        bound: Option<TimeInt>,
        cap: usize,
        out: &mut Vec<TimeInt>,
        mut merge: impl FnMut(&[TimeInt]),
    ) {
        let take = |time: TimeInt, out: &mut Vec<TimeInt>| {
            if bound.is_some_and(|bound| time > bound) || out.len() >= cap {
                return false;
            }
            if out.last() != Some(&time) {
                out.push(time);
            }
            true
        };
        out.clear();
        if let Some(cursor) = &self.cursor {
            cursor.times_ahead(|time| take(time, out));
            merge(out);
        }
        out.clear();
        for &(time, _) in self.clears.get(self.next_clear..).unwrap_or_default() {
            if !take(time, out) {
                break;
            }
        }
        merge(out);
    }

    /// Is every coming time of the column (rows and Clears) that is at most `last` one of
    /// the batch's ascending `times` (`known` tells it for one time)? Then merging them
    /// into the batch would add nothing: what [`Self::coming_times`] gathers, checked
    /// without gathering it ([`RangeCursor::times_ahead_known`]).
    pub(super) fn coming_times_known(
        &self,
        last: TimeInt,
        times: &[TimeInt],
        mut known: impl FnMut(TimeInt) -> bool,
    ) -> bool {
        if let Some(cursor) = &self.cursor
            && !cursor.times_ahead_known(last, times, &mut known)
        {
            return false;
        }
        let clears = self.clears.get(self.next_clear..).unwrap_or_default();
        clears
            .iter()
            .take_while(|&&(time, _)| time <= last)
            .all(|&(time, _)| known(time))
    }

    /// The Clears still to come at or before `last`.
    fn clears_through(&self, last: TimeInt) -> &[(TimeInt, RowId)] {
        let ahead = self.clears.get(self.next_clear..).unwrap_or_default();
        &ahead[..ahead.partition_point(|&(time, _)| time <= last)]
    }

    /// Are the column's coming times up to `last` those of `other` (rows and Clears),
    /// told without walking them ([`RangeCursor::same_times_ahead`])? `false` says nothing.
    pub(super) fn same_times_ahead(&self, other: &Self, last: TimeInt) -> bool {
        let (mine, theirs) = (self.clears_through(last), other.clears_through(last));
        mine.iter().map(|c| c.0).eq(theirs.iter().map(|c| c.0))
            && match (&self.cursor, &other.cursor) {
                (Some(mine), Some(theirs)) => mine.same_times_ahead(theirs, last),
                (None, None) => true,
                _ => false,
            }
    }

    /// Consumes the column's rows up to `last` when no Clear applies to them (none in
    /// the range up to `last`, no static one): the common case, where every event is a
    /// row and shows itself. Hands `sink` each time and the row it shows (of the rows at
    /// one time, the greatest row id's), or, where the sink takes them, a stretch of a
    /// chunk's rows at once. Consumes nothing when a Clear applies:
    /// [`Self::take_events_at`] handles those.
    #[inline]
    pub(super) fn take_rows_through(&mut self, last: TimeInt, sink: &mut impl RowSink) {
        let clear_due = self
            .clears
            .get(self.next_clear)
            .is_some_and(|&(t, _)| t <= last);
        if clear_due || self.hidden_by_static_clear {
            return;
        }
        let Some(cursor) = &mut self.cursor else {
            return;
        };
        // Rows to take one by one before looking for a stretch again: a column whose
        // rows are not the batch's next ones looks once per decoded block.
        let mut before_stretch = 0;
        while let Some(row) = cursor.peek().filter(|row| row.time <= last) {
            if before_stretch == 0 {
                if let Some((source, first, times)) = cursor.dense_ahead() {
                    // The run's last row may tie with the next run's first (the later
                    // row id shows): it is taken alone.
                    let candidates = &times[..times.len() - 1];
                    let mut n = sink.lead(candidates);
                    // Within a chunk, of rows tied on a time the last shows.
                    if n > 0 && times[n] == times[n - 1] {
                        n -= 1;
                    }
                    if n >= MIN_STRETCH {
                        let n32 = u32::try_from(n).unwrap_or(u32::MAX);
                        sink.stretch(source, first..first.saturating_add(n32));
                        cursor.skip_dense(n);
                        continue;
                    }
                }
                before_stretch = crate::query::CURSOR_BLOCK;
            }
            before_stretch -= 1;
            cursor.advance();
            // Rows at one time come in row id order: the last of them shows.
            if cursor.peek().is_none_or(|next| next.time != row.time) {
                sink.row(
                    row.time,
                    Cell::Row {
                        source: row.source,
                        row: row.row,
                    },
                );
            }
        }
    }

    /// Consumes every event (row or Clear) at or before `last` without looking at it: for
    /// a column whose cells the batch does not build and whose rows raise no other index
    /// column, only its times mattered, and the batch's row times already hold them.
    pub(super) fn skip_through(&mut self, last: TimeInt) {
        self.next_clear += self.clears_through(last).len();
        if let Some(cursor) = &mut self.cursor {
            cursor.skip_through(last);
        }
    }

    /// Consumes every event at `time` and returns the cell the row shows (the row of
    /// greatest row id, an empty list where a Clear came later (the Clear's mark), or null
    /// where a static Clear hides the row), and that row of greatest row id itself, shown
    /// or not: what filling goes on with in a column no Clear hides.
    pub(super) fn take_events_at(&mut self, time: TimeInt) -> (Option<Cell>, Option<Cell>) {
        let mut row = None;
        let mut clear = None;
        while let Some(&(_, row_id)) = self.clears.get(self.next_clear).filter(|c| c.0 == time) {
            clear = Some(row_id);
            self.next_clear += 1;
        }
        let mut latest = None;
        if let Some(cursor) = &mut self.cursor {
            while let Some(next) = cursor.peek().filter(|r| r.time == time) {
                row = Some(next);
                cursor.advance();
            }
            latest = row.map(|row| Cell::Row {
                source: row.source,
                row: row.row,
            });
            if let (Some(found), Some(clear)) = (row, clear)
                && clear >= cursor.row_id(found)
            {
                row = None; // the Clear came later: an empty list below
            }
        }
        if self.hidden_by_static_clear {
            row = None; // hidden whenever it was logged: null, or the mark of a Clear here
        }
        let shown = match (row, clear) {
            (Some(row), _) => Some(Cell::Row {
                source: row.source,
                row: row.row,
            }),
            (None, Some(_)) => Some(Cell::Empty),
            (None, None) => None,
        };
        (shown, latest)
    }
}

/// The sparse view's cell at exactly `at` (as [`TemporalColumn::take_events_at`] gives
/// it), from the unfiltered latest-at answer there and the column's Clears: the answer if
/// it was logged at `at` (and no Clear there came later, and no static Clear hides it);
/// an empty list where a Clear at `at` marks the column; else null.
pub(super) fn exact_cell(
    answer: Option<((TimeInt, RowId), Cell)>,
    clears: &[(TimeInt, RowId)],
    at: TimeInt,
    hidden_by_static_clear: bool,
) -> Option<Cell> {
    let end = clears.partition_point(|&(t, _)| t <= at);
    let mark = end
        .checked_sub(1)
        .map(|i| clears[i])
        .filter(|&(t, _)| t == at)
        .map(|(_, row_id)| row_id);
    let row = answer
        .filter(|&((time, row_id), _)| {
            time == at && !hidden_by_static_clear && mark.is_none_or(|m| m < row_id)
        })
        .map(|(_, cell)| cell);
    match (row, mark) {
        (Some(cell), _) => Some(cell),
        (None, Some(_)) => Some(Cell::Empty),
        (None, None) => None,
    }
}

/// The cell of latest-at semantics given the unfiltered answer's index and the latest
/// Clear that applies (SEMANTICS.md sections 3 and 5): a Clear at or after the answer
/// hides it, and a hidden answer is no answer (null), as latest-at gives none.
pub(super) fn visible_cell(
    answer: Option<((TimeInt, RowId), Cell)>,
    latest_clear: Option<(TimeInt, RowId)>,
    hidden_by_static_clear: bool,
) -> Option<Cell> {
    if hidden_by_static_clear {
        return None;
    }
    match (answer, latest_clear) {
        (Some((index, _)), Some(clear)) if index <= clear => None,
        (Some((_, cell)), _) => Some(cell),
        (None, _) => None,
    }
}

/// About how many bytes a row of the selected columns takes in a batch: a static column's
/// cell (copied into every row), a temporal column's average cell in its source chunks
/// where that is large, else its offset.
pub(super) fn row_bytes(columns: &[ColumnState], selected: &[bool]) -> usize {
    columns
        .iter()
        .zip(selected)
        .filter(|(_, selected)| **selected)
        .map(|(column, _)| match &column.kind {
            Kind::Static(Some(Cell::Row { source, row })) => {
                column.sources.cell_bytes(*source, Some(*row))
            }
            Kind::Static(_) => 4,
            // Most temporal cells of a wide table are null in any one row: a small cell
            // costs its offset; a large one (an image) its bytes, as if in every row.
            Kind::Temporal(_) => match column.sources.average_cell_bytes() {
                large if large >= LARGE_CELL_BYTES => large,
                _ => 4,
            },
        })
        .sum()
}

/// A temporal column whose cells average this many bytes or more counts them in every
/// row of a batch's byte estimate.
pub(super) const LARGE_CELL_BYTES: usize = 256;

/// The starting state of one column: its sources, its static cell or its cursor and
/// Clears, and in fill mode its latest-at answer just before the range.
pub(super) fn column_state(
    store: &StoreView,
    plan: &TablePlan,
    column: &ColumnPlan,
    range: TimeRange,
    query: &DataframeQuery,
    merge: bool,
) -> Result<ColumnState, ArrowError> {
    let mut sources = Sources::new(Arc::clone(&column.item_field));
    let timeline = plan.index.name();
    // A Clear hides every component but the Clear component itself (SEMANTICS.md
    // section 5); that column only shows the marks of its ancestors' recursive Clears
    // (section 9).
    let hides = !column.component.is_clear();
    let clears = if hides {
        store.clears.column_clears(&column.entity, timeline, range)
    } else {
        ColumnClears {
            in_range: store
                .clears
                .ancestor_recursive_clears(&column.entity, timeline, range),
            ..ColumnClears::default()
        }
    };
    let entity_index = store.entities.get(&column.entity);
    if let Some(winner) = entity_index.and_then(|e| e.static_winners.get(&column.component)) {
        let hidden = clears.latest_static.is_some_and(|c| winner.row_id <= c);
        let cell = if hidden {
            None
        } else {
            Some(Cell::Row {
                source: sources.push(
                    &winner.chunk,
                    winner.component_column,
                    &plan.index_columns,
                    Some(plan.index_position),
                )?,
                row: winner.row,
            })
        };
        return Ok(ColumnState {
            sources,
            kind: Kind::Static(cell),
        });
    }
    let hidden_by_static_clear = clears.latest_static.is_some();
    let mut temporal = TemporalColumn {
        cursor: None,
        clears: clears.in_range,
        next_clear: 0,
        hidden_by_static_clear,
        hides,
        fill: None,
    };
    if merge {
        let result = store.range(
            &RangeQuery::new(Arc::clone(plan.index.name_arc()), range),
            &column.entity,
            column.component.as_str(),
        );
        let cursor = RangeCursor::new(result);
        for source in 0..cursor.num_sources() {
            let (chunk, component_column) = cursor.source(source);
            let number = sources.push(
                chunk,
                component_column,
                &plan.index_columns,
                Some(plan.index_position),
            )?;
            if number != source {
                return Err(ArrowError::ComputeError(format!(
                    "dataframe column {}:{}: cursor source {source} registered as {number}",
                    column.entity, column.component
                )));
            }
        }
        temporal.cursor = Some(cursor);
        if query.fill_latest_at {
            let before = range
                .min()
                .as_i64()
                .checked_sub(1)
                .and_then(TimeInt::new)
                .filter(|_| !range.is_empty());
            let answer = before.and_then(|at| {
                let query = LatestAtQuery::new(Arc::clone(plan.index.name_arc()), at);
                store.latest_at_unfiltered(&query, &column.entity, column.component.as_str())
            });
            let answer = match answer {
                Some(answer) => {
                    let source = sources.find_or_push(
                        answer.chunk(),
                        answer.component_column_index(),
                        &plan.index_columns,
                        Some(plan.index_position),
                    )?;
                    answer
                        .time()
                        .zip(u32::try_from(answer.row()).ok())
                        .map(|(time, row)| ((time, answer.row_id()), Cell::Row { source, row }))
                }
                None => None,
            };
            temporal.fill = visible_cell(answer, clears.latest_before, hidden_by_static_clear);
        }
    }
    Ok(ColumnState {
        sources,
        kind: Kind::Temporal(temporal),
    })
}
