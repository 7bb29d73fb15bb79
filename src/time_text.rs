//! Times written as a person writes them: an RFC 3339 date and time on a timestamp
//! timeline (`2026-11-21T12:55:49.5Z`), a number with a unit on a duration timeline
//! (`1.5s`, `250ms`), and an integer on any timeline (its own unit: nanoseconds for
//! timestamps and durations). One parser for every door: the CLI's times, SQL's
//! `latest_at`, Python's strings.
//!
//! No date library: a civil date becomes days since 1970-01-01 by the proleptic
//! Gregorian formula (the one every date library uses), and everything is integer
//! arithmetic, checked, so a time beyond the `i64` of nanoseconds is an error rather
//! than a wrapped value.

use std::fmt;

use crate::{TimeInt, TimeType};

/// A text that is no time of the timeline's type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TimeParseError {
    /// The text.
    pub text: String,
    /// The timeline's type.
    pub time_type: TimeType,
    /// What is wrong.
    pub reason: String,
}

impl fmt::Display for TimeParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let example = match self.time_type {
            TimeType::Sequence => "an integer",
            TimeType::DurationNs => "e.g. 1.5s, 250ms, 2min, or integer nanoseconds",
            TimeType::TimestampNs => {
                "e.g. 2026-11-21T12:55:49Z, 2026-11-21 12:55:49.25+01:00, or integer \
                 nanoseconds since 1970"
            }
        };
        let kind = match self.time_type {
            TimeType::Sequence => "sequence",
            TimeType::DurationNs => "duration",
            TimeType::TimestampNs => "timestamp",
        };
        write!(
            f,
            "{:?} is not a time of a {kind} timeline: {} ({example})",
            self.text, self.reason
        )
    }
}

impl std::error::Error for TimeParseError {}

impl TimeType {
    /// Parses a time written for a timeline of this type (see the module docs).
    ///
    /// ```
    /// use chunkstore::{TimeInt, TimeType};
    /// let t = |text: &str, kind: TimeType| kind.parse_time(text).unwrap().as_i64();
    /// assert_eq!(t("30", TimeType::Sequence), 30);
    /// assert_eq!(t("1.5s", TimeType::DurationNs), 1_500_000_000);
    /// assert_eq!(t("1970-01-01T00:00:01Z", TimeType::TimestampNs), 1_000_000_000);
    /// assert!(TimeType::Sequence.parse_time("1.5s").is_err());
    /// ```
    ///
    /// # Errors
    /// A text that is none of the forms the type takes, or a time beyond what an `i64` of
    /// nanoseconds holds (or `i64::MIN`, which is no time).
    pub fn parse_time(self, text: &str) -> Result<TimeInt, TimeParseError> {
        let error = |reason: &str| TimeParseError {
            text: text.to_owned(),
            time_type: self,
            reason: reason.to_owned(),
        };
        let trimmed = text.trim();
        let value = if let Ok(integer) = trimmed.parse::<i64>() {
            integer
        } else {
            match self {
                TimeType::Sequence => return Err(error("a sequence takes integers only")),
                TimeType::DurationNs => parse_duration(trimmed).map_err(error)?,
                TimeType::TimestampNs => parse_timestamp(trimmed).map_err(error)?,
            }
        };
        TimeInt::new(value).ok_or_else(|| error("i64::MIN is no time"))
    }
}

/// Nanoseconds per unit, by the unit's names.
const UNITS: [(&str, i128); 9] = [
    ("ns", 1),
    ("us", 1_000),
    ("µs", 1_000),
    ("ms", 1_000_000),
    ("s", 1_000_000_000),
    ("min", 60_000_000_000),
    ("m", 60_000_000_000),
    ("h", 3_600_000_000_000),
    ("d", 86_400_000_000_000),
];

/// `[-]<digits>[.<digits>]<unit>` in nanoseconds, exactly (a fraction of a nanosecond is
/// an error, not a rounding).
fn parse_duration(text: &str) -> Result<i64, &'static str> {
    let split = text
        .find(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+'))
        .ok_or("a duration needs a unit (ns, us, ms, s, min, h, d)")?;
    let (number, unit) = text.split_at(split);
    let per_unit = UNITS
        .iter()
        .find(|(name, _)| *name == unit.trim())
        .map(|&(_, ns)| ns)
        .ok_or("unknown unit: ns, us, ms, s, min, h or d")?;
    let nanos = decimal_times(number, per_unit)?;
    i64::try_from(nanos).map_err(|_| "beyond the i64 of nanoseconds")
}

