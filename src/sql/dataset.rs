//! A dataset's tables for DataFusion ([`register_dataset`]): one table per timeline (the
//! dataset's dataframe on it, SEMANTICS.md section 15) and `chunks`, each with
//! [`SEGMENT_ID_COLUMN`] first, read segment by segment in bounded memory.
//!
//! What a query's filters say is applied before any file is read: a filter on
//! `rerun_segment_id` (`=`, `IN`, `LIKE`, `starts_with`) keeps only the segments it names;
//! a filter on a timeline table's index keeps only the segments whose span there overlaps
//! it, and in those only the chunks whose manifest entries the range needs (`prune.rs`);
//! on `chunks`, a filter on `entity_path` or a timeline reads only the chunks of those
//! entities or overlapping that range. `EXPLAIN` shows the segments and chunks left;
//! `EXPLAIN ANALYZE` what was read.

use std::collections::BTreeSet;
use std::fmt;
use std::sync::{Arc, OnceLock};

use arrow_array::RecordBatch;
use arrow_schema::{ArrowError, SchemaRef, SortOptions};
use async_trait::async_trait;
use datafusion::catalog::{Session, TableFunctionArgs, TableFunctionImpl};
use datafusion::common::{DataFusionError, Result};
use datafusion::datasource::{TableProvider, TableType};
use datafusion::execution::TaskContext;
use datafusion::logical_expr::{Expr, TableProviderFilterPushDown};
use datafusion::physical_expr::expressions::Column;
use datafusion::physical_expr::{EquivalenceProperties, PhysicalSortExpr};
use datafusion::physical_plan::execution_plan::{Boundedness, EmissionType};
use datafusion::physical_plan::metrics::{
    Count, ExecutionPlanMetricsSet, MetricBuilder, MetricsSet,
};
use datafusion::physical_plan::stream::RecordBatchStreamAdapter;
use datafusion::physical_plan::{
    DisplayAs, DisplayFormatType, ExecutionPlan, Partitioning, PlanProperties,
    SendableRecordBatchStream,
};
use datafusion::prelude::SessionContext;

use super::pushdown::{self, TimeFilter};
use super::read_ahead::{READ_AHEAD_BYTES, ReadAhead};
use super::scan::Limited;
use super::tables::ENTITY_PATH;
use super::{CHUNKS_TABLE, replace_table};
use crate::dataset::{Dataset, DatasetStream, ReadStats};
use crate::{ChunkTableQuery, DataframeQuery, EntityPath, SEGMENT_ID_COLUMN, TimeRange, Timeline};

fn external(error: impl std::error::Error + Send + Sync + 'static) -> DataFusionError {
    DataFusionError::External(Box::new(error))
}

/// Registers the tables of `dataset` in `ctx` (see the module docs), replacing tables of
/// the same names: one per timeline of any segment, and `chunks` (`__chunks` if a timeline
/// is named `chunks`). Returns the table names, timelines first (sorted). Planning the
/// tables' columns reads one chunk of each (entity, component, timeline) of the segments
/// that add a column ([`Dataset::tables`]); no rows are read until a query runs.
///
/// `latest_at(...)` reads one recording, so over a dataset it is an error that says so.
///
/// # Errors
/// The dataset's, should its tables not plan (a column of two types in two segments, a
/// segment that cannot be read); DataFusion's, should the context refuse a table.
pub fn register_dataset(ctx: &SessionContext, dataset: &Dataset) -> Result<Vec<String>> {
    let tables = dataset.tables().map_err(external)?;
    let segments: Arc<[(usize, String)]> = dataset
        .segments()
        .iter()
        .enumerate()
        .map(|(number, segment)| (number, segment.id.clone()))
        .collect();
    let mut names = Vec::new();
    for (timeline, schema) in &tables.timelines {
        let Some(time_type) = dataset.time_type(timeline) else {
            continue;
        };
        let table = DatasetTimelineTable {
            dataset: dataset.clone(),
            index: Timeline::new(timeline.as_str(), time_type),
            schema: Arc::clone(schema),
            segments: Arc::clone(&segments),
        };
        replace_table(ctx, timeline, Arc::new(table))?;
        names.push(timeline.clone());
    }
    let chunks_name = if tables.timelines.contains_key(CHUNKS_TABLE) {
        format!("__{CHUNKS_TABLE}")
    } else {
        CHUNKS_TABLE.to_owned()
    };
    let table = DatasetChunksTable {
        dataset: dataset.clone(),
        schema: Arc::clone(&tables.chunks),
        segments,
        entities: dataset
            .entity_paths()
            .into_iter()
            .map(|path| {
                let text = path.to_string();
                (path, text)
            })
            .collect(),
        timelines: dataset.timelines(),
    };
    replace_table(ctx, &chunks_name, Arc::new(table))?;
    names.push(chunks_name);
    ctx.register_udtf("latest_at", Arc::new(DatasetLatestAt));
    super::register_expr_planners(ctx)?;
    Ok(names)
}

