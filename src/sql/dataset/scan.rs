//! [`DatasetScanExec`]: the execution plan that reads a dataset's table segment by segment,
//! each partition on a thread of its own, with what its table's filters kept and the
//! metrics of what it read from the files.

use std::collections::BTreeSet;
use std::fmt;
use std::sync::{Arc, OnceLock};

use arrow_array::RecordBatch;
use arrow_schema::{ArrowError, SchemaRef};
use datafusion::common::{DataFusionError, Result};
use datafusion::execution::TaskContext;
use datafusion::physical_expr::EquivalenceProperties;
use datafusion::physical_plan::execution_plan::{Boundedness, EmissionType};
use datafusion::physical_plan::metrics::{
    Count, ExecutionPlanMetricsSet, MetricBuilder, MetricsSet,
};
use datafusion::physical_plan::stream::RecordBatchStreamAdapter;
use datafusion::physical_plan::{
    DisplayAs, DisplayFormatType, ExecutionPlan, Partitioning, PlanProperties,
    SendableRecordBatchStream,
};

use crate::dataset::{Dataset, DatasetStream, ReadStats};
use crate::sql::read_ahead::{READ_AHEAD_BYTES, ReadAhead};
use crate::sql::scan::Limited;
use crate::{ChunkTableQuery, DataframeQuery, EntityPath, TimeRange};

/// A projection of a dataset table, as its scan reads it.
pub(super) struct Projected {
    /// The schema the dataset's stream gives: the segment id and the projected columns,
    /// in the table's order.
    pub(super) stream: SchemaRef,
    /// The scan's output.
    pub(super) output: SchemaRef,
    /// The stream's data columns.
    pub(super) names: Vec<String>,
    /// Where each output column is in the stream's batches (`None` when they are the
    /// output).
    pub(super) positions: Option<Vec<usize>>,
}

/// Which chunks of a segment a chunk table scan reads: of these entities (all where
/// `None`), and overlapping this range (any where `None`).
#[derive(Clone, Debug)]
pub(super) struct ChunkPicks {
    pub(super) entities: Option<BTreeSet<EntityPath>>,
    pub(super) overlapping: Option<(String, TimeRange)>,
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
pub(super) enum DatasetSource {
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

/// Reads a dataset's table ([`register_dataset`](super::register_dataset)) segment by
/// segment, each partition on a thread of its own. `EXPLAIN` shows what was pushed down
/// and how many segments and chunks are left to read; `EXPLAIN ANALYZE` also shows
/// `segments_read`, `chunks_decoded` and `bytes_read` (what was read from the files),
/// `requests` and `bytes_fetched` (the GETs of segments in an object store, and what they
/// brought) and `rows_built`.
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
    pub(super) fn new(
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
    requests: Count,
    bytes_fetched: Count,
}

impl ReadMetrics {
    fn new(metrics: &ExecutionPlanMetricsSet, partition: usize) -> Self {
        let counter = |name| MetricBuilder::new(metrics).counter(name, partition);
        Self {
            segments: counter("segments_read"),
            chunks: counter("chunks_decoded"),
            bytes: counter("bytes_read"),
            requests: counter("requests"),
            bytes_fetched: counter("bytes_fetched"),
        }
    }

    fn add(&self, read: ReadStats) {
        let add = |count: &Count, n: u64| count.add(usize::try_from(n).unwrap_or(usize::MAX));
        add(&self.segments, read.segment_reads);
        add(&self.chunks, read.chunks_decoded);
        add(&self.bytes, read.bytes_read);
        add(&self.requests, read.requests);
        add(&self.bytes_fetched, read.bytes_fetched);
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
        self.metrics.add(now.since(&self.reported));
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
        crate::sql::scan::leaf_with_new_children(self, &children)
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
        let metrics = ReadMetrics::new(&self.metrics, partition);
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
                        dataset.read_threads()
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
