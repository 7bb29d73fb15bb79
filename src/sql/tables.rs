//! The store's tables for DataFusion: [`TimelineTable`], one per timeline (the dataframe
//! view on it), and [`ChunksTable`], every stored row across entities.

use std::collections::BTreeSet;
use std::sync::Arc;

use arrow_schema::SchemaRef;
use async_trait::async_trait;
use datafusion::catalog::Session;
use datafusion::common::{DataFusionError, Result};
use datafusion::datasource::{TableProvider, TableType};
use datafusion::logical_expr::{Expr, TableProviderFilterPushDown};
use datafusion::physical_plan::ExecutionPlan;

use super::external;
use super::pushdown::{self, TimeFilter};
use super::scan::{ScanSource, StoreScanExec};
use crate::{
    ChunkTableQuery, DataframeQuery, EntityPath, EntityPathFilter, Snapshot, TimeInt, TimeRange,
    Timeline,
};

/// The name of the chunk table's entity path column.
pub(super) const ENTITY_PATH: &str = "entity_path";

/// What a chunk table's filters read of it, the store's ([`ChunksTable`]) or a dataset's:
/// a filter on `entity_path` picks the entities whose rows are read (`Exact`), one on a
/// timeline the chunks that overlap its range (`Inexact`: DataFusion filters the rows).
#[derive(Debug, Clone)]
pub(super) struct ChunkRowFilters {
    /// Every entity path, with its text as the `entity_path` column shows it.
    entities: Vec<(EntityPath, String)>,
    timelines: Vec<Timeline>,
}

/// The rows a chunk table's filters pick, as [`ChunkRowFilters::apply`] found them.
pub(super) struct PickedRows<'a> {
    /// The query reading them.
    pub query: ChunkTableQuery,
    /// The entities whose rows are read; all where `None`.
    pub entities: Option<BTreeSet<EntityPath>>,
    /// The range on a timeline that the chunks read overlap; any where `None`.
    pub overlapping: Option<(&'a Timeline, TimeRange)>,
}

impl ChunkRowFilters {
    pub(super) fn new(entities: Vec<EntityPath>, timelines: Vec<Timeline>) -> Self {
        let entities = entities
            .into_iter()
            .map(|path| {
                let text = path.to_string();
                (path, text)
            })
            .collect();
        Self {
            entities,
            timelines,
        }
    }

    fn entity_filter(&self, filter: &Expr) -> Option<BTreeSet<EntityPath>> {
        pushdown::text_filter(filter, ENTITY_PATH, &self.entities)
    }

    /// What DataFusion is told of `filter`.
    pub(super) fn support(&self, filter: &Expr) -> TableProviderFilterPushDown {
        pushdown::support(if self.entity_filter(filter).is_some() {
            Some(true)
        } else {
            pushdown::timeline_filter(filter, &self.timelines).map(|_| false)
        })
    }

    /// `filters` applied to `query`, each noted in `pushed_down` for `EXPLAIN`.
    pub(super) fn apply(
        &self,
        filters: &[Expr],
        mut query: ChunkTableQuery,
        pushed_down: &mut Vec<String>,
    ) -> PickedRows<'_> {
        let entities = filters
            .iter()
            .filter_map(|filter| self.entity_filter(filter))
            .reduce(|a, b| a.intersection(&b).cloned().collect());
        if let Some(entities) = &entities {
            pushed_down.push(format!(
                "entities={} of {}",
                entities.len(),
                self.entities.len()
            ));
            query = query.with_row_entities(entities.iter().cloned());
        }
        // One timeline's range narrows the chunks read; DataFusion applies every filter
        // on times again.
        let overlapping = pushdown::chunks_overlapping(filters, &self.timelines);
        if let Some((timeline, range)) = overlapping {
            pushed_down.push(format!(
                "chunks overlapping {}",
                pushdown::describe(timeline.name(), range)
            ));
            query = query.with_rows_overlapping(Arc::clone(timeline.name_arc()), range);
        }
        PickedRows {
            query,
            entities,
            overlapping,
        }
    }
}

/// Batches no longer than this when a small `LIMIT` is pushed down (a longer limit keeps
/// the view's own batch size).
const SMALL_LIMIT: usize = 4_096;

