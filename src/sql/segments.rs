//! Several recordings as one set of tables ([`register_segments`]): each table of
//! [`register`](super::register) once per recording that has it, the recording's id
//! prepended as `rerun_segment_id`, and the recordings' rows stacked (a union by column
//! name, so a column one recording lacks is null in its rows). Filters and projections
//! still reach each recording's scan: the union is a view that DataFusion plans through.

use std::collections::BTreeSet;
use std::sync::Arc;

use datafusion::catalog::{TableFunctionArgs, TableFunctionImpl};
use datafusion::common::{Column, Result};
use datafusion::datasource::{TableProvider, ViewTable, provider_as_source};
use datafusion::logical_expr::{Expr, LogicalPlan, LogicalPlanBuilder, lit};
use datafusion::prelude::SessionContext;

use super::latest_at::{LatestAtFunction, plan_error};
use super::tables::{ChunksTable, TimelineTable};
use super::{CHUNKS_TABLE, replace_table};
use crate::{EntityPathFilter, Snapshot, Timeline};

pub use crate::dataframe::SEGMENT_ID_COLUMN;

/// Registers the tables of several recordings (`(segment id, snapshot)`, usually the
/// recording id) in `ctx`: a table per timeline any of them has, `chunks`, and
/// `latest_at(...)`, each with [`SEGMENT_ID_COLUMN`] first. Returns the table names,
/// timelines first (sorted), then the chunk table's (`__chunks` if a timeline is named
/// `chunks`). With no segment there is `chunks` alone, empty (a timeline table's columns
/// come from its segments; the chunk table's shape does not depend on the data).
///
/// # Errors
/// DataFusion's, should planning a union fail.
pub fn register_segments(
    ctx: &SessionContext,
    segments: &[(String, Snapshot)],
) -> Result<Vec<String>> {
    let timelines: BTreeSet<String> = segments
        .iter()
        .flat_map(|(_, snapshot)| snapshot.timelines())
        .map(|timeline| timeline.name().to_owned())
        .collect();
    let mut names = Vec::new();
    for timeline in &timelines {
        let mut parts = Vec::new();
        for (segment, snapshot) in segments {
            if snapshot.time_type(timeline).is_some() {
                let table =
                    TimelineTable::new(snapshot.clone(), timeline, EntityPathFilter::default())?;
                parts.push((segment.as_str(), Arc::new(table) as Arc<dyn TableProvider>));
            }
        }
        if let Some(view) = stacked(timeline, parts)? {
            replace_table(ctx, timeline, view)?;
            names.push(timeline.clone());
        }
    }
    let chunks_name = if timelines.contains(CHUNKS_TABLE) {
        format!("__{CHUNKS_TABLE}")
    } else {
        CHUNKS_TABLE.to_owned()
    };
    let mut parts = Vec::new();
    for (segment, snapshot) in segments {
        let table = ChunksTable::new(snapshot.clone())?;
        parts.push((segment.as_str(), Arc::new(table) as Arc<dyn TableProvider>));
    }
    // `chunks` is there with no segment too (its shape does not depend on the data), so
    // that a client started before the first recording can probe it: an empty store's
    // table has no rows.
    let empty = crate::SharedStore::new(crate::ChunkStore::new()).snapshot();
    if parts.is_empty() {
        parts.push((
            "",
            Arc::new(ChunksTable::new(empty)?) as Arc<dyn TableProvider>,
        ));
    }
    if let Some(view) = stacked(&chunks_name, parts)? {
        replace_table(ctx, &chunks_name, view)?;
        names.push(chunks_name);
    }
    ctx.register_udtf(
        "latest_at",
        Arc::new(SegmentsLatestAt {
            segments: segments.to_vec(),
        }),
    );
    super::register_expr_planners(ctx)?;
    Ok(names)
}

