//! Which SQL filters the store's index answers, and what they ask of it.
//!
//! DataFusion hands a scan the filters of its `WHERE` clause split at `AND`. A filter on a
//! timeline table's index column (`=`, `<`, `<=`, `>`, `>=`, `BETWEEN`) becomes a time
//! range the dataframe view applies exactly; `IN` becomes the range covering its values,
//! which DataFusion filters again. On the `chunks` table, a filter on `entity_path`
//! (`=`, `IN`, `LIKE`, `starts_with`) is matched against every entity path the store
//! holds, so the scan reads the chunks of the matching entities alone and answers it
//! exactly; a filter on a timeline column keeps the chunks whose times on it overlap the
//! range, and DataFusion filters their rows again.

use std::collections::BTreeSet;

use datafusion::common::ScalarValue;
use datafusion::logical_expr::expr::{Between, BinaryExpr, InList, Like, ScalarFunction};
use datafusion::logical_expr::{Expr, Operator, TableProviderFilterPushDown};

use crate::{TimeInt, TimeRange, TimeType, Timeline};

/// What a filter on a time column asks: rows at times in `range`. `exact` when the range
/// is all the filter says (so the scan alone answers it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct TimeFilter {
    pub range: TimeRange,
    pub exact: bool,
}

/// The time range a filter on column `column` (of type `time_type`) asks for, or `None`
/// if the filter is not one the index answers.
pub(crate) fn time_filter(expr: &Expr, column: &str, time_type: TimeType) -> Option<TimeFilter> {
    let time = |e: &Expr| literal_time(e, time_type);
    let is_column = |e: &Expr| is_column(e, column);
    match expr {
        // DataFusion writes a short `IN` list as `=`s joined by `OR`: the covering range.
        Expr::BinaryExpr(BinaryExpr {
            left,
            op: Operator::Or,
            right,
        }) => {
            let (a, b) = (
                time_filter(left, column, time_type)?,
                time_filter(right, column, time_type)?,
            );
            let range = match (a.range.is_empty(), b.range.is_empty()) {
                (true, _) => b.range,
                (_, true) => a.range,
                _ => TimeRange::new(
                    a.range.min().min(b.range.min()),
                    a.range.max().max(b.range.max()),
                ),
            };
            Some(TimeFilter {
                range,
                exact: false,
            })
        }
        Expr::BinaryExpr(BinaryExpr { left, op, right }) => {
            let (op, value) = if is_column(left) {
                (*op, time(right)?)
            } else if is_column(right) {
                (op.swap()?, time(left)?)
            } else {
                return None;
            };
            let range = match op {
                Operator::Eq => value.into_time().map(TimeRange::at),
                Operator::Lt => value
                    .minus_one()
                    .map(|max| TimeRange::new(TimeInt::MIN, max)),
                Operator::LtEq => value.at_most().map(|max| TimeRange::new(TimeInt::MIN, max)),
                Operator::Gt => value
                    .plus_one()
                    .map(|min| TimeRange::new(min, TimeInt::MAX)),
                Operator::GtEq => Some(TimeRange::new(value.at_least(), TimeInt::MAX)),
                _ => return None,
            };
            Some(TimeFilter {
                range: range.unwrap_or(EMPTY),
                exact: true,
            })
        }
        Expr::Between(Between {
            expr,
            negated: false,
            low,
            high,
        }) if is_column(expr) => {
            let (low, high) = (time(low)?.at_least(), time(high)?.at_most());
            Some(TimeFilter {
                range: high.map_or(EMPTY, |high| TimeRange::new(low, high)),
                exact: true,
            })
        }
        Expr::InList(InList {
            expr,
            list,
            negated: false,
        }) if is_column(expr) => {
            let mut times = Vec::with_capacity(list.len());
            for item in list {
                if let Some(t) = time(item)?.into_time() {
                    times.push(t);
                }
            }
            let range = match (times.iter().min(), times.iter().max()) {
                (Some(&min), Some(&max)) => TimeRange::new(min, max),
                _ => EMPTY,
            };
            Some(TimeFilter {
                range,
                exact: times.len() <= 1 && list.len() == 1,
            })
        }
        _ => None,
    }
}

