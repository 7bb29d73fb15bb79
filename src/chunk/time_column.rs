//! [`TimeColumn`]: one timeline's times in a chunk, their `(time, row id)` order, and the
//! guided search every query runs over them.

use arrow_array::{Array, ArrayRef, DurationNanosecondArray, Int64Array, TimestampNanosecondArray};
use arrow_buffer::ScalarBuffer;
use arrow_schema::DataType;

use super::metadata::Metadata;
use crate::ChunkError;
use crate::sanity::{SanityError, Structure};
use crate::{RowId, TimeInt, TimeRange, Timeline};

/// One timeline's times in a chunk.
#[derive(Debug)]
// What a query's search reads first (the times, their range and order), so that it shares
// the chunk's first cache lines with the component columns (see `Chunk`'s layout).
#[repr(C)]
pub struct TimeColumn {
    pub(super) times: ScalarBuffer<i64>,
    pub(super) time_range: TimeRange,
    /// Row positions in ascending `(time, row id)` order; `None` when the rows already are.
    pub(super) index_order: Option<Box<[u32]>>,
    pub(super) timeline: Timeline,
    /// The column's Arrow type as given (a timestamp may carry a timezone).
    pub(super) data_type: DataType,
    /// Field metadata as given, for lossless transport.
    pub(super) field_metadata: Metadata,
    pub(super) is_sorted: bool,
}

pub(super) struct RawTimeColumn {
    pub(super) timeline: Timeline,
    pub(super) times: RawTimes,
    pub(super) field_metadata: Metadata,
}

/// A time column's data before validation.
pub(super) enum RawTimes {
    /// As given: checked for length and nulls, then read as `i64`.
    Array(ArrayRef),
    /// Copied from a valid column (compaction, slices): already `i64`, without nulls.
    Copied {
        times: ScalarBuffer<i64>,
        data_type: DataType,
    },
}

/// The values of a timeline's array: all three timeline types are 64-bit primitives.
/// Read through the typed array, which holds them already sliced (building an `ArrayData`
/// to reach the buffer cost a small chunk more than the column's own checks).
fn i64_times(array: &ArrayRef) -> Option<ScalarBuffer<i64>> {
    let any = array.as_any();
    if let Some(times) = any.downcast_ref::<Int64Array>() {
        return Some(times.values().clone());
    }
    if let Some(times) = any.downcast_ref::<TimestampNanosecondArray>() {
        return Some(times.values().clone());
    }
    any.downcast_ref::<DurationNanosecondArray>()
        .map(|times| times.values().clone())
}

