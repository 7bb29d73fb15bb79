//! Time values and timelines: what a time column means and how it is typed in Arrow.

use std::fmt;
use std::sync::Arc;

use arrow_schema::{DataType, TimeUnit};

/// A time value on some timeline. `i64::MIN` is reserved and never a valid time.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct TimeInt(i64);

impl TimeInt {
    /// The smallest valid time.
    pub const MIN: Self = Self(i64::MIN + 1);
    /// The greatest valid time.
    pub const MAX: Self = Self(i64::MAX);

    /// A time, or `None` for the reserved `i64::MIN`.
    pub const fn new(value: i64) -> Option<Self> {
        if value == i64::MIN {
            None
        } else {
            Some(Self(value))
        }
    }

    /// A time, clamping the reserved `i64::MIN` to [`TimeInt::MIN`]: for query bounds,
    /// where "from the very beginning" is what a caller passing `i64::MIN` means.
    pub const fn saturating(value: i64) -> Self {
        if value == i64::MIN {
            Self::MIN
        } else {
            Self(value)
        }
    }

    /// The raw value.
    pub const fn as_i64(self) -> i64 {
        self.0
    }
}

impl fmt::Debug for TimeInt {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

impl fmt::Display for TimeInt {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// An inclusive range of times, `[min, max]`: how every API names a span of a timeline
/// (range queries, garbage collection's protected ranges, range drops), always beside the
/// timeline's name. Empty when `min > max`.
///
/// ```
/// use chunkstore::{TimeInt, TimeRange};
/// let t = |v| TimeInt::new(v).unwrap();
/// let range = TimeRange::new(t(10), t(20));
/// assert!(range.contains(t(10)) && range.contains(t(20)) && !range.contains(t(21)));
/// assert!(range.intersects(TimeRange::new(t(20), t(30))));
/// assert!(TimeRange::new(t(2), t(1)).is_empty());
/// assert_eq!(TimeRange::at(t(5)), TimeRange::new(t(5), t(5)));
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TimeRange {
    min: TimeInt,
    max: TimeInt,
}

impl TimeRange {
    /// Every time a timeline can hold.
    pub const EVERYTHING: Self = Self {
        min: TimeInt::MIN,
        max: TimeInt::MAX,
    };

    /// `[min, max]`, both ends included (empty if `min > max`).
    pub const fn new(min: TimeInt, max: TimeInt) -> Self {
        Self { min, max }
    }

    /// The one time `t`.
    pub const fn at(t: TimeInt) -> Self {
        Self { min: t, max: t }
    }

    /// The least time included.
    pub const fn min(self) -> TimeInt {
        self.min
    }

    /// The greatest time included.
    pub const fn max(self) -> TimeInt {
        self.max
    }

    /// Does the range include no time (`min > max`)?
    pub fn is_empty(self) -> bool {
        self.min > self.max
    }

    /// Is `t` in the range?
    pub fn contains(self, t: TimeInt) -> bool {
        self.min <= t && t <= self.max
    }

    /// The least range holding both (of non-empty ranges).
    #[must_use]
    pub fn union(self, other: Self) -> Self {
        Self {
            min: self.min.min(other.min),
            max: self.max.max(other.max),
        }
    }

    /// Do the ranges share a time?
    pub fn intersects(self, other: Self) -> bool {
        !self.is_empty() && !other.is_empty() && self.min <= other.max && other.min <= self.max
    }
}

impl fmt::Display for TimeRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "[{}, {}]", self.min, self.max)
    }
}

/// How the values of a timeline are typed, in Rust and in Arrow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum TimeType {
    /// A sequence number, Arrow `Int64`.
    Sequence,
    /// Nanoseconds since some start, Arrow `Duration(Nanosecond)`.
    DurationNs,
    /// Nanoseconds since the Unix epoch, Arrow `Timestamp(Nanosecond, _)` (any timezone).
    TimestampNs,
}

impl TimeType {
    /// The type of a time column of this Arrow type, if it is one.
    pub fn from_arrow(data_type: &DataType) -> Option<Self> {
        match data_type {
            DataType::Int64 => Some(Self::Sequence),
            DataType::Duration(TimeUnit::Nanosecond) => Some(Self::DurationNs),
            DataType::Timestamp(TimeUnit::Nanosecond, _) => Some(Self::TimestampNs),
            _ => None,
        }
    }

    /// The Arrow type this crate writes for a time column of this type.
    pub fn to_arrow(self) -> DataType {
        match self {
            Self::Sequence => DataType::Int64,
            Self::DurationNs => DataType::Duration(TimeUnit::Nanosecond),
            Self::TimestampNs => DataType::Timestamp(TimeUnit::Nanosecond, None),
        }
    }