/// The first of `timelines` a filter on its column asks a time range of, with that range.
pub(crate) fn timeline_filter<'a>(
    filter: &Expr,
    timelines: &'a [Timeline],
) -> Option<(&'a Timeline, TimeFilter)> {
    timelines.iter().find_map(|timeline| {
        time_filter(filter, timeline.name(), timeline.time_type()).map(|f| (timeline, f))
    })
}

/// The range of one timeline that `filters` ask (the first timeline filtered on, every
/// filter on it intersected), so that a chunk table scan reads only the chunks
/// overlapping it: DataFusion filters their rows again.
pub(crate) fn chunks_overlapping<'a>(
    filters: &[Expr],
    timelines: &'a [Timeline],
) -> Option<(&'a Timeline, TimeRange)> {
    let mut overlapping: Option<(&Timeline, TimeRange)> = None;
    for (timeline, filter) in filters.iter().filter_map(|f| timeline_filter(f, timelines)) {
        match &mut overlapping {
            Some((first, range)) if *first == timeline => {
                *range = intersect(*range, filter.range);
            }
            Some(_) => {}
            None => overlapping = Some((timeline, filter.range)),
        }
    }
    overlapping
}

/// `range` on `column` as `EXPLAIN` shows it: `frame in [3, 9]`, `frame <= 9`,
/// `frame >= 3`, `frame empty`.
pub(crate) fn describe(column: &str, range: TimeRange) -> String {
    match (range.min() == TimeInt::MIN, range.max() == TimeInt::MAX) {
        _ if range.is_empty() => format!("{column} empty"),
        (true, true) => format!("{column} any"),
        (true, false) => format!("{column} <= {}", range.max()),
        (false, true) => format!("{column} >= {}", range.min()),
        (false, false) => format!("{column} in {range}"),
    }
}

/// A range holding no time.
pub(crate) const EMPTY: TimeRange = TimeRange::new(TimeInt::MAX, TimeInt::MIN);

/// The intersection of two ranges (empty if they share no time).
pub(crate) fn intersect(a: TimeRange, b: TimeRange) -> TimeRange {
    let range = TimeRange::new(a.min().max(b.min()), a.max().min(b.max()));
    if range.is_empty() { EMPTY } else { range }
}

/// A literal compared with a time column, as an `i64` of the column's unit. Kept as the
/// raw value so that the edges (`> i64::MAX`, the reserved `i64::MIN`) map to the right
/// bounds: `None` below where no time satisfies the comparison.
#[derive(Clone, Copy, Debug)]
struct Literal(i64);

impl Literal {
    fn into_time(self) -> Option<TimeInt> {
        TimeInt::new(self.0)
    }

    /// The least time `>= self`.
    fn at_least(self) -> TimeInt {
        TimeInt::saturating(self.0)
    }

    /// The greatest time `<= self` (none for the reserved `i64::MIN`).
    fn at_most(self) -> Option<TimeInt> {
        TimeInt::new(self.0)
    }

    /// The least time `> self` (none above `i64::MAX`).
    fn plus_one(self) -> Option<TimeInt> {
        self.0.checked_add(1).map(TimeInt::saturating)
    }

    /// The greatest time `< self` (none below the least time).
    fn minus_one(self) -> Option<TimeInt> {
        self.0.checked_sub(1).and_then(TimeInt::new)
    }
}

