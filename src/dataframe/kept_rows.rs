//! A dataframe view's rows, kept between queries of one snapshot.
//!
//! Every planned column's times decide which rows a view has (SEMANTICS.md section 9), so
//! working them out reads the times of every selected entity, even for a query that builds
//! one column: on a store of 100 entities that is a hundred times the data the answer
//! shows. A snapshot never changes, so a stream that read its view's rows to the end
//! leaves them here, and the next query of the same view over the same range or a part of
//! it takes them from here and reads only the columns it builds.
//!
//! The rows depend on the view's index, contents and kept kinds of column ([`RowsKey`]),
//! and on the range; not on which columns a query builds, nor on filling. A range's rows
//! are the kept rows of any range containing it, cut to it: a row is a time at which some
//! planned column has an event, whatever range asked.

use std::sync::Arc;

use parking_lot::Mutex;

use super::{DataframeQuery, EntityPathFilter, KeptColumns};
use crate::sanity::{SanityError, Structure};
use crate::{TimeInt, TimeRange};

/// At most this many kept row sets per snapshot (each lookup compares keys with all).
const MAX_ENTRIES: usize = 64;

/// A snapshot keeps at least this many bytes of row times, whatever its size.
const MIN_BUDGET_BYTES: u64 = 16 << 20;

/// What decides a view's rows, besides its range.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct RowsKey {
    index: Arc<str>,
    contents: EntityPathFilter,
    kept: KeptColumns,
}

impl RowsKey {
    pub(super) fn of(query: &DataframeQuery) -> Self {
        Self {
            index: Arc::clone(&query.index),
            contents: query.contents.clone(),
            kept: query.kept,
        }
    }
}

/// A view's rows found by earlier queries of one snapshot (see the module docs). Bounded:
/// at most [`MAX_ENTRIES`] sets, and, in all, the greater of 16 MiB of times and a
/// sixteenth of the store's heap bytes; a set that would pass the bound is not kept.
#[derive(Default, Debug)]
pub(crate) struct KeptRows {
    entries: Mutex<Vec<Entry>>,
}

#[derive(Debug)]
struct Entry {
    key: RowsKey,
    /// The rows of exactly this range are `times`.
    range: TimeRange,
    /// Ascending, distinct, within `range`.
    times: Arc<[TimeInt]>,
}

/// A query's rows taken from kept ones: `times[next..end]`, handed out a batch at a time.
#[derive(Debug)]
pub(super) struct GivenRows {
    times: Arc<[TimeInt]>,
    next: usize,
    end: usize,
}

impl GivenRows {
    /// Appends the next `cap` rows (fewer at the end) to `out`.
    pub(super) fn take(&mut self, cap: usize, out: &mut Vec<TimeInt>) {
        let end = self.end.min(self.next.saturating_add(cap));
        out.extend_from_slice(self.times.get(self.next..end).unwrap_or_default());
        self.next = end;
    }
}

/// How many row times a snapshot of a store of `heap_bytes` keeps in all.
pub(super) fn budget_times(heap_bytes: u64) -> usize {
    let bytes = MIN_BUDGET_BYTES.max(heap_bytes / 16);
    usize::try_from(bytes / 8).unwrap_or(usize::MAX)
}

impl KeptRows {
    /// The rows of the view `key` over `range`, if a kept set covers the range.
    pub(super) fn rows(&self, key: &RowsKey, range: TimeRange) -> Option<GivenRows> {
        if range.is_empty() {
            return None;
        }
        let entries = self.entries.lock();
        let entry = entries.iter().find(|entry| {
            entry.range.min() <= range.min()
                && range.max() <= entry.range.max()
                && entry.key == *key
        })?;
        let times = &entry.times;
        Some(GivenRows {
            next: times.partition_point(|&t| t < range.min()),
            end: times.partition_point(|&t| t <= range.max()),
            times: Arc::clone(times),
        })
    }

    /// Keeps `times`, the rows of the view `key` over `range` (ascending, distinct, in
    /// the range), joined with kept sets of the same view over ranges it overlaps or
    /// touches, unless the result would pass the bound of `budget` times in all (then the
    /// kept sets stay as they were).
    pub(super) fn keep(&self, key: RowsKey, range: TimeRange, times: Vec<TimeInt>, budget: usize) {
        if range.is_empty() {
            return;
        }
        self.join(key, range, times, budget);
        debug_assert!(self.sanity_check().is_ok(), "{:?}", self.sanity_check());
    }