/// One view stacking `parts` (each a segment's table) with the segment id first; `None`
/// for no parts.
fn stacked(
    name: &str,
    parts: Vec<(&str, Arc<dyn TableProvider>)>,
) -> Result<Option<Arc<dyn TableProvider>>> {
    let mut plan: Option<LogicalPlanBuilder> = None;
    for (segment, table) in parts {
        let schema = table.schema();
        let mut columns: Vec<Expr> = vec![lit(segment.to_owned()).alias(SEGMENT_ID_COLUMN)];
        columns.extend(
            schema
                .fields()
                .iter()
                .map(|field| Expr::Column(Column::new_unqualified(field.name()))),
        );
        let part = LogicalPlanBuilder::scan(name, provider_as_source(table), None)?
            .project(columns)?
            .build()?;
        plan = Some(match plan {
            None => LogicalPlanBuilder::from(part),
            Some(builder) => builder.union_by_name(part)?,
        });
    }
    let Some(plan) = plan else {
        return Ok(None);
    };
    let plan: LogicalPlan = plan.build()?;
    Ok(Some(Arc::new(StackedTable(ViewTable::new(plan, None)))))
}

/// The stacked view, a table to whoever asks (`SHOW TABLES`, `information_schema`: `BASE
/// TABLE`, as one recording's tables are): DataFusion still plans through the view, which
/// it inlines wherever a provider has a logical plan.
#[derive(Debug)]
struct StackedTable(ViewTable);

#[async_trait::async_trait]
impl TableProvider for StackedTable {
    fn schema(&self) -> arrow_schema::SchemaRef {
        self.0.schema()
    }

    fn table_type(&self) -> datafusion::datasource::TableType {
        datafusion::datasource::TableType::Base
    }

    fn get_logical_plan(&self) -> Option<std::borrow::Cow<'_, LogicalPlan>> {
        self.0.get_logical_plan()
    }

    fn supports_filters_pushdown(
        &self,
        filters: &[&Expr],
    ) -> Result<Vec<datafusion::logical_expr::TableProviderFilterPushDown>> {
        self.0.supports_filters_pushdown(filters)
    }

    async fn scan(
        &self,
        state: &dyn datafusion::catalog::Session,
        projection: Option<&Vec<usize>>,
        filters: &[Expr],
        limit: Option<usize>,
    ) -> Result<Arc<dyn datafusion::physical_plan::ExecutionPlan>> {
        self.0.scan(state, projection, filters, limit).await
    }
}

/// `latest_at('<timeline>', <time>, ...)` over several segments: each segment's answer,
/// stacked, with the segment id first.
#[derive(Debug)]
struct SegmentsLatestAt {
    segments: Vec<(String, Snapshot)>,
}

impl TableFunctionImpl for SegmentsLatestAt {
    fn call_with_args(&self, args: TableFunctionArgs) -> Result<Arc<dyn TableProvider>> {
        let timeline = match args.exprs().first() {
            Some(Expr::Literal(value, _)) => value.try_as_str().flatten().map(str::to_owned),
            _ => None,
        };
        let mut parts = Vec::new();
        for (segment, snapshot) in &self.segments {
            let knows = timeline
                .as_deref()
                .is_some_and(|t| snapshot.time_type(t).is_some());
            if knows {
                let table = LatestAtFunction::new(snapshot.clone())
                    .call_with_args(TableFunctionArgs::new(args.exprs(), args.session()))?;
                parts.push((segment.as_str(), table));
            }
        }
        if parts.is_empty() {
            let known: Vec<Timeline> = self
                .segments
                .iter()
                .flat_map(|(_, snapshot)| snapshot.timelines())
                .collect();
            if let Some(name) = &timeline {
                return Err(plan_error(
                    &crate::UnknownTimeline::new(name, &known).to_string(),
                ));
            }
            // Not a timeline name at all: the single-recording function says what is
            // expected.
            return LatestAtFunction::new(crate::ChunkStore::new().snapshot()).call_with_args(args);
        }
        stacked("latest_at", parts)?.ok_or_else(|| plan_error("no segment has the timeline"))
    }
}
