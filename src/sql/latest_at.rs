//! Latest-at in SQL: the `latest_at` table function, and [`asof_join`], an as-of join
//! of a table of query times with the store.

use std::sync::Arc;

use arrow_array::Array;
use datafusion::catalog::{TableFunctionArgs, TableFunctionImpl, TableProvider};
use datafusion::common::{DataFusionError, JoinType, Result, ScalarValue};
use datafusion::dataframe::DataFrame;
use datafusion::logical_expr::Expr;
use datafusion::prelude::{SessionContext, col};

use super::tables::TimelineTable;
use crate::{EntityPathFilter, Snapshot, TimeInt, TimeType};

/// `latest_at('<timeline>', <time> [, '<entity filter>'...])`: one row per time (a
/// time, or a list of times: `[10, 20, 30]`), each cell the latest-at answer of its
/// column at that time (SEMANTICS.md sections 3 and 9: Clears and static data included).
/// The entity filters are the dataframe view's (`/a/**`, `-/a/b`); default every entity
/// but `/__properties`.
///
/// ```sql
/// SELECT "/robot/arm:joint_torque" FROM latest_at('frame_id', 42, '/robot/**')
/// ```
#[derive(Debug, Clone)]
pub struct LatestAtFunction {
    snapshot: Snapshot,
}

impl LatestAtFunction {
    /// The function over `snapshot`.
    pub fn new(snapshot: Snapshot) -> Self {
        Self { snapshot }
    }
}

pub(super) fn plan_error(message: &str) -> DataFusionError {
    DataFusionError::Plan(format!("latest_at: {message}"))
}

impl TableFunctionImpl for LatestAtFunction {
    fn call_with_args(&self, args: TableFunctionArgs) -> Result<Arc<dyn TableProvider>> {
        let exprs = args.exprs();
        let usage = "expected latest_at('<timeline>', <time or [times]> [, '<entity filter>'...])";
        let Some(Expr::Literal(
            ScalarValue::Utf8(Some(timeline)) | ScalarValue::Utf8View(Some(timeline)),
            _,
        )) = exprs.first()
        else {
            return Err(plan_error(&format!(
                "the first argument must be a timeline name; {usage}"
            )));
        };
        let known = self.snapshot.timelines();
        let time_type = match self.snapshot.time_type(timeline) {
            Some(time_type) => time_type,
            // Without temporal data, any timeline answers (with static data alone); a time
            // is read as the literal's own type.
            None if known.is_empty() => literal_time_type(exprs.get(1)),
            None => {
                let unknown = crate::UnknownTimeline::new(timeline, &known);
                return Err(plan_error(&unknown.to_string()));
            }
        };
        let Some(Expr::Literal(value, _)) = exprs.get(1) else {
            return Err(plan_error(&format!(
                "the second argument must be a time literal; {usage}"
            )));
        };
        let times = times_of(value, time_type)?;
        let mut rules = Vec::new();
        for expr in &exprs[2..] {
            match expr {
                Expr::Literal(
                    ScalarValue::Utf8(Some(rule)) | ScalarValue::Utf8View(Some(rule)),
                    _,
                ) => {
                    rules.push(rule.clone());
                }
                _ => {
                    return Err(plan_error(&format!(
                        "entity filters must be strings; {usage}"
                    )));
                }
            }
        }
        let contents = if rules.is_empty() {
            EntityPathFilter::default()
        } else {
            EntityPathFilter::parse(&rules).map_err(|e| plan_error(&e.to_string()))?
        };
        let table = TimelineTable::sampled(self.snapshot.clone(), timeline, contents, times)?;
        Ok(Arc::new(table))
    }
}

/// The times a literal stands for on a timeline of `time_type`: one value, or each item
/// of a list.
fn times_of(value: &ScalarValue, time_type: TimeType) -> Result<Vec<TimeInt>> {
    if let ScalarValue::List(list) = value {
        let mut times = Vec::new();
        for row in 0..list.len() {
            let items = list.value(row);
            for item in 0..items.len() {
                let scalar = ScalarValue::try_from_array(&items, item)?;
                times.push(time_of(&scalar, time_type)?);
            }
        }
        return Ok(times);
    }
    Ok(vec![time_of(value, time_type)?])
}

