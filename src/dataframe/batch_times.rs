//! A batch's row times: the times of the columns a batch merges, merged into one
//! ascending list ([`merge_times`]), found from a position on ([`position_from`]), and
//! looked up as a set ([`TimeSet`]).

use crate::TimeInt;

/// Where `time` is, or would go, in the ascending `times`, searching from `from` on: a
/// few steps for a column with a row every few rows (most of them: entities on a few
/// clocks), then by galloping, a logarithmic search for a sparse one.
#[inline]
pub(super) fn position_from(times: &[TimeInt], from: usize, time: TimeInt) -> usize {
    const STEPS: usize = 8;
    let rest = times.get(from..).unwrap_or_default();
    let steps = rest.len().min(STEPS);
    let mut step = 0;
    while step < steps && rest[step] < time {
        step += 1;
    }
    if step < steps || rest.len() <= STEPS {
        return from + step;
    }
    // Everything before `low` is earlier than `time`.
    let (mut low, mut high) = (STEPS, 2 * STEPS);
    while high <= rest.len() && rest[high - 1] < time {
        low = high;
        high *= 2;
    }
    let high = high.min(rest.len());
    from + low + rest[low..high].partition_point(|&t| t < time)
}

/// A batch's row times as a set: a bitmap over their span where they are dense enough (at
/// most 64 bits per time), else a binary search. Checking that a column's times are all
/// known then costs a few instructions per time.
#[derive(Default)]
pub(super) struct TimeSet {
    first: i64,
    /// Bit `t - first` is set for each time `t`; empty when the times are too sparse.
    words: Vec<u64>,
}

impl TimeSet {
    pub(super) fn rebuild(&mut self, times: &[TimeInt]) {
        self.words.clear();
        let (Some(first), Some(last)) = (times.first(), times.last()) else {
            return;
        };
        let span = i128::from(last.as_i64()) - i128::from(first.as_i64()) + 1;
        let Ok(span) = usize::try_from(span) else {
            return;
        };
        if span / 64 > times.len() {
            return;
        }
        self.first = first.as_i64();
        self.words.resize(span.div_ceil(64), 0);
        for &time in times {
            let Some(bit) = self.bit(time) else {
                continue;
            };
            if let Some(word) = self.words.get_mut(bit / 64) {
                *word |= 1 << (bit % 64);
            }
        }
    }

    /// `time`'s bit: its distance from the first time, which wraps past the words for a
    /// time before it (`None` where it does not fit a `usize`).
    #[expect(
        clippy::cast_sign_loss,
        reason = "a time before the first wraps to a distance past the span"
    )]
    fn bit(&self, time: TimeInt) -> Option<usize> {
        usize::try_from(time.as_i64().wrapping_sub(self.first) as u64).ok()
    }

    pub(super) fn contains(&self, times: &[TimeInt], time: TimeInt) -> bool {
        if self.words.is_empty() {
            return times.binary_search(&time).is_ok();
        }
        self.bit(time).is_some_and(|bit| {
            self.words
                .get(bit / 64)
                .is_some_and(|word| word & (1 << (bit % 64)) != 0)
        })
    }
}

/// Merges the ascending distinct `new` into the ascending distinct `times`, keeping the
/// first `cap`; returns whether `times` changed. A column whose times the batch already
/// has (many entities on one clock) costs a search per time and no copy.
pub(super) fn merge_times(
    times: &mut Vec<TimeInt>,
    new: &[TimeInt],
    cap: usize,
    merged: &mut Vec<TimeInt>,
) -> bool {
    let Some(&first) = new.first() else {
        return false;
    };
    // Entities on one clock: the column's times are a run of the batch's, found by one
    // search and one comparison of slices rather than a search per time.
    let at = position_from(times, 0, first);
    if times.get(at..at.saturating_add(new.len())) == Some(new) {
        return false;
    }
    let mut from = at;
    let known = new.iter().all(|&time| {
        from = position_from(times, from, time);
        let found = times.get(from) == Some(&time);
        from += 1;
        found
    });
    if known {
        return false;
    }
    merged.clear();
    let (mut a, mut b) = (times.iter().peekable(), new.iter().peekable());
    while merged.len() < cap {
        let next = match (a.peek(), b.peek()) {
            (Some(&&x), Some(&&y)) => {
                if x <= y {
                    a.next();
                }
                if y <= x {
                    b.next();
                }
                x.min(y)
            }
            (Some(&&x), None) => {
                a.next();
                x
            }
            (None, Some(&&y)) => {
                b.next();
                y
            }
            (None, None) => break,
        };
        merged.push(next);
    }
    std::mem::swap(times, merged);
    true
}