/// The batch size a pushed-down `LIMIT` asks of the scan (batches no longer than a short
/// limit, so that no row past it is built), the limit noted for `EXPLAIN`.
fn limit_batch_rows(limit: Option<usize>, pushed_down: &mut Vec<String>) -> Option<usize> {
    let limit = limit?;
    pushed_down.push(format!("limit={limit}"));
    (limit < SMALL_LIMIT).then_some(limit.max(1))
}

/// One timeline's dataframe view of a snapshot (SEMANTICS.md section 9) as a DataFusion
/// table: the timelines' index columns, then one list column per `<entity>:<component>`.
///
/// Filters on the index column (`=`, `<`, `<=`, `>`, `>=`, `BETWEEN`) become the view's
/// range, which the store's index applies exactly (`Exact` pushdown); `IN` reads the
/// range covering its values and DataFusion filters again. A projection builds only the
/// selected columns (every selected entity's times still decide the rows, as the view's
/// rows are), and a `LIMIT` stops the stream early. The rows ascend on the index and the
/// scan declares it, so `ORDER BY <index>` costs no sort.
#[derive(Debug, Clone)]
pub struct TimelineTable {
    snapshot: Snapshot,
    index: Timeline,
    contents: EntityPathFilter,
    /// Sampling at these times (the `latest_at` table function), else the sparse view.
    samples: Option<Arc<[TimeInt]>>,
    schema: SchemaRef,
    /// The times the view holds on its index (`None`: none), found on the first scan of
    /// an open range that is built in parts: O(n) over the indices, so not on
    /// registration.
    held_range: Arc<std::sync::OnceLock<Option<TimeRange>>>,
}

impl TimelineTable {
    /// The sparse view of `snapshot` on `timeline`, over `contents`.
    ///
    /// # Errors
    /// A timeline the snapshot has never seen.
    pub fn new(snapshot: Snapshot, timeline: &str, contents: EntityPathFilter) -> Result<Self> {
        Self::build(snapshot, timeline, contents, None)
    }

    /// One row per time of `times`, in that order, each cell the latest-at answer there
    /// (the view sampled, SEMANTICS.md section 9).
    ///
    /// # Errors
    /// A timeline the snapshot has never seen.
    pub fn sampled(
        snapshot: Snapshot,
        timeline: &str,
        contents: EntityPathFilter,
        times: impl IntoIterator<Item = TimeInt>,
    ) -> Result<Self> {
        Self::build(
            snapshot,
            timeline,
            contents,
            Some(times.into_iter().collect()),
        )
    }

    fn build(
        snapshot: Snapshot,
        timeline: &str,
        contents: EntityPathFilter,
        samples: Option<Arc<[TimeInt]>>,
    ) -> Result<Self> {
        let mut table = Self {
            index: Timeline::new(timeline, crate::TimeType::Sequence),
            contents,
            samples,
            schema: Arc::new(arrow_schema::Schema::empty()),
            held_range: Arc::default(),
            snapshot,
        };
        let query = table.query();
        table.schema = table.snapshot.dataframe_schema(&query).map_err(external)?;
        // A store without temporal data answers on any timeline (static data alone), as
        // its dataframe does: the index is then a sequence.
        let time_type = match table.snapshot.time_type(timeline) {
            Some(time_type) => time_type,
            None if table.snapshot.timelines().is_empty() => crate::TimeType::Sequence,
            None => {
                return Err(DataFusionError::Plan(format!(
                    "the store has no timeline {timeline:?}"
                )));
            }
        };
        table.index = Timeline::new(timeline, time_type);
        Ok(table)
    }

    /// The index timeline.
    pub fn index(&self) -> &Timeline {
        &self.index
    }

    fn query(&self) -> DataframeQuery {
        let query = DataframeQuery::new(Arc::clone(self.index.name_arc()))
            .with_contents(self.contents.clone());
        match &self.samples {
            Some(times) => query.with_index_values(times.iter().copied()),
            None => query,
        }
    }