/// The type a time literal reads as on a timeline of no type: a timestamp or duration
/// literal's own, text in the first form it reads in, otherwise a sequence.
fn literal_time_type(expr: Option<&Expr>) -> TimeType {
    match expr {
        Some(Expr::Literal(ScalarValue::TimestampNanosecond(..), _)) => TimeType::TimestampNs,
        Some(Expr::Literal(ScalarValue::DurationNanosecond(..), _)) => TimeType::DurationNs,
        Some(Expr::Literal(
            ScalarValue::Utf8(Some(text))
            | ScalarValue::Utf8View(Some(text))
            | ScalarValue::LargeUtf8(Some(text)),
            _,
        )) => [
            TimeType::Sequence,
            TimeType::DurationNs,
            TimeType::TimestampNs,
        ]
        .into_iter()
        .find(|kind| kind.parse_time(text).is_ok())
        .unwrap_or(TimeType::Sequence),
        _ => TimeType::Sequence,
    }
}

fn time_of(value: &ScalarValue, time_type: TimeType) -> Result<TimeInt> {
    // Text as a person writes it: '2026-11-21T12:55:49Z', '1.5s' (the CLI's parser).
    if let ScalarValue::Utf8(Some(text))
    | ScalarValue::Utf8View(Some(text))
    | ScalarValue::LargeUtf8(Some(text)) = value
    {
        return time_type
            .parse_time(text)
            .map_err(|e| plan_error(&e.to_string()));
    }
    let raw = match (time_type, value) {
        (TimeType::Sequence, ScalarValue::Int32(Some(v))) => Some(i64::from(*v)),
        (TimeType::Sequence, ScalarValue::UInt64(Some(v))) => i64::try_from(*v).ok(),
        (TimeType::TimestampNs, ScalarValue::TimestampNanosecond(Some(v), _))
        | (TimeType::DurationNs, ScalarValue::DurationNanosecond(Some(v)))
        | (_, ScalarValue::Int64(Some(v))) => Some(*v),
        _ => None,
    };
    raw.and_then(TimeInt::new).ok_or_else(|| {
        plan_error(&format!(
            "{value:?} is not a time of a {time_type:?} timeline (integers, in nanoseconds for \
             timestamps and durations, or text such as '2026-11-21T12:55:49Z' or '1.5s')"
        ))
    })
}

/// An as-of join, like DuckDB's `ASOF JOIN`: every row of `left`, with the latest-at
/// answer of every column of the store's view on `timeline` at that row's `left_on`
/// time (a left join: columns without an answer are null). `left_on` must have the
/// timeline's Arrow type (`Int64` for sequences).
///
/// The store samples its view once per distinct time of `left` and the two tables are
/// joined on equal times; the view's index column is renamed `<timeline>@asof`.
///
/// # Errors
/// DataFusion's, and a `left_on` column whose values are not times of the timeline.
pub async fn asof_join(
    ctx: &SessionContext,
    snapshot: &Snapshot,
    left: DataFrame,
    left_on: &str,
    timeline: &str,
    contents: EntityPathFilter,
) -> Result<DataFrame> {
    let Some(time_type) = snapshot.time_type(timeline) else {
        return Err(plan_error(&format!("unknown timeline {timeline:?}")));
    };
    let batches = left
        .clone()
        .select(vec![col(left_on)])?
        .distinct()?
        .collect()
        .await?;
    let mut times = Vec::new();
    for batch in &batches {
        let column = batch.column(0);
        for row in 0..column.len() {
            let value = ScalarValue::try_from_array(column, row)?;
            if !value.is_null() {
                times.push(time_of(&value, time_type)?);
            }
        }
    }
    times.sort_unstable();
    let table = TimelineTable::sampled(snapshot.clone(), timeline, contents, times)?;
    let renamed = format!("{timeline}@asof");
    let right = ctx
        .read_table(Arc::new(table))?
        .with_column_renamed(timeline, &renamed)?;
    left.join(right, JoinType::Left, &[left_on], &[renamed.as_str()], None)
}
