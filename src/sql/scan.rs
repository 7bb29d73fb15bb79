//! [`StoreScanExec`]: the execution plan that reads one of the store's tables from a
//! snapshot, with what was pushed down to it (a time range, entities, columns, a limit).

use std::fmt;
use std::sync::Arc;

use arrow_array::RecordBatch;
use arrow_schema::{ArrowError, SchemaRef, SortOptions};
use datafusion::common::{DataFusionError, Result};
use datafusion::execution::TaskContext;
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

use super::read_ahead::{READ_AHEAD_BYTES, ReadAhead};
use crate::{ChunkTableQuery, DataframeQuery, Snapshot};

/// What a scan reads.
#[derive(Clone, Debug)]
pub(crate) enum ScanSource {
    /// A dataframe view, in consecutive index ranges read in order (never empty): the
    /// first built on the reader's thread, each other on a thread of its own
    /// ([`ReadAhead`]). Each query holds its range and the columns (which it builds in the
    /// view's order; `projection` puts them in the order asked for).
    Dataframe {
        queries: Vec<DataframeQuery>,
        projection: Option<Vec<usize>>,
    },
    /// The chunk table: its query holds the row filters and the columns (built in the
    /// table's order; `projection` puts them in the order asked for).
    Chunks {
        query: ChunkTableQuery,
        projection: Option<Vec<usize>>,
    },
}

/// Reads one of the store's tables ([`super::register`]) from a snapshot, as one
/// partition (a timeline table's index range may be built in parts side by side, read in
/// order). `EXPLAIN` shows what was pushed down to it; `EXPLAIN ANALYZE` also shows
/// `chunks_read`, the chunks the store read to answer (the store's own count, summed over
/// the parts: a chunk straddling two parts is read by both), and `rows_built`, the rows
/// the store built before any `LIMIT` cut them.
#[derive(Debug)]
pub struct StoreScanExec {
    snapshot: Snapshot,
    table: String,
    source: ScanSource,
    /// What the scan applies itself, for `EXPLAIN`.
    pushed_down: Vec<String>,
    limit: Option<usize>,
    schema: SchemaRef,
    properties: Arc<PlanProperties>,
    metrics: ExecutionPlanMetricsSet,
}

impl StoreScanExec {
    pub(crate) fn new(
        snapshot: Snapshot,
        table: String,
        source: ScanSource,
        pushed_down: Vec<String>,
        limit: Option<usize>,
        schema: SchemaRef,
    ) -> Self {
        let properties = plan_properties(EquivalenceProperties::new(Arc::clone(&schema)));
        Self {
            snapshot,
            table,
            source,
            pushed_down,
            limit,
            schema,
            properties: Arc::new(properties),
            metrics: ExecutionPlanMetricsSet::new(),
        }
    }

    /// Declares the scan's rows ascending on `column` (a timeline view's index: one row
    /// per distinct time, in order), so that DataFusion needs no sort for `ORDER BY` it.
    /// Nothing changes when the projection left the column out.
    pub(crate) fn sorted_by(mut self, column: &str) -> Self {
        self.properties = Arc::new(plan_properties(ascending_on(&self.schema, &[column])));
        self
    }

    /// What the scan applies itself (a range, entities, columns, a limit), as `EXPLAIN`
    /// prints it.
    pub fn pushed_down(&self) -> &[String] {
        &self.pushed_down
    }
}

