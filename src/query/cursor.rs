//! [`RangeCursor`]: walks a temporal range result row by row without borrowing it, a block
//! of rows decoded at a time, for the dataframe's merge across thousands of columns (which
//! keeps each column's result and its position side by side).

use std::sync::Arc;

use arrow_array::Array;

use super::range::{RangeResult, Source};
use crate::{Chunk, RowId, TimeInt};

/// One row a [`RangeCursor`] stands on: 16 bytes, four to a cache line (its row id, which
/// only a same-time tie needs, is read from the chunk: [`RangeCursor::row_id`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct CursorRow {
    pub time: TimeInt,
    /// Which of the result's chunks ([`RangeCursor::source`]).
    pub source: u32,
    pub row: u32,
}

/// Rows a [`RangeCursor`] decodes at once. A merge over thousands of columns steps each
/// cursor once per row it emits; decoding a block at a time walks the chain from result to
/// chunk to column once per block, and each step then reads the next entry of a small
/// buffer instead of missing the cache on every link of that chain.
pub(crate) const CURSOR_BLOCK: usize = 32;

/// Walks a temporal [`RangeResult`] row by row without borrowing it, so that a streaming
/// reader (the dataframe's merge) can keep the result and its position side by side.
#[derive(Debug)]
pub(crate) struct RangeCursor {
    result: RangeResult,
    run: usize,
    /// The next position to decode inside run `run`.
    position: u32,
    /// Decoded rows, from `next` on still to come.
    block: Vec<CursorRow>,
    next: usize,
    /// `(run, count)`: the block's first `count` rows come from run `run`, a stretch of
    /// its chunk's rows in their own order (a chunk sorted on the timeline, a column
    /// without null cells), and the rest of the run follows them row by row
    /// ([`Self::dense_ahead`]).
    dense: Option<(usize, usize)>,
}

impl RangeCursor {
    /// A cursor on the first non-null row of `result` (a temporal result: static answers
    /// have no time to merge on and are never walked).
    pub fn new(result: RangeResult) -> Self {
        let position = result.runs.first().map_or(0, |run| run.start);
        let mut cursor = Self {
            result,
            run: 0,
            position,
            block: Vec::new(),
            next: 0,
            dense: None,
        };
        cursor.refill();
        cursor
    }

    /// The row the cursor stands on; `None` once past the last.
    #[inline]
    pub fn peek(&self) -> Option<CursorRow> {
        self.block.get(self.next).copied()
    }

    /// Moves to the next non-null row.
    #[inline]
    pub fn advance(&mut self) {
        self.next += 1;
        if self.next >= self.block.len() {
            self.refill();
        }
    }

    /// Are this cursor's rows still to come, up to time `last`, at the same times as
    /// `other`'s, told without walking them? They are where both have decoded the same
    /// times and go on with the same runs of the same chunks' time columns, in columns
    /// without a null cell (so that every position is a row of both): an entity's
    /// components logged together. `false` says nothing.
    pub fn same_times_ahead(&self, other: &Self, last: TimeInt) -> bool {
        let (mine, theirs) = (&self.block[self.next..], &other.block[other.next..]);
        if mine.len() != theirs.len() || mine.iter().zip(theirs).any(|(a, b)| a.time != b.time) {
            return false;
        }
        if mine.last().is_some_and(|row| row.time > last) {
            return true; // everything after comes later than `last`
        }
        if self.position != other.position {
            return false;
        }
        let mine = self.result.runs.get(self.run..).unwrap_or_default();
        let theirs = other.result.runs.get(other.run..).unwrap_or_default();
        let mut position = self.position;
        for (run, their_run) in mine.iter().zip(theirs) {
            let source = &self.result.sources[run.source as usize];
            let their_source = &other.result.sources[their_run.source as usize];
            let same = (run.start, run.end) == (their_run.start, their_run.end)
                && Arc::ptr_eq(&source.chunk, &their_source.chunk)
                && source.time_column == their_source.time_column;
            let Some(time_column) = source.time_column.filter(|_| same) else {
                return false;
            };
            let start = position.max(run.start);
            position = 0;
            if start >= run.end {
                continue;
            }
            let times = &source.chunk.time_columns()[time_column as usize];
            if TimeInt::saturating(times.times()[times.row_at(start as usize)]) > last {
                return true;
            }
            let has_nulls = |source: &Source| {
                source.chunk.components()[source.component_column as usize]
                    .list_array()
                    .null_count()
                    > 0
            };
            if has_nulls(source) || has_nulls(their_source) {
                return false;
            }
        }
        mine.len() == theirs.len()
    }