    /// `range` cut into at most `partitions` consecutive ranges of equal width (an open end
    /// clipped to the times the view holds on its index), to be built side by side: a
    /// row's index time puts it in exactly one of them, and a range is exactly what a
    /// pushed-down filter on the index makes of the view (SEMANTICS.md section 9), so
    /// their rows in order are `range`'s. One range when there is no room to cut (fewer
    /// distinct times than parts, or one part asked for).
    fn split(&self, range: TimeRange, partitions: usize) -> Vec<TimeRange> {
        if partitions <= 1 || range.is_empty() {
            return vec![range];
        }
        // An open end is clipped to the times the view holds (else every row would land
        // in the first part of [lo, i64::MAX]). A range bounded at both ends is cut as
        // given: finding the held times is O(n) over the indices, too dear for a query
        // of a session made for it (as Flight SQL makes one per query).
        let (lo, hi) = if range.min() == TimeInt::MIN || range.max() == TimeInt::MAX {
            let held = *self
                .held_range
                .get_or_init(|| self.snapshot.time_range(self.index.name()));
            let Some(held) = held else {
                return vec![range];
            };
            (
                range.min().max(held.min()).as_i64(),
                range.max().min(held.max()).as_i64(),
            )
        } else {
            (range.min().as_i64(), range.max().as_i64())
        };
        if lo > hi {
            return vec![range];
        }
        let width = i128::from(hi) - i128::from(lo) + 1;
        let parts = i128::try_from(partitions).unwrap_or(i128::MAX).min(width);
        if parts <= 1 {
            return vec![range];
        }
        // Bounds of part k: lo + width·k / parts, each within [lo, hi + 1]; the first
        // and last parts keep the range's own ends, so nothing outside the held times
        // is cut off (a chunk inserted later into a fresh snapshot does not matter here:
        // a snapshot never changes).
        let bound = |k: i128| -> i64 {
            i64::try_from(i128::from(lo) + width * k / parts).unwrap_or(i64::MAX)
        };
        (0..parts)
            .map(|k| {
                let min = if k == 0 {
                    range.min()
                } else {
                    TimeInt::saturating(bound(k))
                };
                let max = if k == parts - 1 {
                    range.max()
                } else {
                    TimeInt::saturating(bound(k + 1) - 1)
                };
                TimeRange::new(min, max)
            })
            .collect()
    }

    fn time_filter(&self, filter: &Expr) -> Option<TimeFilter> {
        if self.samples.is_some() {
            return None; // a sample's rows are its times: a range would not narrow them
        }
        pushdown::time_filter(filter, self.index.name(), self.index.time_type())
    }
}

#[async_trait]
impl TableProvider for TimelineTable {
    fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }

    fn table_type(&self) -> TableType {
        TableType::Base
    }

    fn supports_filters_pushdown(
        &self,
        filters: &[&Expr],
    ) -> Result<Vec<TableProviderFilterPushDown>> {
        Ok(filters
            .iter()
            .map(|filter| pushdown::support(self.time_filter(filter).map(|f| f.exact)))
            .collect())
    }

    async fn scan(
        &self,
        state: &dyn Session,
        projection: Option<&Vec<usize>>,
        filters: &[Expr],
        limit: Option<usize>,
    ) -> Result<Arc<dyn ExecutionPlan>> {
        let mut query = self.query();
        let mut pushed_down = Vec::new();
        if let Some(times) = &self.samples {
            pushed_down.push(format!("sampled at {} times", times.len()));
        }
        let ranges: Vec<TimeRange> = filters
            .iter()
            .filter_map(|filter| self.time_filter(filter))
            .map(|filter| filter.range)
            .collect();
        if let Some(range) = ranges.into_iter().reduce(pushdown::intersect) {
            query = query.with_range(range);
            pushed_down.push(pushdown::describe(self.index.name(), range));
        }
        let (schema, projection) = project(&self.schema, projection, &mut pushed_down)?;
        if let Some((names, _)) = &projection {
            query = query.with_columns(names.iter().cloned());
        }
        if let Some(rows) = limit_batch_rows(limit, &mut pushed_down) {
            query = query.with_batch_rows(rows);
        }
        let projection = projection.and_then(|(_, order)| order);
        // The range is built in consecutive parts side by side (`target_partitions` of
        // them), read in order. A sampled view's rows come in the order of its times, and
        // a pushed-down limit wants the first rows only: both are built in one part.
        let partitions = if self.samples.is_none() && limit.is_none() {
            self.split(query.range(), state.config().target_partitions())
        } else {
            vec![query.range()]
        };
        if partitions.len() > 1 {
            pushed_down.push(format!(
                "{} ranges of {} built side by side",
                partitions.len(),
                self.index.name()
            ));
        }
        let source = ScanSource::Dataframe {
            queries: partitions
                .into_iter()
                .map(|range| query.clone().with_range(range))
                .collect(),
            projection,
        };
        let scan = StoreScanExec::new(
            self.snapshot.clone(),
            self.index.name().to_owned(),
            source,
            pushed_down,
            limit,
            schema,
        );
        // The sparse view's rows ascend on the index; sampled rows come in the order of
        // the times asked for.
        Ok(Arc::new(if self.samples.is_none() {
            scan.sorted_by(self.index.name())
        } else {
            scan
        }))
    }
}