/// What is known of the order of rows in `schema` sorted ascending by `columns` in turn:
/// by as many of them, from the first, as the schema has (nothing when it lacks the
/// first, as when a projection left it out). None of these columns has nulls, so every
/// null placement holds and each is declared (SQL's `ORDER BY x` means `NULLS LAST` in
/// DataFusion, `NULLS FIRST` with `DESC`...).
pub(crate) fn ascending_on(schema: &SchemaRef, columns: &[&str]) -> EquivalenceProperties {
    let mut ordered = EquivalenceProperties::new(Arc::clone(schema));
    let sorted: Vec<(&str, usize)> = columns
        .iter()
        .map_while(|&name| Some((name, schema.index_of(name).ok()?)))
        .collect();
    if sorted.is_empty() {
        return ordered;
    }
    // Column `i`'s nulls are first where bit `n - 1 - i` of `placement` is set: the
    // orderings go in the order of their first column's placement, then the next's. The
    // order matters to DataFusion 54's equivalence classes: with the last column's varying
    // slowest instead, a sort on (segment id, index) was planned again
    // (`a_dataset_timeline_table_is_the_dataset_dataframe` checks).
    let n = sorted.len();
    for placement in 0u32..1 << n {
        ordered.add_ordering(sorted.iter().enumerate().map(|(i, &(name, position))| {
            PhysicalSortExpr::new(
                Arc::new(Column::new(name, position)),
                SortOptions {
                    descending: false,
                    nulls_first: placement & (1 << (n - 1 - i)) != 0,
                },
            )
        }));
    }
    ordered
}

/// `ExecutionPlan::with_new_children` of a scan, which has no children: the plan itself,
/// or an internal error should DataFusion hand it some.
pub(crate) fn leaf_with_new_children(
    plan: Arc<dyn ExecutionPlan>,
    children: &[Arc<dyn ExecutionPlan>],
) -> Result<Arc<dyn ExecutionPlan>> {
    if children.is_empty() {
        Ok(plan)
    } else {
        Err(DataFusionError::Internal(format!(
            "{} has no children",
            plan.name()
        )))
    }
}

/// One partition, emitted batch by batch, bounded; `ordered` says what is known of the
/// rows' order.
fn plan_properties(ordered: EquivalenceProperties) -> PlanProperties {
    PlanProperties::new(
        ordered,
        Partitioning::UnknownPartitioning(1),
        EmissionType::Incremental,
        Boundedness::Bounded,
    )
}

impl DisplayAs for StoreScanExec {
    fn fmt_as(&self, t: DisplayFormatType, f: &mut fmt::Formatter) -> fmt::Result {
        match t {
            DisplayFormatType::Default | DisplayFormatType::Verbose => {
                write!(f, "StoreScanExec: table={}", self.table)?;
                for pushed in &self.pushed_down {
                    write!(f, ", {pushed}")?;
                }
                Ok(())
            }
            DisplayFormatType::TreeRender => {
                writeln!(f, "table={}", self.table)?;
                for pushed in &self.pushed_down {
                    writeln!(f, "{pushed}")?;
                }
                Ok(())
            }
        }
    }
}