/// The value of a literal a time column of `time_type` is compared with: integers for
/// sequences, timestamps (any unit, converted to nanoseconds) for timestamps, durations
/// for durations. Anything else, a null or an overflow, is `None` (left to DataFusion).
fn literal_time(expr: &Expr, time_type: TimeType) -> Option<Literal> {
    let Expr::Literal(value, _) = expr else {
        return None;
    };
    let nanos = |v: Option<i64>, per: i64| v?.checked_mul(per);
    let value = match (time_type, value) {
        (TimeType::Sequence, ScalarValue::Int64(v))
        | (TimeType::TimestampNs, ScalarValue::TimestampNanosecond(v, _))
        | (TimeType::DurationNs, ScalarValue::DurationNanosecond(v)) => *v,
        (TimeType::Sequence, ScalarValue::Int32(v)) => v.map(i64::from),
        (TimeType::Sequence, ScalarValue::Int16(v)) => v.map(i64::from),
        (TimeType::Sequence, ScalarValue::Int8(v)) => v.map(i64::from),
        (TimeType::Sequence, ScalarValue::UInt32(v)) => v.map(i64::from),
        (TimeType::Sequence, ScalarValue::UInt64(v)) => v.and_then(|v| i64::try_from(v).ok()),
        (TimeType::TimestampNs, ScalarValue::TimestampMicrosecond(v, _))
        | (TimeType::DurationNs, ScalarValue::DurationMicrosecond(v)) => nanos(*v, 1_000),
        (TimeType::TimestampNs, ScalarValue::TimestampMillisecond(v, _))
        | (TimeType::DurationNs, ScalarValue::DurationMillisecond(v)) => nanos(*v, 1_000_000),
        (TimeType::TimestampNs, ScalarValue::TimestampSecond(v, _))
        | (TimeType::DurationNs, ScalarValue::DurationSecond(v)) => nanos(*v, 1_000_000_000),
        _ => None,
    }?;
    Some(Literal(value))
}

fn is_column(expr: &Expr, name: &str) -> bool {
    matches!(expr, Expr::Column(column) if column.name == name)
}

/// The items (among `known`, each with its text) a filter on the text column `column`
/// keeps (`=`, `IN`, `LIKE`, `starts_with`, and `OR`s of them), or `None` if the filter is
/// not one the scan answers: the `entity_path` column's entities, a dataset's segments by
/// id. Always exact when `Some`.
pub(crate) fn text_filter<K: Ord + Clone>(
    expr: &Expr,
    column: &str,
    known: &[(K, String)],
) -> Option<BTreeSet<K>> {
    let keep = |test: &dyn Fn(&str) -> bool| -> BTreeSet<K> {
        known
            .iter()
            .filter(|(_, text)| test(text))
            .map(|(path, _)| path.clone())
            .collect()
    };
    match expr {
        Expr::BinaryExpr(BinaryExpr {
            left,
            op: Operator::Or,
            right,
        }) => {
            let mut either = text_filter(left, column, known)?;
            either.extend(text_filter(right, column, known)?);
            Some(either)
        }
        Expr::BinaryExpr(BinaryExpr {
            left,
            op: Operator::Eq,
            right,
        }) => {
            let value = if is_column(left, column) {
                literal_str(right)?
            } else if is_column(right, column) {
                literal_str(left)?
            } else {
                return None;
            };
            Some(keep(&|text| text == value))
        }
        Expr::InList(InList {
            expr,
            list,
            negated: false,
        }) if is_column(expr, column) => {
            let values: Vec<&str> = list.iter().map(literal_str).collect::<Option<_>>()?;
            Some(keep(&|text| values.contains(&text)))
        }
        Expr::Like(Like {
            negated: false,
            expr,
            pattern,
            escape_char,
            case_insensitive: false,
        }) if is_column(expr, column) => {
            let pattern = literal_str(pattern)?;
            let escape = escape_char.unwrap_or('\\');
            Some(keep(&|text| like(text, pattern, escape)))
        }
        Expr::ScalarFunction(ScalarFunction { func, args })
            if func.name() == "starts_with" && args.len() == 2 && is_column(&args[0], column) =>
        {
            let prefix = literal_str(&args[1])?;
            Some(keep(&|text| text.starts_with(prefix)))
        }
        _ => None,
    }
}

