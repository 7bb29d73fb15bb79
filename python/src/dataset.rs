//! `chunkstore.open_dataset(path)`: a directory of `.rrd` files (or one file) as one table
//! with a segment column (`chunkstore::dataset`, SEMANTICS.md section 15).

use std::path::PathBuf;

use arrow_array::RecordBatchReader;
use arrow_pyarrow::PyArrowType;
use chunkstore::dataset::{Dataset, DatasetOptions};
use pyo3::prelude::*;

use crate::dataframe_args::DataframeArgs;
use crate::errors::{dataset_error, no_panic, sql_error};
use crate::store::time_type_name;

/// A dataset: see the module docs.
#[pyclass(frozen, module = "chunkstore._chunkstore")]
pub struct NativeDataset {
    dataset: Dataset,
}

/// Opens a dataset: see the module docs.
#[pyfunction]
#[pyo3(signature = (path, skip_bad = false, memory_budget = None, index_cache = None, storage_options = None))]
pub fn open_dataset(
    py: Python<'_>,
    path: PathBuf,
    skip_bad: bool,
    memory_budget: Option<u64>,
    index_cache: Option<PathBuf>,
    storage_options: Option<Vec<(String, String)>>,
) -> PyResult<NativeDataset> {
    let storage = crate::open::storage_from(storage_options);
    py.detach(|| {
        no_panic(|| {
            let mut options = DatasetOptions::default()
                .with_skip_bad(skip_bad)
                .with_storage(storage);
            if let Some(dir) = index_cache {
                options = options.with_index_cache(dir);
            }
            if let Some(budget) = memory_budget {
                options = options.with_memory_budget(budget);
            }
            let dataset = Dataset::open(&path, &options).map_err(dataset_error)?;
            Ok(NativeDataset { dataset })
        })
    })
}

/// A segment as Python sees it.
type SegmentTuple = (
    String,
    String,
    // The file's path, or an object's URL, as text (a `pathlib.Path` would fold a URL's
    // `//`).
    String,
    u64,
    u64,
    Vec<(String, String, i64, i64)>,
);

#[pymethods]
impl NativeDataset {
    /// `(id, application id, path, rows, chunks, [(timeline, type, min, max)])` per
    /// segment, by id.
    fn segments(&self) -> Vec<SegmentTuple> {
        self.dataset
            .segments()
            .iter()
            .map(|s| {
                let timelines = s
                    .timelines
                    .iter()
                    .map(|(t, r)| {
                        (
                            t.name().to_owned(),
                            time_type_name(t.time_type()).to_owned(),
                            r.min().as_i64(),
                            r.max().as_i64(),
                        )
                    })
                    .collect();
                (
                    s.id.clone(),
                    s.application_id.clone(),
                    s.path.to_string_lossy().into_owned(),
                    s.num_rows,
                    s.num_chunks,
                    timelines,
                )
            })
            .collect()
    }

    /// `(name, type, min, max)` per timeline of any segment.
    fn timelines(&self) -> Vec<(String, String, Option<i64>, Option<i64>)> {
        self.dataset
            .timelines()
            .iter()
            .map(|t| {
                let range = self.dataset.time_range(t.name());
                (
                    t.name().to_owned(),
                    time_type_name(t.time_type()).to_owned(),
                    range.map(|r| r.min().as_i64()),
                    range.map(|r| r.max().as_i64()),
                )
            })
            .collect()
    }

    /// The type of `timeline`'s times, `None` if no segment has it.
    fn time_type(&self, timeline: &str) -> Option<&'static str> {
        self.dataset.time_type(timeline).map(time_type_name)
    }

    /// What was skipped so far (`skip_bad`), each once.
    fn take_warnings(&self) -> Vec<String> {
        self.dataset.take_warnings()
    }

    /// Writes the dataset as a Delta Lake table at `table` (a directory or a bucket's
    /// prefix), or with `append` adds its segments to the one there: partitioned by
    /// segment, then by entity, or with `index` and `bucket` by `bucket` index values.
    /// Gives `(version, rows, files, segments, retries)`.
    #[pyo3(signature = (table, index = None, bucket = None, append = false, storage_options = None))]
    #[allow(clippy::too_many_arguments, reason = "Python keyword arguments")]
    fn write_delta(
        &self,
        py: Python<'_>,
        table: PathBuf,
        index: Option<String>,
        bucket: Option<i64>,
        append: bool,
        storage_options: Option<Vec<(String, String)>>,
    ) -> PyResult<(u64, u64, usize, Vec<String>, usize)> {
        use chunkstore::parquet::HiveLayout;
        let storage = crate::open::storage_from(storage_options);
        let layout = match (index, bucket) {
            (Some(index), Some(width)) => HiveLayout::ByTimeBucket {
                timeline: index.into(),
                width,
                query: None,
            },
            (None, Some(_)) => {
                return Err(crate::errors::invalid(
                    "bucket needs an index: the timeline whose values it groups",
                ));
            }
            (index, None) => HiveLayout::ByEntity {
                timeline: index.map(Into::into),
            },
        };
        py.detach(|| {
            no_panic(|| {
                // Nothing cancels a write from Python: Ctrl-C is seen when it returns.
                let never = std::sync::Arc::default();
                let store = chunkstore::storage::delta_table(&table, &storage, never)
                    .map_err(|e| crate::errors::os_error(&table, e.into_io()))?;
                let commit = self
                    .dataset
                    .write_delta(store.as_ref(), &layout, append, &|_, _| {})
                    .map_err(dataset_error)?;
                Ok((
                    commit.version,
                    commit.rows(),
                    commit.files.len(),
                    commit.segments,
                    commit.retries,
                ))
            })
        })
    }

    /// What queries have read from the segments' files so far: `(segment reads, chunks
    /// decoded, bytes read, requests, bytes fetched)`.
    fn read_stats(&self) -> (u64, u64, u64, u64, u64) {
        let read = self.dataset.read_stats();
        (
            read.segment_reads,
            read.chunks_decoded,
            read.bytes_read,
            read.requests,
            read.bytes_fetched,
        )
    }

    /// The dataset's table: see `chunkstore.Dataset.dataframe`.
    fn dataframe(
        &self,
        py: Python<'_>,
        args: DataframeArgs,
    ) -> PyResult<PyArrowType<Box<dyn RecordBatchReader + Send>>> {
        let query = args.reader_query()?;
        py.detach(|| {
            no_panic(|| {
                let stream = self.dataset.dataframe(&query).map_err(dataset_error)?;
                Ok(PyArrowType(
                    Box::new(stream) as Box<dyn RecordBatchReader + Send>
                ))
            })
        })
    }

    /// The answer of a SQL query over the dataset's tables, streamed: see
    /// `chunkstore.Dataset.sql`.
    fn sql(
        &self,
        py: Python<'_>,
        query: &str,
    ) -> PyResult<PyArrowType<Box<dyn RecordBatchReader + Send>>> {
        py.detach(|| {
            no_panic(|| {
                let ctx = chunkstore::sql::session_context();
                chunkstore::sql::register_dataset(&ctx, &self.dataset).map_err(sql_error)?;
                let answer = chunkstore::sql::SqlReader::run(&ctx, query).map_err(sql_error)?;
                Ok(PyArrowType(
                    Box::new(answer) as Box<dyn RecordBatchReader + Send>
                ))
            })
        })
    }
}
