//! A dataset's tables: [`DatasetTimelineTable`], one per timeline, and
//! [`DatasetChunksTable`]; each turns a query's filters into the segments, chunks and
//! columns its [`DatasetScanExec`] reads, and tells DataFusion which filters it answers.

use std::collections::BTreeSet;
use std::sync::Arc;

use arrow_schema::SchemaRef;
use async_trait::async_trait;
use datafusion::catalog::Session;
use datafusion::common::Result;
use datafusion::datasource::{TableProvider, TableType};
use datafusion::logical_expr::{Expr, TableProviderFilterPushDown};
use datafusion::physical_expr::EquivalenceProperties;
use datafusion::physical_plan::ExecutionPlan;

use super::scan::{ChunkPicks, DatasetScanExec, DatasetSource, Projected};
use crate::dataset::Dataset;
use crate::sql::CHUNKS_TABLE;
use crate::sql::pushdown::{self, TimeFilter};
use crate::sql::scan::ascending_on;
use crate::sql::tables::{ChunkRowFilters, PickedRows};
use crate::{ChunkTableQuery, DataframeQuery, SEGMENT_ID_COLUMN, Timeline};

/// The segments (among `segments`) that `filters` on [`SEGMENT_ID_COLUMN`] keep, all of
/// them where no filter is on it; and how many the filters dropped.
fn kept_segments(filters: &[Expr], segments: &[(usize, String)]) -> (BTreeSet<usize>, usize) {
    let mut kept: BTreeSet<usize> = segments.iter().map(|(n, _)| *n).collect();
    for filter in filters {
        if let Some(named) = segment_filter(filter, segments) {
            kept = kept.intersection(&named).copied().collect();
        }
    }
    let dropped = segments.len() - kept.len();
    (kept, dropped)
}

/// The segments (by number) a filter on [`SEGMENT_ID_COLUMN`] keeps, where it is one the
/// scan applies itself (exactly: DataFusion need not filter again).
fn segment_filter(filter: &Expr, segments: &[(usize, String)]) -> Option<BTreeSet<usize>> {
    pushdown::text_filter(filter, SEGMENT_ID_COLUMN, segments)
}

/// What `EXPLAIN` says of the segments a scan reads: `segments=N of M`, and why the others
/// were pruned.
fn segments_line(kept: usize, total: usize, pruned: &[String]) -> String {
    if pruned.is_empty() {
        format!("segments={kept} of {total}")
    } else {
        format!("segments={kept} of {total} (pruned: {})", pruned.join(", "))
    }
}

/// The segments a filter on the id pruned, as [`segments_line`] lists them.
fn pruned_by_id(by_id: usize) -> Vec<String> {
    if by_id > 0 {
        vec![format!("{by_id} by {SEGMENT_ID_COLUMN}")]
    } else {
        Vec::new()
    }
}

/// The scan's side of a projection: the stream's schema (the segment id and the projected
/// columns, in the table's order), the output, and where each output column is.
fn stream_projection(
    table: &SchemaRef,
    projection: Option<&Vec<usize>>,
    pushed_down: &mut Vec<String>,
) -> Result<Projected> {
    let Some(projection) = projection else {
        let names = table
            .fields()
            .iter()
            .skip(1)
            .map(|f| f.name().clone())
            .collect();
        return Ok(Projected {
            stream: Arc::clone(table),
            output: Arc::clone(table),
            names,
            positions: None,
        });
    };
    let output = Arc::new(table.project(projection)?);
    let mut read: Vec<usize> = projection.clone();
    read.push(0);
    read.sort_unstable();
    read.dedup();
    pushed_down.push(format!(
        "columns={} of {}",
        projection.iter().collect::<BTreeSet<_>>().len(),
        table.fields().len()
    ));
    let stream = Arc::new(table.project(&read)?);
    let names = read
        .iter()
        .skip(1)
        .map(|&i| table.field(i).name().clone())
        .collect();
    let positions: Vec<usize> = projection
        .iter()
        .map(|i| read.partition_point(|r| r < i))
        .collect();
    let identity =
        positions.len() == read.len() && positions.iter().enumerate().all(|(a, &b)| a == b);
    Ok(Projected {
        stream,
        output,
        names,
        positions: (!identity).then_some(positions),
    })
}

