//! [`DataframeArgs`]: the keywords of a dataframe in one struct, as the Python half hands
//! them over (`chunkstore/_arguments.py`, `dataframe_args`): `Store.dataframe`,
//! `Dataset.dataframe` and `Store.write_parquet` take the same nine, declared once on each
//! side.

use chunkstore::{DataframeQuery, EntityPathFilter, TimeInt, TimeRange};
use pyo3::prelude::*;

use crate::errors::invalid;

/// Rows per batch at least of a dataframe read from Python, unless rows are asked for
/// (`write_parquet`'s batches stay in Rust and keep the crate's default). Each batch
/// crosses into pyarrow array by array, a fixed cost per (batch, column), so a wide
/// table's short default batches (349 rows at 3,000 columns) cost Python more than they
/// cost Rust: reading such a table whole took 4.6 s from Python against 2.8 s in Rust;
/// with batches of 4,096 rows, 3.1 s (the read benchmark, `docs/performance-log.md`).
/// Narrower tables already have batches this long.
const PYTHON_MIN_BATCH_ROWS: usize = 4_096;

/// A dataframe's keywords, times already integers on the index's timeline (a dict from
/// the Python half, one item per field).
#[derive(FromPyObject)]
#[pyo3(from_item_all)]
#[allow(
    clippy::struct_excessive_bools,
    reason = "Python's keyword arguments, one each"
)]
pub(crate) struct DataframeArgs {
    index: String,
    contents: Option<Vec<String>>,
    range: Option<(i64, i64)>,
    index_values: Option<Vec<i64>>,
    fill_latest_at: bool,
    batch_rows: Option<usize>,
    include_tombstone_columns: bool,
    include_semantically_empty_columns: bool,
    exact_index_values: bool,
}

impl DataframeArgs {
    /// The index timeline.
    pub fn index(&self) -> &str {
        &self.index
    }

    /// Whether rows are the values given (`index_values`), not the index's times.
    pub fn is_sampled(&self) -> bool {
        self.index_values.is_some()
    }

    /// The query the keywords ask for.
    pub fn query(&self) -> PyResult<DataframeQuery> {
        let mut query = base_query(&self.index, self.contents.clone())?
            .with_fill_latest_at(self.fill_latest_at)
            .with_tombstone_columns(self.include_tombstone_columns)
            .with_semantically_empty_columns(self.include_semantically_empty_columns)
            .with_exact_index_values(self.exact_index_values);
        if let Some((lo, hi)) = self.range {
            query = query.with_range(time_range(lo, hi)?);
        }
        if let Some(values) = &self.index_values {
            let values: Vec<TimeInt> = values.iter().map(|&v| time(v)).collect::<PyResult<_>>()?;
            query = query.with_index_values(values);
        }
        if let Some(rows) = self.batch_rows {
            if rows == 0 {
                return Err(invalid("batch_rows must be at least 1"));
            }
            query = query.with_batch_rows(rows);
        }
        Ok(query)
    }

    /// The query of a reader whose batches cross into pyarrow: at least
    /// [`PYTHON_MIN_BATCH_ROWS`] a batch unless `batch_rows` says.
    pub fn reader_query(&self) -> PyResult<DataframeQuery> {
        let query = self.query()?;
        Ok(if self.batch_rows.is_none() {
            query.with_min_batch_rows(PYTHON_MIN_BATCH_ROWS)
        } else {
            query
        })
    }
}

/// The query of every row on `index` with these `contents`: what a schema asks.
pub(crate) fn base_query(index: &str, contents: Option<Vec<String>>) -> PyResult<DataframeQuery> {
    let mut query = DataframeQuery::new(index);
    if let Some(filter) = contents_filter(contents)? {
        query = query.with_contents(filter);
    }
    Ok(query)
}

/// A time from Python, if the store's range holds it.
pub(crate) fn time(value: i64) -> PyResult<TimeInt> {
    TimeInt::new(value).ok_or_else(|| invalid(format!("time {value} is out of range")))
}

/// `[lo, hi]` as a time range; `lo` after `hi` is refused, not read as empty.
pub(crate) fn time_range(lo: i64, hi: i64) -> PyResult<TimeRange> {
    if lo > hi {
        return Err(invalid(format!(
            "range ({lo}, {hi}): the start is after the end"
        )));
    }
    Ok(TimeRange::new(time(lo)?, time(hi)?))
}

fn contents_filter(contents: Option<Vec<String>>) -> PyResult<Option<EntityPathFilter>> {
    contents
        .map(|rules| {
            EntityPathFilter::parse(&rules).map_err(|e| invalid(format!("contents {rules:?}: {e}")))
        })
        .transpose()
}