/// `number` (a decimal, signed) times `per_unit`, exactly.
fn decimal_times(number: &str, per_unit: i128) -> Result<i128, &'static str> {
    let (negative, digits) = match number.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, number.strip_prefix('+').unwrap_or(number)),
    };
    let (whole, fraction) = digits.split_once('.').unwrap_or((digits, ""));
    if whole.is_empty() && fraction.is_empty() {
        return Err("no number");
    }
    if !whole
        .bytes()
        .chain(fraction.bytes())
        .all(|b| b.is_ascii_digit())
        || fraction.len() > 18
    {
        return Err("not a decimal number");
    }
    let parse = |s: &str| -> Result<i128, &'static str> {
        if s.is_empty() {
            Ok(0)
        } else {
            s.parse::<i128>().map_err(|_| "too large")
        }
    };
    let scale = 10i128.pow(u32::try_from(fraction.len()).map_err(|_| "too long")?);
    let whole_part = parse(whole)?
        .checked_mul(per_unit)
        .ok_or("beyond the i64 of nanoseconds")?;
    let fraction_scaled = parse(fraction)?
        .checked_mul(per_unit)
        .ok_or("beyond the i64 of nanoseconds")?;
    if fraction_scaled % scale != 0 {
        return Err("finer than a nanosecond");
    }
    let magnitude = whole_part
        .checked_add(fraction_scaled / scale)
        .ok_or("beyond the i64 of nanoseconds")?;
    Ok(if negative { -magnitude } else { magnitude })
}

/// Days from 1970-01-01 to a proleptic Gregorian date.
fn days_from_civil(year: i64, month: i64, day: i64) -> i64 {
    let year = if month <= 2 { year - 1 } else { year };
    let era = if year >= 0 { year } else { year - 399 } / 400;
    let year_of_era = year - era * 400;
    let month_from_march = (month + 9) % 12;
    let day_of_year = (153 * month_from_march + 2) / 5 + day - 1;
    let day_of_era = year_of_era * 365 + year_of_era / 4 - year_of_era / 100 + day_of_year;
    era * 146_097 + day_of_era - 719_468
}

fn days_in_month(year: i64, month: i64) -> i64 {
    match month {
        2 if (year % 4 == 0 && year % 100 != 0) || year % 400 == 0 => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    }
}

/// A fixed-width decimal field of `text` at `range`, within `bounds`.
fn field(
    text: &str,
    range: std::ops::Range<usize>,
    bounds: std::ops::RangeInclusive<i64>,
    what: &'static str,
) -> Result<i64, &'static str> {
    let digits = text.get(range).ok_or(what)?;
    if !digits.bytes().all(|b| b.is_ascii_digit()) {
        return Err(what);
    }
    let value: i64 = digits.parse().map_err(|_| what)?;
    if bounds.contains(&value) {
        Ok(value)
    } else {
        Err(what)
    }
}

