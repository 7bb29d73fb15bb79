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
}

/// A named timeline, e.g. `frame` (a sequence) or `log_time` (timestamps).
///
/// Cheap to clone: the name is shared.
#[derive(Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Timeline {
    name: Arc<str>,
    time_type: TimeType,
}

impl Timeline {
    /// A timeline of the given name and type. Equal names share one allocation,
    /// process-wide (up to a cap), so that chunks do not each carry a copy.
    pub fn new(name: impl Into<Arc<str>>, time_type: TimeType) -> Self {
        Self {
            name: crate::shared::share_name(name.into()),
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