    /// Calls `visit` with the times of the rows still to come, in order, without moving,
    /// until it returns `false` or the rows end. A column-at-a-time reader (the
    /// dataframe's batches) learns where a batch ends from every column's coming times
    /// before it consumes any.
    pub fn times_ahead(&self, mut visit: impl FnMut(TimeInt) -> bool) {
        for row in &self.block[self.next..] {
            if !visit(row.time) {
                return;
            }
        }
        let mut position = self.position;
        for run in self.result.runs.get(self.run..).unwrap_or_default() {
            let start = position.max(run.start);
            position = 0;
            let source = &self.result.sources[run.source as usize];
            let Some(time_column) = source.time_column else {
                continue;
            };
            let column = &source.chunk.components()[source.component_column as usize];
            let times = &source.chunk.time_columns()[time_column as usize];
            let values = times.times();
            for pos in start..run.end {
                let row = times.row_at(pos as usize);
                if column.is_valid_in_bounds(row) && !visit(TimeInt::saturating(values[row])) {
                    return;
                }
            }
        }
    }

    /// Is the time of every row still to come, up to `last`, one of the ascending distinct
    /// `times` (`known` tells it for one time)? Where a run's rows are a slice of its
    /// chunk's row-ordered times without a null cell (an entity logging at every tick),
    /// the slice is compared with the run of `times` it starts at: one comparison of
    /// slices rather than a look-up per row. A slice that does not match is looked up
    /// time by time, so the answer is the same either way.
    pub fn times_ahead_known(
        &self,
        last: TimeInt,
        times: &[TimeInt],
        mut known: impl FnMut(TimeInt) -> bool,
    ) -> bool {
        for row in &self.block[self.next..] {
            if row.time > last {
                return true;
            }
            if !known(row.time) {
                return false;
            }
        }
        let mut position = self.position;
        // Where the previous run's matched times ended (the next run may start with its
        // last time, duplicated across chunks).
        let mut from = 0;
        for run in self.result.runs.get(self.run..).unwrap_or_default() {
            let start = position.max(run.start) as usize;
            position = 0;
            let source = &self.result.sources[run.source as usize];
            let Some(time_column) = source.time_column else {
                continue;
            };
            let column = &source.chunk.components()[source.component_column as usize];
            let time_column = &source.chunk.time_columns()[time_column as usize];
            let values = time_column.times();
            let end = run.end as usize;
            if time_column.index_order().is_none() && column.list_array().null_count() == 0 {
                let run_times = values.get(start..end).unwrap_or_default();
                let due = run_times.partition_point(|&v| TimeInt::saturating(v) <= last);
                if let Some(&first) = run_times.first().filter(|_| due > 0) {
                    let first = TimeInt::saturating(first);
                    let at = from + times[from.min(times.len())..].partition_point(|&t| t < first);
                    let same = times.get(at..at + due).is_some_and(|known_run| {
                        crate::time::leading_equal(known_run, &run_times[..due]) == due
                    });
                    if same {
                        from = at + due - 1;
                    } else if !run_times[..due]
                        .iter()
                        .all(|&v| known(TimeInt::saturating(v)))
                    {
                        return false;
                    }
                }
                if due < run_times.len() {
                    return true;
                }
                continue;
            }
            for pos in start..end {
                let row = time_column.row_at(pos);
                if !column.is_valid_in_bounds(row) {
                    continue;
                }
                let time = TimeInt::saturating(values[row]);
                if time > last {
                    return true;
                }
                if !known(time) {
                    return false;
                }
            }
        }
        true
    }