#[cfg(test)]
mod tests {
    use super::{TimeSet, merge_times, position_from};
    use crate::TimeInt;

    fn times(values: &[i64]) -> Vec<TimeInt> {
        values.iter().map(|&t| TimeInt::saturating(t)).collect()
    }

    #[test]
    fn galloping_finds_what_a_binary_search_finds_from_any_start() {
        // Short steps, then galloping: a few times, and many with gaps of every size.
        let mut long: Vec<i64> = vec![1, 3, 4, 8, 9, 10, 20, 21, 40, 41, 42, 43, 90];
        long.extend((0..150).map(|i| 100 + i * i / 7));
        long.dedup();
        for sorted in [times(&long[..13]), times(&long)] {
            search_from_everywhere(&sorted);
        }
        assert_eq!(position_from(&[], 0, TimeInt::saturating(5)), 0);
    }

    fn search_from_everywhere(sorted: &[TimeInt]) {
        let end = sorted.last().map_or(0, |t| t.as_i64() + 2);
        for from in 0..=sorted.len() {
            for t in 0..end {
                let time = TimeInt::saturating(t);
                let expected = from + sorted[from..].partition_point(|&x| x < time);
                assert_eq!(
                    position_from(sorted, from, time),
                    expected,
                    "from {from}, t {t}"
                );
            }
        }
    }

    #[test]
    fn a_time_set_holds_exactly_its_times_dense_or_sparse() {
        let extremes = [i64::MIN + 1, -5, 0, 3, i64::MAX - 1, i64::MAX];
        let dense: Vec<i64> = (10..400).filter(|t| t % 3 != 1).collect();
        let sparse = [-1_000_000, 0, 7, 1_000_000];
        let mut set = TimeSet::default();
        for list in [
            &dense[..],
            &sparse[..],
            &[42][..],
            &[i64::MIN + 1, i64::MAX][..],
            &[],
        ] {
            let batch = times(list);
            set.rebuild(&batch);
            let probes = list
                .iter()
                .flat_map(|&t| [t.saturating_sub(1), t, t.saturating_add(1)])
                .chain(extremes);
            for t in probes {
                let time = TimeInt::saturating(t);
                assert_eq!(
                    set.contains(&batch, time),
                    list.contains(&time.as_i64()),
                    "{t} in a set of {} times",
                    list.len()
                );
            }
        }
    }

    #[test]
    fn merged_times_are_the_first_distinct_ones_of_the_union() {
        // Runs of the times merged so far (found by one comparison), runs reaching past
        // them, and scattered times.
        let lists: [&[i64]; 10] = [
            &[5, 9, 12],
            &[1, 5, 7],
            &[],
            &[2, 3, 4, 5, 6, 7, 8],
            &[3, 4, 5],
            &[7, 8, 9, 10],
            &[1, 2],
            &[40],
            &[0],
            &[0, 1, 2, 3],
        ];
        for cap in 1..12 {
            let (mut merged, mut scratch) = (Vec::new(), Vec::new());
            let mut all = Vec::new();
            for list in lists {
                let before = merged.clone();
                let changed = merge_times(&mut merged, &times(list), cap, &mut scratch);
                all.extend_from_slice(list);
                let mut expected = all.clone();
                expected.sort_unstable();
                expected.dedup();
                expected.truncate(cap);
                assert_eq!(merged, times(&expected), "cap {cap}");
                // A change is always reported (an unchanged merge may be too).
                assert!(
                    changed || merged == before,
                    "cap {cap}: a change is reported"
                );
            }
        }
    }
}