/// `YYYY-MM-DD[(T| )HH:MM[:SS[.fraction]]][Z|±HH:MM]` in nanoseconds since the Unix epoch;
/// without an offset, UTC.
fn parse_timestamp(text: &str) -> Result<i64, &'static str> {
    let year = field(text, 0..4, 0..=9999, "expected a date YYYY-MM-DD")?;
    if text.get(4..5) != Some("-") || text.get(7..8) != Some("-") {
        return Err("expected a date YYYY-MM-DD");
    }
    let month = field(text, 5..7, 1..=12, "no such month")?;
    let day = field(text, 8..10, 1..=31, "no such day")?;
    if day > days_in_month(year, month) {
        return Err("no such day in that month");
    }
    let mut rest = &text[10..];
    let mut seconds_of_day: i64 = 0;
    let mut nanos: i128 = 0;
    if let Some(time) = rest.strip_prefix(['T', 't', ' ']) {
        let hour = field(time, 0..2, 0..=23, "expected a time HH:MM[:SS]")?;
        if time.get(2..3) != Some(":") {
            return Err("expected a time HH:MM[:SS]");
        }
        let minute = field(time, 3..5, 0..=59, "no such minute")?;
        seconds_of_day = hour * 3600 + minute * 60;
        rest = &time[5..];
        if let Some(seconds) = rest.strip_prefix(':') {
            seconds_of_day += field(seconds, 0..2, 0..=59, "no such second")?;
            rest = &seconds[2..];
            if let Some(fraction) = rest.strip_prefix(['.', ',']) {
                let digits = fraction.bytes().take_while(u8::is_ascii_digit).count();
                if digits == 0 {
                    return Err("no digits after the decimal point");
                }
                nanos = decimal_times(&format!("0.{}", &fraction[..digits]), 1_000_000_000)?;
                rest = &fraction[digits..];
            }
        }
    }
    let offset_seconds = match rest {
        "" | "Z" | "z" => 0,
        offset => {
            let sign = match offset.as_bytes().first() {
                Some(b'+') => 1,
                Some(b'-') => -1,
                _ => return Err("expected Z or an offset ±HH:MM after the time"),
            };
            let hours = field(offset, 1..3, 0..=23, "expected an offset ±HH:MM")?;
            let minutes = match offset.len() {
                3 => 0,
                6 if offset.get(3..4) == Some(":") => {
                    field(offset, 4..6, 0..=59, "expected an offset ±HH:MM")?
                }
                5 => field(offset, 3..5, 0..=59, "expected an offset ±HH:MM")?,
                _ => return Err("expected an offset ±HH:MM"),
            };
            sign * (hours * 3600 + minutes * 60)
        }
    };
    let seconds = i128::from(days_from_civil(year, month, day)) * 86_400
        + i128::from(seconds_of_day)
        - i128::from(offset_seconds);
    let total = seconds * 1_000_000_000 + nanos;
    i64::try_from(total).map_err(|_| "beyond the i64 of nanoseconds (years 1677 to 2262)")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ns(text: &str, kind: TimeType) -> i64 {
        kind.parse_time(text)
            .unwrap_or_else(|e| panic!("{e}"))
            .as_i64()
    }

    #[test]
    fn timestamps_in_rfc_3339_and_friends() {
        let ts = TimeType::TimestampNs;
        assert_eq!(ns("1970-01-01T00:00:00Z", ts), 0);
        assert_eq!(ns("1970-01-01", ts), 0);
        assert_eq!(ns("1970-01-02 00:00", ts), 86_400_000_000_000);
        // The robot recording's first log_time, as Rerun shows it.
        assert_eq!(
            ns("2026-11-21T12:55:48.902914462Z", ts),
            1_795_265_748_902_914_462
        );
        assert_eq!(
            ns("2026-11-21T13:55:48.902914462+01:00", ts),
            1_795_265_748_902_914_462
        );
        assert_eq!(ns("2000-02-29T12:00:00.5Z", ts), 951_825_600_500_000_000);
        assert_eq!(ns("1969-12-31T23:59:59Z", ts), -1_000_000_000);
        assert_eq!(ns("12345", ts), 12_345);
        for bad in [
            "2026-02-29",
            "2026-13-01",
            "2026-11-21T24:00:00Z",
            "2026-11-21T12:00:00.Z",
            "2026-11-21T12:00:00+1",
            "2300-01-01",
            "yesterday",
            "2026-11-21T12:00:00.0000000001Z",
        ] {
            let error = ts.parse_time(bad).unwrap_err();
            assert!(error.to_string().contains("timestamp"), "{error}");
        }
    }

    #[test]
    fn durations_with_units() {
        let d = TimeType::DurationNs;
        assert_eq!(ns("1.5s", d), 1_500_000_000);
        assert_eq!(ns("250ms", d), 250_000_000);
        assert_eq!(ns("2min", d), 120_000_000_000);
        assert_eq!(ns("-3us", d), -3_000);
        assert_eq!(ns("1h", d), 3_600_000_000_000);
        assert_eq!(ns("7", d), 7);
        assert_eq!(ns(".5s", d), 500_000_000);
        for bad in ["1.5", "1.5x", "0.5ns", "s", "300000d", "1e3s"] {
            assert!(d.parse_time(bad).is_err(), "{bad}");
        }
        assert!(TimeType::Sequence.parse_time("1.5s").is_err());
        assert!(
            TimeType::Sequence
                .parse_time(&i64::MIN.to_string())
                .is_err()
        );
    }
}