fn literal_str(expr: &Expr) -> Option<&str> {
    match expr {
        Expr::Literal(
            ScalarValue::Utf8(Some(s))
            | ScalarValue::Utf8View(Some(s))
            | ScalarValue::LargeUtf8(Some(s)),
            _,
        ) => Some(s),
        _ => None,
    }
}

/// SQL `LIKE`: `%` matches any run of characters, `_` any one character, and `escape`
/// makes the character after it literal. Linear in `text` per pattern position (the
/// classic two-pointer match with backtracking to the last `%`).
pub(crate) fn like(text: &str, pattern: &str, escape: char) -> bool {
    #[derive(Clone, Copy, PartialEq)]
    enum Token {
        Any,
        One,
        Char(char),
    }
    let mut tokens = Vec::with_capacity(pattern.len());
    let mut chars = pattern.chars();
    while let Some(c) = chars.next() {
        tokens.push(match c {
            c if c == escape => Token::Char(chars.next().unwrap_or(escape)),
            '%' => Token::Any,
            '_' => Token::One,
            c => Token::Char(c),
        });
    }
    let text: Vec<char> = text.chars().collect();
    let (mut t, mut p) = (0, 0);
    let mut backtrack: Option<(usize, usize)> = None;
    while t < text.len() {
        match tokens.get(p) {
            Some(Token::Any) => {
                backtrack = Some((p, t));
                p += 1;
            }
            Some(Token::One) => {
                t += 1;
                p += 1;
            }
            Some(Token::Char(c)) if *c == text[t] => {
                t += 1;
                p += 1;
            }
            _ => match backtrack {
                Some((star, from)) => {
                    p = star + 1;
                    t = from + 1;
                    backtrack = Some((star, from + 1));
                }
                None => return false,
            },
        }
    }
    tokens[p..].iter().all(|token| *token == Token::Any)
}

/// The pushdown DataFusion is told for a filter: `Exact` where the scan alone answers it,
/// `Inexact` where the scan narrows what it reads and DataFusion filters again.
pub(crate) fn support(exact: Option<bool>) -> TableProviderFilterPushDown {
    match exact {
        Some(true) => TableProviderFilterPushDown::Exact,
        Some(false) => TableProviderFilterPushDown::Inexact,
        None => TableProviderFilterPushDown::Unsupported,
    }
}

#[cfg(test)]
mod tests {
    use datafusion::prelude::{col, lit};

    use super::*;

    fn t(v: i64) -> TimeInt {
        TimeInt::new(v).unwrap()
    }