/// One timeline's dataframe over a dataset as a DataFusion table: the segment id, the
/// timelines' index columns, one list column per `<entity>:<component>` of any segment.
/// Rows are ordered by (segment id, index) within each partition, and the scan says so.
#[derive(Debug, Clone)]
pub struct DatasetTimelineTable {
    dataset: Dataset,
    index: Timeline,
    schema: SchemaRef,
    /// Every segment, by number, with its id.
    segments: Arc<[(usize, String)]>,
}

impl DatasetTimelineTable {
    pub(super) fn new(
        dataset: Dataset,
        index: Timeline,
        schema: SchemaRef,
        segments: Arc<[(usize, String)]>,
    ) -> Self {
        Self {
            dataset,
            index,
            schema,
            segments,
        }
    }

    fn time_filter(&self, filter: &Expr) -> Option<TimeFilter> {
        pushdown::time_filter(filter, self.index.name(), self.index.time_type())
    }
}

#[async_trait]
impl TableProvider for DatasetTimelineTable {
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
            .map(|filter| {
                if segment_filter(filter, &self.segments).is_some() {
                    TableProviderFilterPushDown::Exact
                } else {
                    pushdown::support(self.time_filter(filter).map(|f| f.exact))
                }
            })
            .collect())
    }

    async fn scan(
        &self,
        state: &dyn Session,
        projection: Option<&Vec<usize>>,
        filters: &[Expr],
        limit: Option<usize>,
    ) -> Result<Arc<dyn ExecutionPlan>> {
        let index = self.index.name();
        let mut pushed_down = Vec::new();
        let (mut kept, by_id) = kept_segments(filters, &self.segments);
        let with_index = kept.len();
        kept.retain(|&n| self.dataset.segments()[n].time_range(index).is_some());
        let without_index = with_index - kept.len();
        let mut query = DataframeQuery::new(Arc::clone(self.index.name_arc()));
        let range = filters
            .iter()
            .filter_map(|filter| self.time_filter(filter))
            .map(|filter| filter.range)
            .reduce(pushdown::intersect);
        let before = kept.len();
        if let Some(range) = range {
            query = query.with_range(range);
            kept.retain(|&n| {
                self.dataset.segments()[n]
                    .time_range(index)
                    .is_some_and(|span| span.intersects(range))
            });
        }
        let mut pruned = pruned_by_id(by_id);
        if without_index > 0 {
            pruned.push(format!("{without_index} without {index}"));
        }
        if let Some(range) = range {
            pruned.push(format!(
                "{} outside {}",
                before - kept.len(),
                pushdown::describe(index, range)
            ));
        }
        pushed_down.push(segments_line(kept.len(), self.segments.len(), &pruned));
        if let Some(range) = range {
            pushed_down.push(pushdown::describe(index, range));
        }
        let projected = stream_projection(&self.schema, projection, &mut pushed_down)?;
        if let Some(rows) = limit {
            pushed_down.push(format!("limit={rows}"));
            query = query.with_batch_rows(rows.clamp(1, 4_096));
        }
        // Batches wait in queues ahead of DataFusion (a few per partition): their size
        // follows the memory budget, a sixteenth of it (at 32 MB each, the default, a
        // scan of images held 180 MB of batches under a 64 MiB budget).
        let budget = usize::try_from(self.dataset.options().memory_budget).unwrap_or(usize::MAX);
        let query = query
            .with_columns(projected.names.iter().cloned())
            .with_batch_bytes((budget / 16).clamp(1 << 20, crate::DEFAULT_BATCH_BYTES));
        let kept: Vec<usize> = kept.into_iter().collect();
        let partitions = if limit.is_some() {
            1
        } else {
            state.config().target_partitions()
        };
        let groups = groups_by_bytes(&self.dataset, &kept, partitions);
        // Each partition's rows are by segment id, then (where it is there) the index; nothing
        // is said when the segment id is projected away.
        let ordering = ascending_on(&projected.output, &[SEGMENT_ID_COLUMN, index]);
        Ok(Arc::new(DatasetScanExec::new(
            self.dataset.clone(),
            index.to_owned(),
            DatasetSource::Dataframe { groups, query },
            pushed_down,
            limit,
            projected,
            ordering,
        )))
    }
}

