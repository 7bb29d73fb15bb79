//! A dataset's tables for DataFusion ([`register_dataset`]): one table per timeline (the
//! dataset's dataframe on it, SEMANTICS.md section 15) and `chunks`, each with
//! [`SEGMENT_ID_COLUMN`](crate::SEGMENT_ID_COLUMN) first, read segment by segment in bounded memory.
//!
//! What a query's filters say is applied before any file is read: a filter on
//! `rerun_segment_id` (`=`, `IN`, `LIKE`, `starts_with`) keeps only the segments it names;
//! a filter on a timeline table's index keeps only the segments whose span there overlaps
//! it, and in those only the chunks whose manifest entries the range needs (`prune.rs`);
//! on `chunks`, a filter on `entity_path` or a timeline reads only the chunks of those
//! entities or overlapping that range. `EXPLAIN` shows the segments and chunks left;
//! `EXPLAIN ANALYZE` what was read.
//!
//! As on the store's side: `tables.rs` holds the two `TableProvider`s (what a query's
//! filters keep), `scan.rs` the [`DatasetScanExec`] that reads what they kept.

mod scan;
mod tables;

use std::sync::Arc;

use datafusion::catalog::{TableFunctionArgs, TableFunctionImpl};
use datafusion::common::Result;
use datafusion::datasource::TableProvider;
use datafusion::prelude::SessionContext;

use super::{CHUNKS_TABLE, external, replace_table};
use crate::Timeline;
use crate::dataset::Dataset;

pub use scan::DatasetScanExec;
pub use tables::{DatasetChunksTable, DatasetTimelineTable};

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
        let table = DatasetTimelineTable::new(
            dataset.clone(),
            Timeline::new(timeline.as_str(), time_type),
            Arc::clone(schema),
            Arc::clone(&segments),
        );
        replace_table(ctx, timeline, Arc::new(table))?;
        names.push(timeline.clone());
    }
    let chunks_name = if tables.timelines.contains_key(CHUNKS_TABLE) {
        format!("__{CHUNKS_TABLE}")
    } else {
        CHUNKS_TABLE.to_owned()
    };
    let table = DatasetChunksTable::new(dataset.clone(), Arc::clone(&tables.chunks), segments);
    replace_table(ctx, &chunks_name, Arc::new(table))?;
    names.push(chunks_name);
    ctx.register_udtf("latest_at", Arc::new(DatasetLatestAt));
    super::register_expr_planners(ctx)?;
    Ok(names)
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
