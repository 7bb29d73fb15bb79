//! Integers compared with times: `WHERE sim_time > 1000000000`. A duration or timestamp
//! timeline's column is Arrow `Duration(ns)` or `Timestamp(ns)`, which DataFusion
//! compares with an `INTERVAL`, a `TIMESTAMP` or a string but refuses to compare with an
//! integer ("Cannot infer common argument type"), while everywhere else in chunkstore (the
//! CLI, Python, `latest_at`) such a time is written as integer nanoseconds. This planner
//! casts the integer side of such a comparison to the column's type before DataFusion
//! coerces types; the cast literal folds to a time, which the scan's pushdown reads as any
//! other.

use arrow_schema::{DataType, TimeUnit};
use datafusion::common::DFSchema;
use datafusion::error::Result;
use datafusion::logical_expr::planner::{ExprPlanner, PlannerResult, RawBinaryExpr};
use datafusion::logical_expr::{Expr, ExprSchemable, cast};
use datafusion::sql::sqlparser::ast::BinaryOperator;

/// See the module docs.
#[derive(Debug)]
pub(crate) struct IntegerTimes;

/// A column type this planner lets integers compare with: nanosecond durations and
/// timestamps (any timezone), the types of duration and timestamp timelines.
fn is_time(data_type: &DataType) -> bool {
    matches!(
        data_type,
        DataType::Duration(TimeUnit::Nanosecond) | DataType::Timestamp(TimeUnit::Nanosecond, _)
    )
}

impl ExprPlanner for IntegerTimes {
    fn plan_binary_op(
        &self,
        expr: RawBinaryExpr,
        schema: &DFSchema,
    ) -> Result<PlannerResult<RawBinaryExpr>> {
        use BinaryOperator::{Eq, Gt, GtEq, Lt, LtEq, NotEq};
        if !matches!(expr.op, Eq | NotEq | Lt | LtEq | Gt | GtEq) {
            return Ok(PlannerResult::Original(expr));
        }
        let type_of = |e: &Expr| e.get_type(schema).ok();
        let RawBinaryExpr { op, left, right } = expr;
        let (left, right) = match (type_of(&left), type_of(&right)) {
            (Some(l), Some(r)) if is_time(&l) && r.is_integer() => (left, cast(right, l)),
            (Some(l), Some(r)) if l.is_integer() && is_time(&r) => (cast(left, r), right),
            _ => (left, right),
        };
        // Not planned here: DataFusion goes on with the (possibly cast) operands.
        Ok(PlannerResult::Original(RawBinaryExpr { op, left, right }))
    }
}