/// `numbers` in at most `partitions` consecutive groups of about equal bytes (never an
/// empty group; one empty group for no segment).
fn groups_by_bytes(dataset: &Dataset, numbers: &[usize], partitions: usize) -> Vec<Vec<usize>> {
    let parts = partitions.clamp(1, numbers.len().max(1));
    let bytes = |n: usize| dataset.segments()[n].file_bytes.max(1);
    let total: u64 = numbers.iter().map(|&n| bytes(n)).sum();
    let mut groups: Vec<Vec<usize>> = vec![Vec::new(); parts];
    let mut before = 0u64;
    for &n in numbers {
        let part = usize::try_from(u128::from(before) * parts as u128 / u128::from(total.max(1)))
            .unwrap_or(parts - 1)
            .min(parts - 1);
        groups[part].push(n);
        before += bytes(n);
    }
    groups.retain(|g| !g.is_empty());
    if groups.is_empty() {
        groups.push(Vec::new());
    }
    groups
}

/// Every stored row of every segment (each segment's chunk table,
/// `StoreView::chunk_table`), the segment id first, as a DataFusion table: the chunk, row
/// and entity columns, every timeline, every component by name.
#[derive(Debug, Clone)]
pub struct DatasetChunksTable {
    dataset: Dataset,
    schema: SchemaRef,
    segments: Arc<[(usize, String)]>,
    /// The filters on entity paths and times.
    filters: ChunkRowFilters,
}

impl DatasetChunksTable {
    pub(super) fn new(
        dataset: Dataset,
        schema: SchemaRef,
        segments: Arc<[(usize, String)]>,
    ) -> Self {
        let filters = ChunkRowFilters::new(dataset.entity_paths(), dataset.timelines());
        Self {
            dataset,
            schema,
            segments,
            filters,
        }
    }
}

#[async_trait]
impl TableProvider for DatasetChunksTable {
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
            .map(|filter| {
                if segment_filter(filter, &self.segments).is_some() {
                    TableProviderFilterPushDown::Exact
                } else {
                    self.filters.support(filter)
                }
            })
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
        let (kept, by_id) = kept_segments(filters, &self.segments);
        pushed_down.push(segments_line(
            kept.len(),
            self.segments.len(),
            &pruned_by_id(by_id),
        ));
        let PickedRows {
            mut query,
            entities,
            overlapping,
        } = self
            .filters
            .apply(filters, ChunkTableQuery::new(), &mut pushed_down);
        let projected = stream_projection(&self.schema, projection, &mut pushed_down)?;
        if let Some(rows) = limit {
            pushed_down.push(format!("limit={rows}"));
            query = query.with_batch_rows(rows.clamp(1, 4_096));
        }
        let picks = ChunkPicks {
            entities,
            overlapping: overlapping.map(|(t, range)| (t.name().to_owned(), range)),
        };
        Ok(Arc::new(DatasetScanExec::new(
            self.dataset.clone(),
            CHUNKS_TABLE.to_owned(),
            DatasetSource::Chunks {
                segments: kept.into_iter().collect(),
                query,
                columns: projected.names.clone(),
                picks,
            },
            pushed_down,
            limit,
            projected,
            EquivalenceProperties::new(Arc::clone(&self.schema)),
        )))
    }
}