    fn join(&self, key: RowsKey, range: TimeRange, times: Vec<TimeInt>, budget: usize) {
        let mut entries = self.entries.lock();
        let mut range = range;
        let mut times = times;
        let mut joined = Vec::new();
        // Joining one set can make the range touch another: repeat until none is left.
        while let Some(position) = entries.iter().enumerate().position(|(i, entry)| {
            !joined.contains(&i) && entry.key == key && touch(entry.range, range)
        }) {
            let entry = &entries[position];
            range = range.union(entry.range);
            times = merge_distinct(&times, &entry.times);
            joined.push(position);
        }
        let others: usize = entries
            .iter()
            .enumerate()
            .filter(|(i, _)| !joined.contains(i))
            .map(|(_, entry)| entry.times.len())
            .sum();
        let remaining = entries.len() - joined.len();
        if others.saturating_add(times.len()) > budget || remaining >= MAX_ENTRIES {
            return;
        }
        let mut position = 0;
        entries.retain(|_| {
            position += 1;
            !joined.contains(&(position - 1))
        });
        entries.push(Entry {
            key,
            range,
            times: times.into(),
        });
    }

    /// How many row times are kept, in all.
    #[cfg(test)]
    pub(super) fn num_times(&self) -> usize {
        self.entries.lock().iter().map(|e| e.times.len()).sum()
    }

    /// Checks the invariants: each set ascending, distinct and within its range; no two
    /// sets of one view whose ranges overlap or touch (they are joined); at most
    /// [`MAX_ENTRIES`] sets.
    ///
    /// # Errors
    /// The first invariant broken.
    pub(crate) fn sanity_check(&self) -> Result<(), SanityError> {
        let entries = self.entries.lock();
        let fail = |invariant: &'static str, detail: String| {
            Err(SanityError::new(Structure::KeptRows, invariant).at(detail))
        };
        if entries.len() > MAX_ENTRIES {
            return fail("at most MAX_ENTRIES row sets", format!("{}", entries.len()));
        }
        for (i, entry) in entries.iter().enumerate() {
            if entry.range.is_empty() {
                return fail("a kept range is not empty", format!("{:?}", entry.range));
            }
            if !entry.times.windows(2).all(|w| w[0] < w[1]) {
                return fail("kept rows ascend, distinct", format!("set {i}"));
            }
            if !entry.times.iter().all(|&t| entry.range.contains(t)) {
                return fail("kept rows lie in their range", format!("set {i}"));
            }
            if let Some(j) = entries[..i]
                .iter()
                .position(|other| other.key == entry.key && touch(other.range, entry.range))
            {
                return fail(
                    "sets of one view over touching ranges are joined",
                    format!("sets {j} and {i}"),
                );
            }
        }
        Ok(())
    }
}

/// Do `a` and `b` overlap or meet end to end (so that their union is one range whose rows
/// are theirs together)?
fn touch(a: TimeRange, b: TimeRange) -> bool {
    let meets = |low: TimeRange, high: TimeRange| {
        low.max().as_i64().checked_add(1) == Some(high.min().as_i64())
    };
    a.intersects(b) || meets(a, b) || meets(b, a)
}