impl TimeColumn {
    #[expect(
        clippy::cast_possible_truncation,
        reason = "rows < 2^32, checked in Chunk::from_raw"
    )]
    pub(super) fn try_new(raw: RawTimeColumn, row_ids: &[RowId]) -> Result<Self, ChunkError> {
        let RawTimeColumn {
            timeline,
            times,
            field_metadata,
        } = raw;
        let name = || timeline.name().to_owned();
        let (times, data_type) = match times {
            RawTimes::Array(array) => {
                if array.len() != row_ids.len() {
                    return Err(ChunkError::LengthMismatch {
                        column: name(),
                        expected: row_ids.len(),
                        actual: array.len(),
                    });
                }
                if array.null_count() > 0 {
                    return Err(ChunkError::NullTimes {
                        timeline: name(),
                        null_count: array.null_count(),
                    });
                }
                let times = i64_times(&array).ok_or_else(|| ChunkError::BadTimeType {
                    timeline: name(),
                    data_type: array.data_type().clone(),
                })?;
                (times, array.data_type().clone())
            }
            RawTimes::Copied { times, data_type } => (times, data_type),
        };
        if times.len() != row_ids.len() {
            // Only a copy made by this crate gets here with another length: a bug.
            return Err(ChunkError::LengthMismatch {
                column: name(),
                expected: row_ids.len(),
                actual: times.len(),
            });
        }
        // One pass for both orders: a tie of times is in index order when its row ids
        // are. Sorted times (the usual case) then give the reserved-time check and the
        // range from their ends; only unsorted ones are read again.
        let (mut is_sorted, mut in_index_order) = (true, true);
        for (t, r) in times.windows(2).zip(row_ids.windows(2)) {
            if t[0] > t[1] {
                is_sorted = false;
                break;
            }
            in_index_order &= t[0] < t[1] || r[0] <= r[1];
        }
        in_index_order &= is_sorted;
        let reserved = if is_sorted {
            times.first().is_some_and(|&t| t == i64::MIN).then_some(0)
        } else {
            times.iter().position(|&t| t == i64::MIN)
        };
        if let Some(row) = reserved {
            return Err(ChunkError::ReservedTime {
                timeline: name(),
                row,
            });
        }
        let index_order = (!in_index_order).then(|| {
            let mut order: Vec<u32> = (0..row_ids.len() as u32).collect();
            order.sort_by_key(|&i| (times[i as usize], row_ids[i as usize]));
            order.into_boxed_slice()
        });
        let (min, max) = match (is_sorted, times.first(), times.last()) {
            (true, Some(&first), Some(&last)) => (first, last),
            _ => times.iter().fold((i64::MAX, i64::MIN + 1), |(lo, hi), &t| {
                (lo.min(t), hi.max(t))
            }),
        };
        Ok(Self {
            timeline,
            data_type,
            times,
            field_metadata,
            is_sorted,
            index_order,
            time_range: TimeRange::new(TimeInt::saturating(min), TimeInt::saturating(max)),
        })
    }

    pub(super) fn sanity_check(&self, row_ids: &[RowId]) -> Result<(), SanityError> {
        let Self {
            timeline,
            times,
            data_type,
            field_metadata: _, // as given, for transport only
            is_sorted,
            index_order,
            time_range,
        } = self;
        let fail =
            |invariant| Err(SanityError::new(Structure::TimeColumn, invariant).at(timeline.name()));
        if times.len() != row_ids.len() {
            return fail("a time column has one time per row");
        }
        if crate::TimeType::from_arrow(data_type) != Some(timeline.time_type()) {
            return fail("the Arrow type matches the timeline's type");
        }
        if times.contains(&i64::MIN) {
            return fail("no time is the reserved i64::MIN");
        }
        if *is_sorted != times.is_sorted() {
            return fail("is_sorted matches the times");
        }
        let (lo, hi) = (times.iter().min(), times.iter().max());
        if (lo.copied(), hi.copied())
            != (
                Some(time_range.min().as_i64()),
                Some(time_range.max().as_i64()),
            )
        {
            return fail("the time range spans the times");
        }
        let key = |i: usize| (times[i], row_ids[i]);
        let ordered = match index_order {
            Some(order) => {
                let mut seen = order.to_vec();
                seen.sort_unstable();
                seen.iter().enumerate().all(|(i, &row)| row as usize == i)
                    && order
                        .windows(2)
                        .all(|w| key(w[0] as usize) <= key(w[1] as usize))
                    && !(1..times.len()).all(|i| key(i - 1) <= key(i))
            }
            None => (1..times.len()).all(|i| key(i - 1) <= key(i)),
        };
        if !ordered {
            return fail(
                "the index order is a permutation sorting by (time, row id), kept only when \
                 row order is not",
            );
        }
        Ok(())
    }

    /// The timeline.
    pub fn timeline(&self) -> &Timeline {
        &self.timeline
    }

    /// The times, in row order.
    pub fn times(&self) -> &[i64] {
        &self.times
    }

    /// The Arrow type of the column as it was given.
    pub fn data_type(&self) -> &DataType {
        &self.data_type
    }

    /// Are the times non-decreasing in row order?
    pub fn is_sorted(&self) -> bool {
        self.is_sorted
    }

    /// Least and greatest time.
    pub fn time_range(&self) -> TimeRange {
        self.time_range
    }

    /// The row at position `pos` of ascending `(time, row id)` order.
    #[inline]
    pub(crate) fn row_at(&self, pos: usize) -> usize {
        match &self.index_order {
            Some(order) => order[pos] as usize,
            None => pos,
        }
    }

    /// The rows in ascending `(time, row id)` order, when that is not row order.
    pub(crate) fn index_order(&self) -> Option<&[u32]> {
        self.index_order.as_deref()
    }

    /// Number of positions whose time is `<= t` (a partition point in index order).
    pub(crate) fn num_positions_at_or_before(&self, t: i64) -> usize {
        self.partition_point(t, |time| time <= t, |_| {})
    }

    /// [`TimeColumn::num_positions_at_or_before`], calling `first_probe` with the row the
    /// search reads first, before it reads it (a guided search's guess: see
    /// [`guided_partition_point`]), so that the caller can start loading what it will read
    /// of that row while the search waits for its times.
    pub(crate) fn num_positions_at_or_before_touching(
        &self,
        t: i64,
        first_probe: impl FnOnce(usize),
    ) -> usize {
        self.partition_point(t, |time| time <= t, first_probe)
    }

    /// Number of positions whose time is `< t`.
    pub(crate) fn num_positions_before(&self, t: i64) -> usize {
        self.partition_point(t, |time| time < t, |_| {})
    }

    /// The number of leading positions (in index order) whose time `holds`, where `holds`
    /// is true up to around `t` and false after.
    pub(super) fn partition_point(
        &self,
        t: i64,
        holds: impl Fn(i64) -> bool,
        first_probe: impl FnOnce(usize),
    ) -> usize {
        let (min, max) = (self.time_range.min(), self.time_range.max());
        match &self.index_order {
            Some(order) => guided_partition_point(
                order.len(),
                (min, max),
                t,
                |p| self.times[order[p] as usize],
                holds,
                |p| first_probe(order[p] as usize),
            ),
            None => guided_partition_point(
                self.times.len(),
                (min, max),
                t,
                |p| self.times[p],
                holds,
                first_probe,
            ),
        }
    }
}