    /// Moves past every row at or before `last`, without decoding them: a column that
    /// only decides which rows a table has (one left out of its projection) finds the
    /// first later row of each run by a search of its chunk's time column.
    /// The cursor ends where [`Self::advance`] would have left it.
    #[expect(
        clippy::cast_possible_truncation,
        reason = "rows < 2^32, checked in Chunk::from_raw"
    )]
    pub fn skip_through(&mut self, last: TimeInt) {
        let ahead = &self.block[self.next..];
        let at_or_before = ahead.partition_point(|row| row.time <= last);
        if at_or_before < ahead.len() {
            self.next += at_or_before;
            return;
        }
        // Everything decoded is at or before `last`: `position` is the first row not
        // decoded. Runs are in global order and a run's positions in its own, so the rows
        // at or before `last` are a prefix of what is left.
        while let Some(run) = self.result.runs.get(self.run).copied() {
            let start = self.position.max(run.start);
            let source = &self.result.sources[run.source as usize];
            // A run is a range of its chunk's positions, in which times ascend: the
            // column's own partition point, kept inside the run.
            let later = source.time_column.map_or(run.end as usize, |time_column| {
                source.chunk.time_columns()[time_column as usize]
                    .num_positions_at_or_before(last.as_i64())
                    .max(start as usize)
                    .min(run.end as usize)
            });
            if later < run.end as usize {
                self.position = later as u32;
                break;
            }
            self.run += 1;
            if let Some(next) = self.result.runs.get(self.run) {
                self.position = next.start;
            }
        }
        self.refill();
    }

    /// The rows from the cursor's on to the end of its run as one stretch of one chunk's
    /// rows, where they are one (a chunk sorted on the timeline whose column has no null
    /// cell: the cursor's rows are then the chunk's rows in order): the source, the first
    /// row, and the times of the rows from it to the run's end. A reader taking a whole
    /// stretch at once ([`Self::skip_dense`]) does a few instructions per row where a row
    /// at a time takes dozens.
    pub fn dense_ahead(&self) -> Option<(u32, u32, &[i64])> {
        let (run, count) = self.dense?;
        if self.next >= count {
            return None;
        }
        let row = self.block.get(self.next)?;
        let run = self.result.runs.get(run)?;
        let source = &self.result.sources[run.source as usize];
        let time_column = &source.chunk.time_columns()[source.time_column? as usize];
        let times = time_column
            .times()
            .get(row.row as usize..run.end as usize)?;
        Some((run.source, row.row, times))
    }

    /// Moves past the first `n` rows of the stretch [`Self::dense_ahead`] gave (at most
    /// its length): the cursor ends where `n` calls of [`Self::advance`] leave it.
    #[expect(
        clippy::cast_possible_truncation,
        reason = "rows < 2^32, checked in Chunk::from_raw"
    )]
    pub fn skip_dense(&mut self, n: usize) {
        let Some((run, count)) = self.dense else {
            return;
        };
        let decoded = count.saturating_sub(self.next);
        if n < decoded || run != self.run {
            // Within the decoded rows (all of the run's, if the block went on past it).
            self.next += n.min(decoded);
            if self.next >= self.block.len() {
                self.refill();
            }
            return;
        }
        // Past the decoded rows: the run goes on row by row from the stretch's first.
        if let Some(first) = self.block.get(self.next) {
            self.position = first.row + n as u32;
        }
        self.refill();
    }

    /// How many chunks the result's rows come from.
    #[expect(clippy::cast_possible_truncation, reason = "one source per chunk")]
    pub fn num_sources(&self) -> u32 {
        self.result.sources.len() as u32
    }

    /// The row id of `row`.
    pub fn row_id(&self, row: CursorRow) -> RowId {
        self.result.sources[row.source as usize].chunk.row_ids()[row.row as usize]
    }

    /// The chunk and component column of source `source`.
    pub fn source(&self, source: u32) -> (&Arc<Chunk>, u32) {
        let source = &self.result.sources[source as usize];
        (&source.chunk, source.component_column)
    }

    /// Decodes the next non-null rows, up to a block of them (none: the end).
    #[expect(
        clippy::cast_possible_truncation,
        reason = "rows < 2^32, checked in Chunk::from_raw"
    )]
    fn refill(&mut self) {
        self.block.clear();
        self.next = 0;
        self.dense = None;
        while self.block.len() < CURSOR_BLOCK {
            let Some(run) = self.result.runs.get(self.run).copied() else {
                return;
            };
            if self.position >= run.end {
                self.run += 1;
                if let Some(next) = self.result.runs.get(self.run) {
                    self.position = next.start;
                }
                continue;
            }
            let source = &self.result.sources[run.source as usize];
            let end = run
                .end
                .min(self.position + (CURSOR_BLOCK - self.block.len()) as u32);
            let Some(time_column) = source.time_column else {
                self.position = run.end; // a static answer has no place in a time merge
                continue;
            };
            let column = &source.chunk.components()[source.component_column as usize];
            let times = &source.chunk.time_columns()[time_column as usize];
            let values = times.times();
            let first_rows = self.block.is_empty();
            for pos in self.position..end {
                let row = times.row_at(pos as usize);
                if column.is_valid_in_bounds(row) {
                    self.block.push(CursorRow {
                        time: TimeInt::saturating(values[row]),
                        source: run.source,
                        row: row as u32,
                    });
                }
            }
            // The block's first rows, of a run whose rows are its chunk's in order: the
            // run is decoded once per refill, so these are all of them in the block.
            if first_rows
                && !self.block.is_empty()
                && times.index_order().is_none()
                && column.list_array().null_count() == 0
            {
                self.dense = Some((self.run, self.block.len()));
            }
            self.position = end;
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::{ArrayRef, Float64Array};

    use super::{CursorRow, RangeCursor};
    use crate::query::RangeQuery;
    use crate::{ChunkBuilder, ChunkId, ChunkStore, EntityPath, RowId, StoreConfig, TimeInt};
    use crate::{TimeRange, Timeline};

    /// One entity's `x` over chunks of every shape a run can have: sorted and not, a null
    /// cell, a time shared across chunks, overlapping chunks (merged runs), and more rows
    /// than a cursor decodes at once.
    fn cursor() -> RangeCursor {
        let entity = EntityPath::parse("e").unwrap();
        let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).unwrap();
        let value = || Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
        let chunks: [&[i64]; 7] = [
            &[1, 2, 3, 4],
            &[4, 6, 5, 8],
            &[9, 10, 11, 12],
            &[12, 13],
            &[20, 21, 22],
            &[
                30, 31, 32, 33, 34, 35, 36, 37, 38, 39, 40, 41, 42, 43, 44, 45, 46, 47, 48, 49,
            ],
            &[
                40, 41, 42, 43, 44, 45, 46, 47, 48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59,
            ],
        ];
        for frames in chunks {
            let mut builder = ChunkBuilder::new(ChunkId::new(), entity.clone());
            for &frame in frames {
                // Frame 10 has no `x`: a null cell the cursor skips.
                let component = if frame == 10 { "y" } else { "x" };
                builder = builder.with_row(
                    RowId::new(),
                    [(Timeline::sequence("frame"), frame)],
                    [(component, value())],
                );
            }
            store.insert(builder.build().unwrap()).unwrap();
        }
        let query = RangeQuery::new("frame", TimeRange::EVERYTHING);
        RangeCursor::new(store.range(&query, &entity, "x"))
    }

    fn rest(mut cursor: RangeCursor) -> Vec<CursorRow> {
        let mut rows = Vec::new();
        while let Some(row) = cursor.peek() {
            rows.push(row);
            cursor.advance();
        }
        rows
    }

    fn t(time: i64) -> TimeInt {
        TimeInt::new(time).unwrap()
    }

    /// From any row, skipping through any time leaves the cursor where advancing row by
    /// row past that time does.
    #[test]
    fn skipping_through_a_time_ends_where_advancing_does() {
        let all = rest(cursor());
        assert!(all.len() > super::CURSOR_BLOCK, "runs past a decoded block");
        assert!(
            all.iter().all(|row| row.time != t(10)),
            "the null cell is no row"
        );
        for start in 0..=all.len() {
            for last in -1..62 {
                let mut skipping = cursor();
                for _ in 0..start {
                    skipping.advance();
                }
                skipping.skip_through(t(last));
                let expected: Vec<CursorRow> = all[start..]
                    .iter()
                    .copied()
                    .filter(|row| row.time > t(last))
                    .collect();
                assert_eq!(rest(skipping), expected, "from row {start} through {last}");
            }
        }
    }

    /// Whether the coming times are known is answered as a look-up per time answers it,
    /// for batches holding all of them, all but one, and more.
    #[test]
    fn coming_times_known_by_runs_as_by_looking_each_up() {
        let all = rest(cursor());
        let mut distinct: Vec<TimeInt> = all.iter().map(|row| row.time).collect();
        distinct.dedup();
        let mut batches = vec![distinct.clone(), (0..70).map(t).collect()];
        for missing in 0..distinct.len() {
            let mut batch = distinct.clone();
            batch.remove(missing);
            batches.push(batch);
        }
        for batch in &batches {
            for start in [0, 1, 5, 30, 40, all.len()] {
                for last in -1..62 {
                    let mut cursor = cursor();
                    for _ in 0..start {
                        cursor.advance();
                    }
                    let known = |time: TimeInt| batch.binary_search(&time).is_ok();
                    let expected = all[start..]
                        .iter()
                        .filter(|row| row.time <= t(last))
                        .all(|row| known(row.time));
                    assert_eq!(
                        cursor.times_ahead_known(t(last), batch, known),
                        expected,
                        "from row {start} through {last}, batch {batch:?}"
                    );
                }
            }
        }
    }
}