/// The distinct times of two ascending, distinct lists, ascending.
fn merge_distinct(a: &[TimeInt], b: &[TimeInt]) -> Vec<TimeInt> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while let (Some(&x), Some(&y)) = (a.get(i), b.get(j)) {
        out.push(x.min(y));
        i += usize::from(x <= y);
        j += usize::from(y <= x);
    }
    out.extend_from_slice(a.get(i..).unwrap_or_default());
    out.extend_from_slice(b.get(j..).unwrap_or_default());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(v: i64) -> TimeInt {
        TimeInt::new(v).unwrap()
    }

    fn range(min: i64, max: i64) -> TimeRange {
        TimeRange::new(t(min), t(max))
    }

    fn key(index: &str) -> RowsKey {
        RowsKey::of(&DataframeQuery::new(index))
    }

    fn given(kept: &KeptRows, key: &RowsKey, range: TimeRange) -> Option<Vec<i64>> {
        let mut rows = kept.rows(key, range)?;
        let mut out = Vec::new();
        rows.take(2, &mut out);
        rows.take(usize::MAX, &mut out);
        Some(out.iter().map(|t| t.as_i64()).collect())
    }

    fn times(values: &[i64]) -> Vec<TimeInt> {
        values.iter().map(|&v| t(v)).collect()
    }

    #[test]
    fn a_range_inside_a_kept_one_is_cut_from_it() {
        let kept = KeptRows::default();
        let frame = key("frame");
        kept.keep(frame.clone(), range(0, 100), times(&[1, 5, 9, 50]), 100);
        assert_eq!(given(&kept, &frame, range(0, 100)), Some(vec![1, 5, 9, 50]));
        assert_eq!(given(&kept, &frame, range(5, 9)), Some(vec![5, 9]));
        assert_eq!(given(&kept, &frame, range(10, 49)), Some(vec![]));
        // Not covered, another view, an empty range: not given.
        assert_eq!(given(&kept, &frame, range(0, 101)), None);
        assert_eq!(given(&kept, &key("log_time"), range(5, 9)), None);
        assert_eq!(given(&kept, &frame, range(9, 5)), None);
        kept.sanity_check().unwrap();
    }

    #[test]
    fn parts_that_touch_or_overlap_join_and_their_union_is_given() {
        let kept = KeptRows::default();
        let frame = key("frame");
        kept.keep(frame.clone(), range(21, 30), times(&[21, 30]), 100);
        kept.keep(frame.clone(), range(0, 10), times(&[0, 10]), 100);
        kept.keep(key("other"), range(11, 20), times(&[11]), 100);
        kept.sanity_check().unwrap();
        assert_eq!(given(&kept, &frame, range(0, 30)), None);
        // The middle part touches both: one set, its union.
        kept.keep(frame.clone(), range(11, 20), times(&[12, 20]), 100);
        kept.sanity_check().unwrap();
        assert_eq!(
            given(&kept, &frame, range(0, 30)),
            Some(vec![0, 10, 12, 20, 21, 30])
        );
        // An overlapping part joins with its rows counted once.
        kept.keep(frame.clone(), range(25, 40), times(&[30, 35]), 100);
        kept.sanity_check().unwrap();
        assert_eq!(
            given(&kept, &frame, range(5, 40)),
            Some(vec![10, 12, 20, 21, 30, 35])
        );
        assert_eq!(kept.num_times(), 7 + 1);
        // The ends of the timeline touch nothing past them.
        kept.keep(
            frame.clone(),
            TimeRange::new(t(50), TimeInt::MAX),
            times(&[60]),
            100,
        );
        kept.keep(
            frame.clone(),
            TimeRange::new(TimeInt::MIN, t(-10)),
            vec![],
            100,
        );
        kept.sanity_check().unwrap();
        assert_eq!(given(&kept, &frame, range(55, 70)), Some(vec![60]));
    }

    #[test]
    fn nothing_past_the_budget_is_kept_and_what_was_kept_stays() {
        let kept = KeptRows::default();
        let frame = key("frame");
        kept.keep(frame.clone(), range(0, 9), times(&[0, 1, 2]), 4);
        // Joined, the set would hold five: the join is refused, both parts stay as they were.
        kept.keep(frame.clone(), range(10, 19), times(&[10, 11]), 4);
        assert_eq!(given(&kept, &frame, range(0, 9)), Some(vec![0, 1, 2]));
        assert_eq!(given(&kept, &frame, range(10, 19)), None);
        assert_eq!(kept.num_times(), 3);
        // At most MAX_ENTRIES sets, budget or not.
        for i in 0..2 * MAX_ENTRIES {
            let i = i64::try_from(i).unwrap();
            kept.keep(
                frame.clone(),
                range(100 * i + 100, 100 * i + 150),
                vec![],
                1 << 20,
            );
        }
        kept.sanity_check().unwrap();
        assert_eq!(kept.entries.lock().len(), MAX_ENTRIES);
        assert!(budget_times(0) >= 1 << 21);
        assert_eq!(budget_times(1 << 40), (1 << 36) / 8);
    }

    #[test]
    fn merging_keeps_each_time_once_in_order() {
        assert_eq!(
            merge_distinct(&times(&[1, 3, 5, 7]), &times(&[2, 3, 8])),
            times(&[1, 2, 3, 5, 7, 8])
        );
        assert_eq!(merge_distinct(&[], &times(&[4])), times(&[4]));
    }
}
