//! `--retention`: how much of each timeline the server keeps, behind the newest time it
//! holds there (as a time-series database's retention does), applied to every recording
//! once a second by [`chunkstore::hub::StoreHub::retain_recent`].
//!
//! - `--retention 1h`: every time-typed timeline (timestamps, durations) keeps its last
//!   hour; sequence timelines are not touched.
//! - `--retention frame=100000`: the timeline `frame` keeps its last 100,000 steps (a
//!   number without a unit is in the timeline's own units: steps, or nanoseconds).
//! - `--retention log_time=30m`: that timeline keeps its last 30 minutes.
//!
//! A rule naming a timeline wins over one that does not.

use chunkstore::{TimeType, Timeline};

/// One `--retention` rule.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Rule {
    /// The timeline it names, or `None` for every time-typed one.
    pub timeline: Option<String>,
    /// How far behind the newest time data is kept, in the timeline's units.
    pub span: u64,
}

/// Parses `SPAN` or `TIMELINE=SPAN` (see the module).
pub fn parse_rule(text: &str) -> Result<Rule, String> {
    let (timeline, span) = match text.rsplit_once('=') {
        Some((name, span)) if !name.is_empty() => (Some(name.to_owned()), span),
        Some(_) => return Err(format!("{text:?} names no timeline before `=`")),
        None => (None, text),
    };
    let span = span.trim();
    let digits = span.len() - span.trim_start_matches(|c: char| c.is_ascii_digit()).len();
    let (number, unit) = span.split_at(digits);
    let number: u64 = number.parse().map_err(|_| {
        format!("{span:?} is not a span: a number, with a unit (ns, us, ms, s, m, h, d) for time")
    })?;
    let nanos_per = match unit.trim() {
        "" if timeline.is_some() => 1,
        "" => {
            return Err(format!(
                "{span:?} has no unit: give one (1h, 30m, 7d) for every time timeline, or \
                 name the timeline (frame={span})"
            ));
        }
        "ns" => 1,
        "us" => 1_000,
        "ms" => 1_000_000,
        "s" => 1_000_000_000,
        "m" | "min" => 60 * 1_000_000_000,
        "h" => 3_600 * 1_000_000_000,
        "d" => 86_400 * 1_000_000_000,
        other => {
            return Err(format!(
                "{other:?} is not a unit of time (ns, us, ms, s, m, h, d)"
            ));
        }
    };
    let span = number
        .checked_mul(nanos_per)
        .ok_or_else(|| format!("{span:?} is too long a span"))?;
    Ok(Rule { timeline, span })
}

/// The span `rules` give `timeline`, if any.
pub fn span_of(rules: &[Rule], timeline: &Timeline) -> Option<u64> {
    let named = rules
        .iter()
        .find(|rule| rule.timeline.as_deref() == Some(timeline.name()));
    let timed = || {
        let is_time = matches!(
            timeline.time_type(),
            TimeType::DurationNs | TimeType::TimestampNs
        );
        rules.iter().find(|rule| rule.timeline.is_none() && is_time)
    };
    named.or_else(timed).map(|rule| rule.span)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rules_parse_with_units_and_names() {
        let hour = 3_600_000_000_000;
        assert_eq!(
            parse_rule("1h"),
            Ok(Rule {
                timeline: None,
                span: hour
            })
        );
        assert_eq!(
            parse_rule("frame=100"),
            Ok(Rule {
                timeline: Some("frame".into()),
                span: 100
            })
        );
        assert_eq!(
            parse_rule("log_time=30m").map(|r| r.span),
            Ok(30 * 60 * 1_000_000_000)
        );
        for bad in [
            "",
            "100",
            "=5",
            "h",
            "5 parsecs",
            "frame=",
            "99999999999999d",
        ] {
            assert!(parse_rule(bad).is_err(), "{bad:?} parsed");
        }
    }

    #[test]
    fn a_named_rule_wins_and_unnamed_ones_cover_time_timelines_only() {
        let rules = [
            parse_rule("1s").unwrap(),
            parse_rule("sim=7").unwrap(),
            parse_rule("frame=9").unwrap(),
        ];
        let of = |name: &str, time_type| span_of(&rules, &Timeline::new(name, time_type));
        assert_eq!(of("frame", TimeType::Sequence), Some(9));
        assert_eq!(of("sim", TimeType::DurationNs), Some(7));
        assert_eq!(of("log_time", TimeType::TimestampNs), Some(1_000_000_000));
        assert_eq!(of("step", TimeType::Sequence), None);
    }
}
