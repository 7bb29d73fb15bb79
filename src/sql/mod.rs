//! SQL over the store through [DataFusion](https://datafusion.apache.org) (feature
//! `datafusion`): the store's views as tables, with filters, projections and limits pushed
//! down to its indices.
//!
//! [`register`] adds to a `SessionContext`, for one [`Snapshot`]:
//! - one table per timeline, named after it ([`TimelineTable`]): the dataframe view on
//!   that timeline (SEMANTICS.md section 9), index columns then `<entity>:<component>`
//!   list columns (quote such names in SQL: `"/robot/arm:torque"`);
//! - `chunks` ([`ChunksTable`]): every stored row across entities, with its entity path,
//!   chunk id, row id, times and components (`__chunks` if a timeline is named `chunks`);
//! - the table function `latest_at('<timeline>', <time>)` ([`LatestAtFunction`]).
//!
//! Every query reads the one snapshot the tables were registered with, so ingest can go
//! on meanwhile ([`SharedStore`](crate::SharedStore)). Queries run on DataFusion's own
//! runtime; the scans ([`StoreScanExec`]) answer from the store synchronously.
//!
//! ```
//! # use std::sync::Arc;
//! # use arrow_array::{ArrayRef, Float64Array};
//! use chunkstore::*;
//! use datafusion::prelude::SessionContext;
//! # let frame = Timeline::sequence("frame");
//! # let mut store = ChunkStore::new();
//! # for t in 0..100 {
//! #     let v = Arc::new(Float64Array::from(vec![t as f64])) as ArrayRef;
//! #     store.insert(ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/arm")?)
//! #         .with_row(RowId::new(), [(frame.clone(), t)], [("torque", v)]).build()?)?;
//! # }
//! let ctx = SessionContext::new();
//! chunkstore::sql::register(&ctx, &store.snapshot())?;
//! let runtime = tokio::runtime::Builder::new_current_thread().build()?;
//! let batches = runtime.block_on(async {
//!     ctx.sql(r#"SELECT count(*) AS n, avg("/arm:torque"[1]) AS mean
//!                FROM frame WHERE frame BETWEEN 10 AND 19"#)
//!         .await?
//!         .collect()
//!         .await
//! })?;
//! let text = datafusion::arrow::util::pretty::pretty_format_batches(&batches)?.to_string();
//! assert!(text.contains("| 10 | 14.5 |"), "{text}");
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod blocking;
#[cfg(feature = "rrd")]
mod dataset;
mod integer_times;
mod latest_at;
mod pushdown;
mod read_ahead;
mod scan;
mod segments;
mod tables;

use std::sync::Arc;

use datafusion::common::{Result, TableReference};
use datafusion::prelude::SessionContext;

use crate::{EntityPathFilter, Snapshot};

pub use blocking::{SqlReader, session_context};
/// The error of every SQL call here (DataFusion's), for callers without a `datafusion`
/// dependency of their own.
pub use datafusion::error::DataFusionError;
#[cfg(feature = "rrd")]
pub use dataset::{DatasetChunksTable, DatasetScanExec, DatasetTimelineTable, register_dataset};
pub use latest_at::{LatestAtFunction, asof_join};
pub use scan::StoreScanExec;
pub use segments::register_segments;
pub use tables::{ChunksTable, TimelineTable};

/// The name of the table of every stored row.
pub const CHUNKS_TABLE: &str = "chunks";

/// Registers the tables and the `latest_at` function of `snapshot` in `ctx` (see the
/// module docs), replacing tables of the same names; returns the table names, timelines
/// first (sorted), then the chunk table's.
///
/// # Errors
/// DataFusion's, should the context refuse a table.
pub fn register(ctx: &SessionContext, snapshot: &Snapshot) -> Result<Vec<String>> {
    let mut names = Vec::new();
    for timeline in snapshot.timelines() {
        let table = TimelineTable::new(
            snapshot.clone(),
            timeline.name(),
            EntityPathFilter::default(),
        )?;
        replace_table(ctx, timeline.name(), Arc::new(table))?;
        names.push(timeline.name().to_owned());
    }
    let chunks_name = if names.iter().any(|n| n == CHUNKS_TABLE) {
        format!("__{CHUNKS_TABLE}")
    } else {
        CHUNKS_TABLE.to_owned()
    };
    replace_table(
        ctx,
        &chunks_name,
        Arc::new(ChunksTable::new(snapshot.clone())?),
    )?;
    names.push(chunks_name);
    ctx.register_udtf(
        "latest_at",
        Arc::new(LatestAtFunction::new(snapshot.clone())),
    );
    register_expr_planners(ctx)?;
    Ok(names)
}

/// The planner that lets integers stand for times, once per context however often a
/// snapshot is registered again.
fn register_expr_planners(ctx: &SessionContext) -> Result<()> {
    use datafusion::execution::FunctionRegistry as _;
    let state = ctx.state_ref();
    let mut state = state.write();
    let registered = state
        .expr_planners()
        .iter()
        .any(|planner| format!("{planner:?}") == "IntegerTimes");
    if !registered {
        state.register_expr_planner(Arc::new(integer_times::IntegerTimes))?;
    }
    Ok(())
}

/// Registers `table` under exactly `name` (never parsed: a timeline named `a.b` is one
/// table, not table `b` of schema `a`).
fn replace_table(
    ctx: &SessionContext,
    name: &str,
    table: Arc<dyn datafusion::datasource::TableProvider>,
) -> Result<()> {
    let reference = TableReference::bare(name.to_owned());
    ctx.deregister_table(reference.clone())?;
    ctx.register_table(reference, table)?;
    Ok(())
}

/// An error of the store, a dataset or a file as DataFusion carries it (its message kept).
fn external(error: impl std::error::Error + Send + Sync + 'static) -> DataFusionError {
    DataFusionError::External(Box::new(error))
}
