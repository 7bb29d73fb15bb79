//! A query run from synchronous code: [`SqlReader`] plans a query on a runtime of its own
//! and hands its answer over batch by batch as an Arrow `RecordBatchReader`, for callers
//! without an async runtime (the CLI, the Python package, file writers).

use std::sync::Arc;

use arrow_array::{RecordBatch, RecordBatchReader};
use arrow_schema::{ArrowError, SchemaRef};
use datafusion::common::{DataFusionError, Result};
use datafusion::physical_plan::SendableRecordBatchStream;
use datafusion::prelude::{SessionConfig, SessionContext};
use futures::StreamExt as _;

/// A `SessionContext` configured as the CLI and the Python package query the store: with
/// the information schema (`SHOW TABLES`, `SHOW COLUMNS`), and without DataFusion's
/// round-robin repartition. A timeline table's scan builds its range on every core and
/// yields rows in index order; spreading them over partitions for a filter would
/// interleave them for no gain, so an answer without `ORDER BY` keeps the table's order.
pub fn session_context() -> SessionContext {
    SessionContext::new_with_config(
        SessionConfig::new()
            .with_information_schema(true)
            .with_round_robin_repartition(false),
    )
}

/// A query's answer, read batch by batch; each batch is computed when it is asked for,
/// so an answer larger than memory streams through. It owns the runtime the query runs
/// on (a worker per core, for DataFusion's own partitions) and may move between threads.
///
/// ```
/// # use std::sync::Arc;
/// # use arrow_array::{ArrayRef, Float64Array};
/// use chunkstore::*;
/// # let frame = Timeline::sequence("frame");
/// # let mut store = ChunkStore::new();
/// # for t in 0..100 {
/// #     let v = Arc::new(Float64Array::from(vec![t as f64])) as ArrayRef;
/// #     store.insert(ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/arm")?)
/// #         .with_row(RowId::new(), [(frame.clone(), t)], [("torque", v)]).build()?)?;
/// # }
/// let ctx = chunkstore::sql::session_context();
/// chunkstore::sql::register(&ctx, &store.snapshot())?;
/// let answer = chunkstore::sql::SqlReader::run(&ctx, "SELECT count(*) AS n FROM frame")?;
/// let rows: usize = answer.map(|batch| batch.map_or(0, |b| b.num_rows())).sum();
/// assert_eq!(rows, 1);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct SqlReader {
    runtime: Arc<tokio::runtime::Runtime>,
    stream: SendableRecordBatchStream,
    schema: SchemaRef,
}

impl std::fmt::Debug for SqlReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SqlReader")
            .field("schema", &self.schema)
            .finish_non_exhaustive()
    }
}

impl SqlReader {
    /// Plans `query` in `ctx` and starts it.
    ///
    /// # Errors
    /// The query's own (SQL it cannot parse, a table or column it lacks, a plan it
    /// refuses), or a runtime that could not be started.
    pub fn run(ctx: &SessionContext, query: &str) -> Result<Self> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .build()
            .map_err(|e| DataFusionError::Execution(format!("starting the query runtime: {e}")))?;
        let stream = runtime.block_on(async {
            let frame = ctx.sql(query).await?;
            frame.execute_stream().await
        })?;
        let schema = stream.schema();
        Ok(Self {
            runtime: Arc::new(runtime),
            stream,
            schema,
        })
    }
}

impl Iterator for SqlReader {
    type Item = std::result::Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        let next = self.runtime.block_on(self.stream.next())?;
        Some(next.map_err(|e| match e {
            DataFusionError::ArrowError(error, _) => *error,
            other => ArrowError::ExternalError(Box::new(other)),
        }))
    }
}

impl RecordBatchReader for SqlReader {
    fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }
}