impl ExecutionPlan for StoreScanExec {
    fn name(&self) -> &'static str {
        "StoreScanExec"
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
        leaf_with_new_children(self, &children)
    }

    fn execute(
        &self,
        partition: usize,
        _context: Arc<TaskContext>,
    ) -> Result<SendableRecordBatchStream> {
        if partition != 0 {
            return Err(DataFusionError::Internal(format!(
                "StoreScanExec has one partition, not {}",
                partition + 1
            )));
        }
        let chunks_read = MetricBuilder::new(&self.metrics).counter("chunks_read", partition);
        let rows_built = MetricBuilder::new(&self.metrics).counter("rows_built", partition);
        let (batches, projection): (Box<dyn Iterator<Item = _> + Send>, _) = match &self.source {
            ScanSource::Dataframe {
                queries,
                projection,
            } => {
                let counted = |snapshot: Snapshot, query: &DataframeQuery, chunks_read: Count| {
                    snapshot
                        .into_dataframe(query)
                        .map(|stream| CountedDataframe {
                            stream,
                            counted: 0,
                            sources_counted: None,
                            chunks_read,
                        })
                };
                let (first, rest) = queries
                    .split_first()
                    .ok_or_else(|| DataFusionError::Internal("a scan of no range".to_owned()))?;
                let mut batches: Box<dyn Iterator<Item = _> + Send> = Box::new(
                    counted(self.snapshot.clone(), first, chunks_read.clone())
                        .map_err(|e| DataFusionError::External(Box::new(e)))?,
                );
                for query in rest {
                    let (snapshot, query, chunks_read) =
                        (self.snapshot.clone(), query.clone(), chunks_read.clone());
                    let part = ReadAhead::spawn(
                        move || -> Box<dyn Iterator<Item = _>> {
                            match counted(snapshot, &query, chunks_read) {
                                Ok(stream) => Box::new(stream),
                                Err(error) => Box::new(std::iter::once(Err(
                                    ArrowError::ExternalError(Box::new(error)),
                                ))),
                            }
                        },
                        READ_AHEAD_BYTES,
                    )
                    .map_err(|e| {
                        DataFusionError::Execution(format!("starting a scan thread: {e}"))
                    })?;
                    batches = Box::new(batches.chain(part));
                }
                (batches, projection.clone())
            }
            ScanSource::Chunks { query, projection } => {
                let stream = self
                    .snapshot
                    .chunk_table(query)
                    .map_err(|e| DataFusionError::External(Box::new(e)))?;
                chunks_read.add(stream.num_chunks());
                (Box::new(stream), projection.clone())
            }
        };
        let batches =
            Box::new(batches.map(
                move |batch: Result<RecordBatch, ArrowError>| match &projection {
                    Some(columns) => batch?.project(columns),
                    None => batch,
                },
            ));
        let limited = Limited {
            batches,
            remaining: self.limit,
            rows_built,
        };
        let schema = Arc::clone(&self.schema);
        let checked = limited.map(move |batch| {
            let batch = batch?;
            // The table's schema was taken from the same snapshot; a mismatch is a bug,
            // reported as an error rather than a wrong table.
            if batch.schema().fields() != schema.fields() {
                return Err(DataFusionError::Internal(format!(
                    "a store scan produced columns {:?} where {:?} were planned",
                    batch
                        .schema()
                        .fields()
                        .iter()
                        .map(|f| f.name())
                        .collect::<Vec<_>>(),
                    schema.fields().iter().map(|f| f.name()).collect::<Vec<_>>()
                )));
            }
            Ok(batch.with_schema(Arc::clone(&schema))?)
        });
        Ok(Box::pin(RecordBatchStreamAdapter::new(
            Arc::clone(&self.schema),
            futures::stream::iter(checked),
        )))
    }

    fn metrics(&self) -> Option<MetricsSet> {
        Some(self.metrics.clone_inner())
    }
}

/// A dataframe stream that reports the chunks it read as it goes (filling and sampling
/// find more while they run).
struct CountedDataframe {
    stream: crate::DataframeStream<'static>,
    counted: usize,
    /// The stream's sources when last counted: counting sorts every source's chunk id,
    /// which only needs doing again when a source was added.
    sources_counted: Option<usize>,
    chunks_read: Count,
}

impl Iterator for CountedDataframe {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        let next = self.stream.next();
        let sources = self.stream.num_sources();
        if self.sources_counted != Some(sources) {
            self.sources_counted = Some(sources);
            let read = self.stream.num_chunks_read();
            self.chunks_read.add(read.saturating_sub(self.counted));
            self.counted = self.counted.max(read);
        }
        next
    }
}

/// At most `remaining` rows (all of them when `None`), the last batch cut short; the
/// source is not asked for more once the limit is reached.
pub(super) struct Limited {
    batches: Box<dyn Iterator<Item = Result<RecordBatch, ArrowError>> + Send>,
    remaining: Option<usize>,
    rows_built: Count,
}

impl Limited {
    pub(super) fn new(
        batches: Box<dyn Iterator<Item = Result<RecordBatch, ArrowError>> + Send>,
        remaining: Option<usize>,
        rows_built: Count,
    ) -> Self {
        Self {
            batches,
            remaining,
            rows_built,
        }
    }
}

impl Iterator for Limited {
    type Item = Result<RecordBatch, DataFusionError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.remaining == Some(0) {
            return None;
        }
        let batch = match self.batches.next()? {
            Ok(batch) => batch,
            Err(error) => return Some(Err(error.into())),
        };
        self.rows_built.add(batch.num_rows());
        let Some(remaining) = &mut self.remaining else {
            return Some(Ok(batch));
        };
        let rows = batch.num_rows().min(*remaining);
        *remaining -= rows;
        Some(Ok(batch.slice(0, rows)))
    }
}