    /// A time column of this type holding `values`, none null: the buffer taken as it
    /// is, where [`Self::array`] builds its nulls cell by cell.
    pub fn dense_array(self, values: Vec<i64>) -> arrow_array::ArrayRef {
        use arrow_array::PrimitiveArray;
        use arrow_array::types::{DurationNanosecondType, Int64Type, TimestampNanosecondType};
        match self {
            Self::Sequence => Arc::new(PrimitiveArray::<Int64Type>::from(values)),
            Self::DurationNs => Arc::new(PrimitiveArray::<DurationNanosecondType>::from(values)),
            Self::TimestampNs => Arc::new(PrimitiveArray::<TimestampNanosecondType>::from(values)),
        }
    }

    /// A time column of this type ([`Self::to_arrow`]) holding `values`, nulls where a row
    /// has no time.
    pub fn array(self, values: Vec<Option<i64>>) -> arrow_array::ArrayRef {
        use arrow_array::PrimitiveArray;
        use arrow_array::types::{DurationNanosecondType, Int64Type, TimestampNanosecondType};
        match self {
            Self::Sequence => Arc::new(PrimitiveArray::<Int64Type>::from(values)),
            Self::DurationNs => Arc::new(PrimitiveArray::<DurationNanosecondType>::from(values)),
            Self::TimestampNs => Arc::new(PrimitiveArray::<TimestampNanosecondType>::from(values)),
        }
    }
}

/// How many of `times` lead `values` one for one. Compared a block at a time without a
/// branch per element (the compiler makes vector compares of it), then the first block
/// that differs element by element.
pub(crate) fn leading_equal(times: &[TimeInt], values: &[i64]) -> usize {
    const BLOCK: usize = 64;
    /// Compared one by one first: a column with a row every few of the batch's differs
    /// at its second time, and is told so in a few instructions.
    const FIRST: usize = 4;
    /// Counted one by one, up to the first difference.
    fn equal_prefix(times: &[TimeInt], values: &[i64]) -> usize {
        times
            .iter()
            .zip(values)
            .take_while(|&(time, &value)| time.as_i64() == value)
            .count()
    }
    let len = times.len().min(values.len());
    let (times, values) = (&times[..len], &values[..len]);
    let head = FIRST.min(len);
    let first = equal_prefix(&times[..head], &values[..head]);
    if first < head {
        return first;
    }
    let mut equal = 0;
    for (times, values) in times.chunks(BLOCK).zip(values.chunks(BLOCK)) {
        let all = times
            .iter()
            .zip(values)
            .fold(true, |all, (time, &value)| all & (time.as_i64() == value));
        if !all {
            return equal + equal_prefix(times, values);
        }
        equal += times.len();
    }
    equal
}

/// A named timeline, e.g. `frame` (a sequence) or `log_time` (timestamps).
///
/// Cheap to clone: the name is shared.
#[derive(Clone, Eq)]
pub struct Timeline {
    name: Arc<str>,
    time_type: TimeType,
}

// As for `ComponentName`: names compare their pointers first (`crate::interner::same_name`),
// the hash is the text's, and the order is by name, then type.
impl PartialEq for Timeline {
    fn eq(&self, other: &Self) -> bool {
        crate::interner::same_name(&self.name, &other.name) && self.time_type == other.time_type
    }
}

impl std::hash::Hash for Timeline {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.name.hash(state);
        self.time_type.hash(state);
    }
}

impl PartialOrd for Timeline {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Timeline {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        crate::interner::cmp_names(&self.name, &other.name)
            .then_with(|| self.time_type.cmp(&other.time_type))
    }
}

impl Timeline {
    /// A timeline of the given name and type. Equal names share one allocation,
    /// process-wide (up to a cap), so that chunks do not each carry a copy.
    pub fn new(name: impl Into<Arc<str>>, time_type: TimeType) -> Self {
        Self {
            name: crate::interner::share_name(name.into()),
            time_type,
        }
    }

    /// A sequence timeline (Arrow `Int64`).
    pub fn sequence(name: impl Into<Arc<str>>) -> Self {
        Self::new(name, TimeType::Sequence)
    }

    /// The timeline's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The shared name, for keys that outlive a borrow.
    pub(crate) fn name_arc(&self) -> &Arc<str> {
        &self.name
    }

    /// The timeline's type.
    pub fn time_type(&self) -> TimeType {
        self.time_type
    }
}