/// Below this many positions a plain binary search is as good as a guided one.
pub(super) const GUIDED_SEARCH_MIN_POSITIONS: usize = 32;

/// `offset * last / span` (`0 ≤ offset ≤ span`, `span > 0`), rounded down: in 64-bit
/// arithmetic where the product fits (every span under 2^32 times, and most others), which
/// is one division instruction where 128-bit arithmetic calls a routine of several dozen
/// (`__divti3`), on the path of every guided search's first probe.
pub(super) fn interpolate(offset: i128, last: usize, span: i128) -> usize {
    let exact = u64::try_from(offset)
        .ok()
        .zip(u64::try_from(last).ok())
        .and_then(|(offset, last)| offset.checked_mul(last))
        .zip(u64::try_from(span).ok())
        .map(|(product, span)| product / span);
    if let Some(guess) = exact {
        return usize::try_from(guess).unwrap_or(last);
    }
    let last_wide = i128::try_from(last).unwrap_or(i128::MAX);
    usize::try_from(offset * last_wide / span).unwrap_or(last)
}

/// The partition point of `holds` over `time_at(0..n)`, times ascending with the position
/// between `min` and `max`. The first probe goes where `t` would be if the times were
/// evenly spread, then the search gallops outward from there: a series logged at a steady
/// rate is answered from one or two cache lines instead of `log2(n)` scattered ones, and
/// any other spread costs at most twice the binary search.
pub(super) fn guided_partition_point(
    n: usize,
    (min, max): (TimeInt, TimeInt),
    t: i64,
    time_at: impl Fn(usize) -> i64,
    holds: impl Fn(i64) -> bool,
    first_probe: impl FnOnce(usize),
) -> usize {
    let binary = |mut low: usize, mut high: usize| {
        while low < high {
            let middle = low + (high - low) / 2;
            if holds(time_at(middle)) {
                low = middle + 1;
            } else {
                high = middle;
            }
        }
        low
    };
    let span = i128::from(max.as_i64()) - i128::from(min.as_i64());
    if n < GUIDED_SEARCH_MIN_POSITIONS || span <= 0 {
        return binary(0, n);
    }
    let offset = (i128::from(t) - i128::from(min.as_i64())).clamp(0, span);
    let guess = interpolate(offset, n - 1, span).min(n - 1);
    first_probe(guess);
    let mut step = 1;
    if holds(time_at(guess)) {
        // The answer is past `guess`: gallop up to the first position that fails.
        let mut low = guess + 1;
        loop {
            let probe = guess + step;
            if probe >= n {
                return binary(low, n);
            }
            if !holds(time_at(probe)) {
                return binary(low, probe);
            }
            low = probe + 1;
            step *= 2;
        }
    }
    // The answer is at or before `guess`: gallop down to the last position that holds.
    let mut high = guess;
    loop {
        let Some(probe) = guess.checked_sub(step) else {
            return binary(0, high);
        };
        if holds(time_at(probe)) {
            return binary(probe + 1, high);
        }
        high = probe;
        step *= 2;
    }
}