/// A projection of `schema`: the projected schema and, when there is a projection, the
/// names of its columns and the order to put the table's columns in (`None` when the
/// table's own order is the one asked for). The store builds the named columns in its
/// own order.
type Projected = (SchemaRef, Option<(Vec<String>, Option<Vec<usize>>)>);

fn project(
    schema: &SchemaRef,
    projection: Option<&Vec<usize>>,
    pushed_down: &mut Vec<String>,
) -> Result<Projected> {
    let Some(projection) = projection else {
        return Ok((Arc::clone(schema), None));
    };
    let projected = Arc::new(schema.project(projection)?);
    let mut sorted = projection.clone();
    sorted.sort_unstable();
    sorted.dedup();
    let order: Vec<usize> = projection
        .iter()
        .map(|i| sorted.partition_point(|s| s < i))
        .collect();
    let in_view_order =
        order.iter().enumerate().all(|(a, &b)| a == b) && order.len() == sorted.len();
    pushed_down.push(format!(
        "columns={} of {}",
        sorted.len(),
        schema.fields().len()
    ));
    let names = sorted
        .iter()
        .map(|&i| schema.field(i).name().clone())
        .collect();
    Ok((
        projected,
        Some((names, if in_view_order { None } else { Some(order) })),
    ))
}

/// Every stored row of a snapshot, across entities (`StoreView::chunk_table`):
/// `entity_path`, `chunk_id`, `row_id`, one column per timeline, one list column per
/// component name.
///
/// Filters on `entity_path` (`=`, `IN`, `LIKE`, `starts_with`) are matched against the
/// store's entity paths and read only the matching entities' chunks (`Exact`); a filter
/// on a timeline column reads only the chunks whose times there overlap it, and
/// DataFusion filters their rows again (`Inexact`). A projection builds only the selected
/// columns, and a `LIMIT` stops the stream early.
#[derive(Debug, Clone)]
pub struct ChunksTable {
    snapshot: Snapshot,
    filters: ChunkRowFilters,
    schema: SchemaRef,
}

impl ChunksTable {
    /// Every stored row of `snapshot`.
    ///
    /// # Errors
    /// None in practice (the chunk table of a store always plans); DataFusion's error type
    /// for uniformity.
    pub fn new(snapshot: Snapshot) -> Result<Self> {
        let schema = snapshot
            .chunk_table(&ChunkTableQuery::new().with_row_entities([]))
            .map_err(external)?
            .schema();
        let filters = ChunkRowFilters::new(snapshot.entity_paths(), snapshot.timelines());
        Ok(Self {
            snapshot,
            filters,
            schema,
        })
    }
}

#[async_trait]
impl TableProvider for ChunksTable {
    fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }

    fn table_type(&self) -> TableType {
        TableType::Base
    }

    fn supports_filters_pushdown(
        &self,
        filters: &[&Expr],
    ) -> Result<Vec<TableProviderFilterPushDown>> {
        Ok(filters
            .iter()
            .map(|filter| self.filters.support(filter))
            .collect())
    }

    async fn scan(
        &self,
        _state: &dyn Session,
        projection: Option<&Vec<usize>>,
        filters: &[Expr],
        limit: Option<usize>,
    ) -> Result<Arc<dyn ExecutionPlan>> {
        let mut pushed_down = Vec::new();
        let mut query = self
            .filters
            .apply(filters, ChunkTableQuery::new(), &mut pushed_down)
            .query;
        let (schema, projection) = project(&self.schema, projection, &mut pushed_down)?;
        if let Some((names, _)) = &projection {
            query = query.with_columns(names.iter().cloned());
        }
        if let Some(rows) = limit_batch_rows(limit, &mut pushed_down) {
            query = query.with_batch_rows(rows);
        }
        let source = ScanSource::Chunks {
            query,
            projection: projection.and_then(|(_, order)| order),
        };
        Ok(Arc::new(StoreScanExec::new(
            self.snapshot.clone(),
            "chunks".to_owned(),
            source,
            pushed_down,
            limit,
            schema,
        )))
    }
}