/// The segments (among `segments`) that `filters` on [`SEGMENT_ID_COLUMN`] keep, all of
/// them where no filter is on it; and how many the filters dropped.
fn kept_segments(filters: &[Expr], segments: &[(usize, String)]) -> (BTreeSet<usize>, usize) {
    let mut kept: BTreeSet<usize> = segments.iter().map(|(n, _)| *n).collect();
    for filter in filters {
        if let Some(named) = pushdown::text_filter(filter, SEGMENT_ID_COLUMN, segments) {
            kept = kept.intersection(&named).copied().collect();
        }
    }
    let dropped = segments.len() - kept.len();
    (kept, dropped)
}

/// A projection of a dataset table, as its scan reads it.
struct Projected {
    /// The schema the dataset's stream gives: the segment id and the projected columns,
    /// in the table's order.
    stream: SchemaRef,
    /// The scan's output.
    output: SchemaRef,
    /// The stream's data columns.
    names: Vec<String>,
    /// Where each output column is in the stream's batches (`None` when they are the
    /// output).
    positions: Option<Vec<usize>>,
}

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
                if pushdown::text_filter(filter, SEGMENT_ID_COLUMN, &self.segments).is_some() {
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
        let mut pruned = Vec::new();
        if by_id > 0 {
            pruned.push(format!("{by_id} by {SEGMENT_ID_COLUMN}"));
        }
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
        pushed_down.push(format!(
            "segments={} of {}{}",
            kept.len(),
            self.segments.len(),
            if pruned.is_empty() {
                String::new()
            } else {
                format!(" (pruned: {})", pruned.join(", "))
            }
        ));
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
        let ordering = ordering_of(&projected.output, index);
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

/// The order each partition's rows are in: by segment id, then (when it is there) the
/// index; nothing is said when the segment id is projected away.
fn ordering_of(schema: &SchemaRef, index: &str) -> EquivalenceProperties {
    let mut ordered = EquivalenceProperties::new(Arc::clone(schema));
    let Ok(segment) = schema.index_of(SEGMENT_ID_COLUMN) else {
        return ordered;
    };
    let index = schema.index_of(index).ok();
    // Neither column has nulls, so every null placement holds.
    for segment_nulls_first in [false, true] {
        for index_nulls_first in [false, true] {
            let sort = |name: &str, position: usize, nulls_first: bool| {
                PhysicalSortExpr::new(
                    Arc::new(Column::new(name, position)),
                    SortOptions {
                        descending: false,
                        nulls_first,
                    },
                )
            };
            let mut exprs = vec![sort(SEGMENT_ID_COLUMN, segment, segment_nulls_first)];
            if let Some(position) = index {
                exprs.push(sort(
                    schema.field(position).name(),
                    position,
                    index_nulls_first,
                ));
            }
            ordered.add_ordering(exprs);
        }
    }
    ordered
}

/// Every stored row of every segment (each segment's chunk table,
/// `StoreView::chunk_table`), the segment id first, as a DataFusion table: the chunk, row
/// and entity columns, every timeline, every component by name.
#[derive(Debug, Clone)]
pub struct DatasetChunksTable {
    dataset: Dataset,
    schema: SchemaRef,
    segments: Arc<[(usize, String)]>,
    /// Every entity path of any segment, with its text as `entity_path` shows it.
    entities: Vec<(EntityPath, String)>,
    timelines: Vec<Timeline>,
}

impl DatasetChunksTable {
    fn time_filter(&self, filter: &Expr) -> Option<(&Timeline, TimeFilter)> {
        pushdown::timeline_filter(filter, &self.timelines)
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
                let exact = pushdown::text_filter(filter, SEGMENT_ID_COLUMN, &self.segments)
                    .is_some()
                    || pushdown::text_filter(filter, ENTITY_PATH, &self.entities).is_some();
                if exact {
                    TableProviderFilterPushDown::Exact
                } else if self.time_filter(filter).is_some() {
                    TableProviderFilterPushDown::Inexact
                } else {
                    TableProviderFilterPushDown::Unsupported
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
        pushed_down.push(format!(
            "segments={} of {}{}",
            kept.len(),
            self.segments.len(),
            if by_id > 0 {
                format!(" (pruned: {by_id} by {SEGMENT_ID_COLUMN})")
            } else {
                String::new()
            }
        ));
        let mut query = ChunkTableQuery::new();
        let entities = filters
            .iter()
            .filter_map(|filter| pushdown::text_filter(filter, ENTITY_PATH, &self.entities))
            .reduce(|a, b| a.intersection(&b).cloned().collect());
        if let Some(entities) = &entities {
            pushed_down.push(format!(
                "entities={} of {}",
                entities.len(),
                self.entities.len()
            ));
            query = query.with_row_entities(entities.iter().cloned());
        }
        let overlapping = pushdown::chunks_overlapping(filters, &self.timelines);
        if let Some((timeline, range)) = overlapping {
            pushed_down.push(format!(
                "chunks overlapping {}",
                pushdown::describe(timeline.name(), range)
            ));
            query = query.with_rows_overlapping(Arc::clone(timeline.name_arc()), range);
        }
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

/// Which chunks of a segment a chunk table scan reads: of these entities (all where
/// `None`), and overlapping this range (any where `None`).
#[derive(Clone, Debug)]
struct ChunkPicks {
    entities: Option<BTreeSet<EntityPath>>,
    overlapping: Option<(String, TimeRange)>,
}

impl ChunkPicks {
    fn keeps(&self, entry: &crate::rrd::ManifestEntry) -> bool {
        let entity = self
            .entities
            .as_ref()
            .is_none_or(|entities| entities.contains(&entry.entity_path));
        let overlaps = self.overlapping.as_ref().is_none_or(|(timeline, range)| {
            entry.ranges.iter().any(|r| {
                r.timeline.name() == timeline && TimeRange::new(r.min, r.max).intersects(*range)
            })
        });
        entity && overlaps
    }
}

/// What a dataset scan reads.
#[derive(Clone, Debug)]
enum DatasetSource {
    /// A timeline table: each group of segments (a partition) streamed in order, each
    /// segment with `query`.
    Dataframe {
        groups: Vec<Vec<usize>>,
        query: DataframeQuery,
    },
    /// The chunk table: these segments' chunk tables, one after another, each of what
    /// `picks` picks of it, with `query` and the `columns` it has.
    Chunks {
        segments: Vec<usize>,
        query: ChunkTableQuery,
        columns: Vec<String>,
        picks: ChunkPicks,
    },
}

/// Reads a dataset's table ([`register_dataset`]) segment by segment, each partition on a
/// thread of its own. `EXPLAIN` shows what was pushed down and how many segments and
/// chunks are left to read; `EXPLAIN ANALYZE` also shows `segments_read`,
/// `chunks_decoded` and `bytes_read` (what was read from the files) and `rows_built`.
#[derive(Debug)]
pub struct DatasetScanExec {
    dataset: Dataset,
    table: String,
    source: DatasetSource,
    pushed_down: Vec<String>,
    limit: Option<usize>,
    /// The schema the dataset's stream gives.
    stream_schema: SchemaRef,
    /// Where each output column is in the stream's batches (`None`: they are the output).
    positions: Option<Vec<usize>>,
    schema: SchemaRef,
    properties: Arc<PlanProperties>,
    metrics: ExecutionPlanMetricsSet,
    /// The chunks left to read, counted from the footers when `EXPLAIN` first asks.
    chunks_left: OnceLock<String>,
}

impl DatasetScanExec {
    fn new(
        dataset: Dataset,
        table: String,
        source: DatasetSource,
        pushed_down: Vec<String>,
        limit: Option<usize>,
        projected: Projected,
        ordering: EquivalenceProperties,
    ) -> Self {
        let Projected {
            stream: stream_schema,
            output: schema,
            positions,
            ..
        } = projected;
        let partitions = match &source {
            DatasetSource::Dataframe { groups, .. } => groups.len(),
            DatasetSource::Chunks { .. } => 1,
        };
        let ordering = if ordering.schema().fields() == schema.fields() {
            ordering
        } else {
            EquivalenceProperties::new(Arc::clone(&schema))
        };
        let properties = PlanProperties::new(
            ordering,
            Partitioning::UnknownPartitioning(partitions),
            EmissionType::Incremental,
            Boundedness::Bounded,
        );
        Self {
            dataset,
            table,
            source,
            pushed_down,
            limit,
            stream_schema,
            positions,
            schema,
            properties: Arc::new(properties),
            metrics: ExecutionPlanMetricsSet::new(),
            chunks_left: OnceLock::new(),
        }
    }

    /// What the scan applies itself (segments, a range, entities, columns, a limit), as
    /// `EXPLAIN` prints it, with the chunks left to read (counted from the footers).
    pub fn pushed_down(&self) -> Vec<String> {
        let mut lines = self.pushed_down.clone();
        lines.push(self.chunks_left().to_owned());
        lines
    }

    fn chunks_left(&self) -> &str {
        self.chunks_left.get_or_init(|| {
            let total: u64 = self.dataset.segments().iter().map(|s| s.num_chunks).sum();
            let left = match &self.source {
                DatasetSource::Dataframe { groups, query } => {
                    let numbers: Vec<usize> = groups.iter().flatten().copied().collect();
                    self.dataset
                        .chunks_for_rows(&numbers, query)
                        .map_err(|e| e.to_string())
                }
                DatasetSource::Chunks {
                    segments, picks, ..
                } => self
                    .dataset
                    .chunks_picked(segments, |entry| picks.keeps(entry))
                    .map_err(|e| e.to_string()),
            };
            match left {
                Ok(left) => format!("chunks={left} of {total}"),
                Err(error) => format!("chunks=? of {total} ({error})"),
            }
        })
    }

    /// The batches `make` makes, read on a thread of their own, a bounded queue ahead of
    /// DataFusion's; with a limit, on the reader's thread, so that no segment past the
    /// limit's rows is read.
    fn read_ahead<I>(
        &self,
        make: impl FnOnce() -> I + Send + 'static,
    ) -> Result<Box<dyn Iterator<Item = Result<RecordBatch, ArrowError>> + Send>>
    where
        I: Iterator<Item = Result<RecordBatch, ArrowError>> + Send + 'static,
    {
        if self.limit.is_some() {
            return Ok(Box::new(make()));
        }
        // The queues count against the dataset's memory budget: together at most a
        // quarter of it (a part's first batch is always taken). At 64 MiB queues of their
        // own, two partitions held four 32 MB batches of images ahead under a 64 MiB budget.
        let budget = usize::try_from(self.dataset.options().memory_budget).unwrap_or(usize::MAX);
        let queue_bytes = READ_AHEAD_BYTES.min(budget / 4 / self.num_partitions().max(1));
        let part = ReadAhead::spawn(make, queue_bytes)
            .map_err(|e| DataFusionError::Execution(format!("starting a scan thread: {e}")))?;
        Ok(Box::new(part))
    }

    /// The partitions (groups of segments, each read in order).
    fn num_partitions(&self) -> usize {
        self.properties.partitioning.partition_count()
    }
}

impl DisplayAs for DatasetScanExec {
    fn fmt_as(&self, t: DisplayFormatType, f: &mut fmt::Formatter) -> fmt::Result {
        let partitions = self.num_partitions();
        match t {
            DisplayFormatType::Default | DisplayFormatType::Verbose => {
                write!(f, "DatasetScanExec: table={}", self.table)?;
                for pushed in self.pushed_down() {
                    write!(f, ", {pushed}")?;
                }
                write!(f, ", partitions={partitions}")
            }
            DisplayFormatType::TreeRender => {
                writeln!(f, "table={}", self.table)?;
                for pushed in self.pushed_down() {
                    writeln!(f, "{pushed}")?;
                }
                writeln!(f, "partitions={partitions}")
            }
        }
    }
}

/// The metrics of what a partition read from the files.
#[derive(Clone)]
struct ReadMetrics {
    segments: Count,
    chunks: Count,
    bytes: Count,
}

impl ReadMetrics {
    fn add(&self, read: ReadStats) {
        self.segments
            .add(usize::try_from(read.segment_reads).unwrap_or(usize::MAX));
        self.chunks
            .add(usize::try_from(read.chunks_decoded).unwrap_or(usize::MAX));
        self.bytes
            .add(usize::try_from(read.bytes_read).unwrap_or(usize::MAX));
    }
}

/// A dataset stream that reports what it read as it goes.
struct CountedStream {
    stream: DatasetStream,
    reported: ReadStats,
    metrics: ReadMetrics,
}

impl Iterator for CountedStream {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        let next = self.stream.next();
        let now = self.stream.read_stats();
        self.metrics.add(ReadStats {
            segment_reads: now.segment_reads - self.reported.segment_reads,
            chunks_decoded: now.chunks_decoded - self.reported.chunks_decoded,
            bytes_read: now.bytes_read - self.reported.bytes_read,
        });
        self.reported = now;
        next
    }
}

/// The chunk tables of segments one after another, each in the table's schema.
struct ChunkRows {
    dataset: Dataset,
    schema: SchemaRef,
    segments: std::vec::IntoIter<usize>,
    query: ChunkTableQuery,
    columns: Vec<String>,
    picks: ChunkPicks,
    current: Option<crate::dataset::Placed<crate::ChunkTableStream>>,
    metrics: ReadMetrics,
}

impl ChunkRows {
    /// The next segment's chunk table; `Ok(false)` when there is none.
    fn start_next(&mut self) -> Result<bool, ArrowError> {
        let Some(number) = self.segments.next() else {
            return Ok(false);
        };
        let failed = |error: String| ArrowError::ExternalError(error.into());
        let picks = &self.picks;
        let (snapshot, read) = self
            .dataset
            .segment_chunks(number, |manifest| {
                manifest
                    .entries
                    .iter()
                    .filter(|entry| picks.keeps(entry))
                    .map(|entry| entry.chunk_id)
                    .collect()
            })
            .map_err(|e| failed(e.to_string()))?;
        self.metrics.add(read);
        // Of the table's columns, those this segment's chunk table has.
        let own = snapshot
            .chunk_table(&ChunkTableQuery::new().with_row_entities([]))
            .map_err(|e| failed(e.to_string()))?
            .schema();
        let present: Vec<&String> = self
            .columns
            .iter()
            .filter(|name| own.field_with_name(name).is_ok())
            .collect();
        let stream = snapshot
            .chunk_table(&self.query.clone().with_columns(present))
            .map_err(|e| failed(e.to_string()))?;
        let id = self.dataset.segments()[number].id.as_str().into();
        self.current = Some(crate::dataset::Placed::new(
            stream,
            Arc::clone(&self.schema),
            id,
        ));
        Ok(true)
    }
}

impl Iterator for ChunkRows {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(placed) = &mut self.current {
                match placed.next() {
                    Some(batch) => return Some(batch),
                    None => self.current = None,
                }
            }
            match self.start_next() {
                Ok(true) => {}
                Ok(false) => return None,
                Err(error) => return Some(Err(error)),
            }
        }
    }
}

impl ExecutionPlan for DatasetScanExec {
    fn name(&self) -> &'static str {
        "DatasetScanExec"
    }

    fn properties(&self) -> &Arc<PlanProperties> {
        &self.properties
    }

    fn children(&self) -> Vec<&Arc<dyn ExecutionPlan>> {
        Vec::new()
    }

    fn with_new_children(
        self: Arc<Self>,
        children: Vec<Arc<dyn ExecutionPlan>>,
    ) -> Result<Arc<dyn ExecutionPlan>> {
        if children.is_empty() {
            Ok(self)
        } else {
            Err(DataFusionError::Internal(
                "DatasetScanExec has no children".to_owned(),
            ))
        }
    }

    fn execute(
        &self,
        partition: usize,
        _context: Arc<TaskContext>,
    ) -> Result<SendableRecordBatchStream> {
        if partition >= self.num_partitions() {
            return Err(DataFusionError::Internal(format!(
                "DatasetScanExec has {} partitions, not {}",
                self.num_partitions(),
                partition + 1
            )));
        }
        let metrics = ReadMetrics {
            segments: MetricBuilder::new(&self.metrics).counter("segments_read", partition),
            chunks: MetricBuilder::new(&self.metrics).counter("chunks_decoded", partition),
            bytes: MetricBuilder::new(&self.metrics).counter("bytes_read", partition),
        };
        let rows_built = MetricBuilder::new(&self.metrics).counter("rows_built", partition);
        let dataset = self.dataset.clone();
        let stream_schema = Arc::clone(&self.stream_schema);
        let batches: Box<dyn Iterator<Item = Result<RecordBatch, ArrowError>> + Send> =
            match &self.source {
                DatasetSource::Dataframe { groups, query } => {
                    let segments: Vec<_> = groups[partition]
                        .iter()
                        .map(|&n| (n, query.clone(), None))
                        .collect();
                    // One partition alone loads ahead on the dataset's threads; a limit
                    // wants no segment past its rows read.
                    let threads = if groups.len() == 1 && self.limit.is_none() {
                        dataset.options().threads
                    } else {
                        1
                    };
                    let counted = move || CountedStream {
                        stream: dataset.stream_segments(stream_schema, segments, threads),
                        reported: ReadStats::default(),
                        metrics,
                    };
                    self.read_ahead(counted)?
                }
                DatasetSource::Chunks {
                    segments,
                    query,
                    columns,
                    picks,
                } => {
                    let rows = ChunkRows {
                        dataset,
                        schema: stream_schema,
                        segments: segments.clone().into_iter(),
                        query: query.clone(),
                        columns: columns.clone(),
                        picks: picks.clone(),
                        current: None,
                        metrics,
                    };
                    self.read_ahead(move || rows)?
                }
            };
        let positions = self.positions.clone();
        let projected = batches.map(
            move |batch: Result<RecordBatch, ArrowError>| match &positions {
                Some(columns) => batch?.project(columns),
                None => batch,
            },
        );
        let schema = Arc::clone(&self.schema);
        let limited = Limited::new(Box::new(projected), self.limit, rows_built)
            .map(move |batch| Ok(batch?.with_schema(Arc::clone(&schema))?));
        Ok(Box::pin(RecordBatchStreamAdapter::new(
            Arc::clone(&self.schema),
            futures::stream::iter(limited),
        )))
    }

    fn metrics(&self) -> Option<MetricsSet> {
        Some(self.metrics.clone_inner())
    }
}

/// `latest_at(...)` over a dataset: an error saying what answers it instead.
#[derive(Debug)]
struct DatasetLatestAt;

impl TableFunctionImpl for DatasetLatestAt {
    fn call_with_args(&self, _args: TableFunctionArgs) -> Result<Arc<dyn TableProvider>> {
        Err(super::latest_at::plan_error(
            "reads one recording, not a dataset: `latest-at --segment ID` reads one \
             segment's, and a timeline table filtered on rerun_segment_id its rows",
        ))
    }
}