    #[test]
    fn comparisons_on_the_index_become_exact_ranges() {
        let filter = |e: Expr| time_filter(&e, "frame", TimeType::Sequence);
        let range = |e: Expr| filter(e).map(|f| (f.range, f.exact));
        assert_eq!(
            range(col("frame").eq(lit(5i64))),
            Some((TimeRange::at(t(5)), true))
        );
        assert_eq!(
            range(col("frame").lt(lit(5i64))),
            Some((TimeRange::new(TimeInt::MIN, t(4)), true))
        );
        assert_eq!(
            range(lit(5i64).lt(col("frame"))),
            Some((TimeRange::new(t(6), TimeInt::MAX), true)),
            "a literal on the left flips the comparison"
        );
        assert_eq!(
            range(col("frame").between(lit(2i64), lit(7i64))),
            Some((TimeRange::new(t(2), t(7)), true))
        );
        assert_eq!(
            range(col("frame").in_list(vec![lit(9i64), lit(3i64)], false)),
            Some((TimeRange::new(t(3), t(9)), false)),
            "IN reads the covering range; DataFusion keeps the exact filter"
        );
        assert_eq!(
            range(col("frame").eq(lit(9i64)).or(col("frame").eq(lit(3i64)))),
            Some((TimeRange::new(t(3), t(9)), false)),
            "DataFusion's form of a short IN list"
        );
        assert!(range(col("frame").gt(lit(i64::MAX))).unwrap().0.is_empty());
        assert!(
            range(col("frame").lt(lit(i64::MIN + 1)))
                .unwrap()
                .0
                .is_empty()
        );
        assert!(
            range(col("frame").lt_eq(lit(i64::MIN)))
                .unwrap()
                .0
                .is_empty()
        );
        assert!(
            range(col("frame").between(lit(0i64), lit(i64::MIN)))
                .unwrap()
                .0
                .is_empty()
        );
        assert_eq!(
            range(col("frame").gt_eq(lit(i64::MIN))),
            Some((TimeRange::EVERYTHING, true))
        );
        assert_eq!(range(col("other").eq(lit(5i64))), None);
        assert_eq!(range(col("frame").not_eq(lit(5i64))), None);
        assert_eq!(range(col("frame").eq(lit(ScalarValue::Int64(None)))), None);
        assert_eq!(range(col("frame").eq(lit("5"))), None);
    }

    #[test]
    fn timestamps_of_any_unit_compare_in_nanoseconds() {
        let filter = time_filter(
            &col("log_time").gt_eq(lit(ScalarValue::TimestampMillisecond(Some(3), None))),
            "log_time",
            TimeType::TimestampNs,
        )
        .unwrap();
        assert_eq!(filter.range, TimeRange::new(t(3_000_000), TimeInt::MAX));
    }

    #[test]
    fn like_matches_as_sql_does() {
        assert!(like("/world/robot", "/world/%", '\\'));
        assert!(!like("/world", "/world/%", '\\'));
        assert!(like("/a/b/c", "%b%", '\\'));
        assert!(like("/a", "/_", '\\'));
        assert!(!like("/ab", "/_", '\\'));
        assert!(like("50%", "50\\%", '\\'));
        assert!(!like("500", "50\\%", '\\'));
        assert!(like("", "%", '\\'));
        assert!(like("aXbXc", "a%b%c", '\\'));
        assert!(!like("aXbX", "a%b%c", '\\'));
    }

    #[test]
    fn entity_filters_select_among_the_known_paths() {
        let known: Vec<(crate::EntityPath, String)> = ["/a", "/a/b", "/c"]
            .iter()
            .map(|p| {
                let path = crate::EntityPath::parse(p).unwrap();
                let text = path.to_string();
                (path, text)
            })
            .collect();
        let kept = |e: Expr| {
            text_filter(&e, "entity_path", &known)
                .map(|set| set.iter().map(ToString::to_string).collect::<Vec<_>>())
        };
        assert_eq!(
            kept(col("entity_path").eq(lit("/a"))),
            Some(vec!["/a".to_owned()])
        );
        assert_eq!(
            kept(col("entity_path").like(lit("/a/%"))),
            Some(vec!["/a/b".to_owned()])
        );
        assert_eq!(
            kept(col("entity_path").in_list(vec![lit("/c"), lit("/zzz")], false)),
            Some(vec!["/c".to_owned()])
        );
        assert_eq!(
            kept(
                col("entity_path")
                    .eq(lit("/a"))
                    .or(col("entity_path").eq(lit("/c")))
            ),
            Some(vec!["/a".to_owned(), "/c".to_owned()])
        );
        assert_eq!(
            kept(
                col("entity_path")
                    .eq(lit("/a"))
                    .or(col("chunk_id").eq(lit("/c")))
            ),
            None,
            "an OR with anything else is DataFusion's to answer"
        );
        assert_eq!(kept(col("entity_path").not_like(lit("/a/%"))), None);
        assert_eq!(kept(col("chunk_id").eq(lit("/a"))), None);
    }
}