impl fmt::Debug for Timeline {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}({:?})", self.name, self.time_type)
    }
}

/// A timeline the store (or recording) has no data on: the error of every read that names
/// one (dataframes, SQL's `latest_at`, the recording reader, the CLI and Python), naming the
/// timelines there are, so that a misspelt name is never taken for an answer of static data
/// only.
///
/// ```
/// use chunkstore::{Timeline, UnknownTimeline};
/// let error = UnknownTimeline::new("frame", &[Timeline::sequence("frame_id")]);
/// assert_eq!(error.to_string(), "unknown timeline \"frame\" (the store has: frame_id)");
/// ```
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnknownTimeline {
    /// The name asked for.
    pub name: String,
    /// The timelines there are, sorted by name.
    pub known: Vec<String>,
}

impl UnknownTimeline {
    /// `name` is none of `timelines`.
    pub fn new(name: &str, timelines: &[Timeline]) -> Self {
        let mut known: Vec<String> = timelines.iter().map(|t| t.name().to_owned()).collect();
        known.sort();
        Self {
            name: name.to_owned(),
            known,
        }
    }
}

impl fmt::Display for UnknownTimeline {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "unknown timeline {:?} (the store has: ", self.name)?;
        if self.known.is_empty() {
            write!(f, "none)")
        } else {
            write!(f, "{})", self.known.join(", "))
        }
    }
}

impl std::error::Error for UnknownTimeline {}

#[cfg(test)]
mod tests {
    use super::*;

    /// The branchless blocks agree with a plain count, wherever the first difference is.
    #[test]
    fn leading_equal_counts_up_to_the_first_difference() {
        let times: Vec<TimeInt> = (0..300).map(|v| TimeInt::new(v).unwrap()).collect();
        let values: Vec<i64> = (0..300).collect();
        for len in [0, 1, 3, 4, 5, 63, 64, 65, 200, 300] {
            assert_eq!(leading_equal(&times[..len], &values), len);
            assert_eq!(leading_equal(&times, &values[..len]), len);
            for differ in 0..len {
                let mut other = values[..len].to_vec();
                other[differ] += 1;
                assert_eq!(leading_equal(&times, &other), differ, "{len} {differ}");
            }
        }
    }

    #[test]
    fn min_is_reserved() {
        assert_eq!(TimeInt::new(i64::MIN), None);
        assert_eq!(TimeInt::new(i64::MIN + 1), Some(TimeInt::MIN));
        assert_eq!(TimeInt::saturating(i64::MIN), TimeInt::MIN);
    }

    #[test]
    fn arrow_types_map_both_ways() {
        for t in [
            TimeType::Sequence,
            TimeType::DurationNs,
            TimeType::TimestampNs,
        ] {
            assert_eq!(TimeType::from_arrow(&t.to_arrow()), Some(t));
        }
        let with_tz = DataType::Timestamp(TimeUnit::Nanosecond, Some("+02:00".into()));
        assert_eq!(TimeType::from_arrow(&with_tz), Some(TimeType::TimestampNs));
        assert_eq!(TimeType::from_arrow(&DataType::Int32), None);
        assert_eq!(
            TimeType::from_arrow(&DataType::Duration(TimeUnit::Millisecond)),
            None
        );
    }

    /// Timelines compare, order and hash by name then type, whether or not their names
    /// share one allocation.
    #[test]
    fn timelines_compare_as_their_name_and_type() {
        let shared = Timeline::sequence("t");
        let own = Timeline {
            name: Arc::from("t"),
            time_type: TimeType::Sequence,
        };
        assert!(!Arc::ptr_eq(&shared.name, &own.name));
        assert_eq!(shared, own);
        assert_eq!(shared.cmp(&own), std::cmp::Ordering::Equal);
        let hash = |t: &Timeline| ahash::RandomState::with_seeds(1, 2, 3, 4).hash_one(t);
        assert_eq!(hash(&shared), hash(&own));
        assert_ne!(shared, Timeline::new("t", TimeType::TimestampNs));
        let mut timelines = [
            Timeline::sequence("b"),
            Timeline::new("t", TimeType::TimestampNs),
            own,
            Timeline::sequence("a"),
        ];
        timelines.sort();
        let keys: Vec<(&str, TimeType)> = timelines
            .iter()
            .map(|t| (t.name(), t.time_type()))
            .collect();
        let mut expected = keys.clone();
        expected.sort_unstable();
        assert_eq!(keys, expected);
        assert_eq!(keys[0], ("a", TimeType::Sequence));
    }
}
