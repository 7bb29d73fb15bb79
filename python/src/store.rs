//! `NativeStore`: the store behind `chunkstore.Store`. Every method takes plain integers
//! and strings (the Python half converts), releases the GIL, and reads one snapshot.
//!
//! A store opened from an `.rrd` with a footer starts *lazy*: discovery (entities,
//! timelines, components, length) reads the footer's manifest, and `latest_at`/`range`
//! decode only the chunks that could answer. Anything that needs every chunk (a
//! dataframe, a write, GC, compaction, export) decodes the rest once, and from then on
//! the store is an ordinary shared store.
//!
//! Locking: the state's mutex is only ever taken with the GIL released (inside
//! `Python::detach`), so a thread waiting for it never holds the GIL that the holder
//! needs to return.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::{Array, RecordBatch, RecordBatchReader};
use arrow_pyarrow::{PyArrowType, Table};
use arrow_schema::{DataType, Field, Schema};
use chunkstore::parquet::{ParquetOptions, write_parquet_file};
use chunkstore::recording::{Recording, RecordingReader};
use chunkstore::rrd::{LazyRecording, LazyStats, StoreId, StoreInfo};
use chunkstore::storage::{OutputError, StorageOptions};
use chunkstore::{
    Chunk, ChunkStore, EntityPath, GcOptions, GcTarget, LatestAtQuery, RangeQuery, SharedStore,
    Snapshot, StoreConfig, StoreEvent, StoreView, TimeInt, TimeType,
};
use parking_lot::Mutex;
use pyo3::prelude::*;

use crate::dataframe_args::{DataframeArgs, base_query, time, time_range};
use crate::errors::{
    Error, chunk_error, dataframe_error, insert_error, invalid, listing, no_panic, open_error,
    os_error, rrd_error, unknown_timeline,
};
use crate::tables::{Answer, latest_at_batch, range_batches};

/// What a store is: a recording still read lazily, or a store in memory.
enum State {
    Lazy(Box<Recording>),
    Loaded(SharedStore),
}

/// The native store (see the module docs); Python code uses `chunkstore.Store`.
#[pyclass(module = "chunkstore._chunkstore", frozen)]
pub struct NativeStore {
    state: Mutex<State>,
    /// The recording's store info, written back by `write_rrd`.
    store_info: Mutex<Option<StoreInfo>>,
    /// The file or directory the store was opened from, which no write may replace (a
    /// lazy store still reads it; a loaded one would lose its only copy).
    source: Option<PathBuf>,
    /// What a lazy recording had read when it was decoded whole (its reads' cost stays
    /// known once the store is loaded).
    read_when_loaded: Mutex<Option<LazyStats>>,
}

impl NativeStore {
    /// A store over a store in memory, opened from `source` (if it was).
    pub fn loaded(store: ChunkStore, store_info: Option<StoreInfo>, source: Option<&Path>) -> Self {
        Self {
            state: Mutex::new(State::Loaded(SharedStore::new(store))),
            store_info: Mutex::new(store_info),
            source: source.map(Path::to_owned),
            read_when_loaded: Mutex::new(None),
        }
    }

    /// A store over an opened recording: still lazy, or loaded (then shared).
    pub fn open(recording: Recording) -> PyResult<Self> {
        let store_info = recording.store_info().cloned();
        let source = recording.source().to_owned();
        let state = if recording.is_lazy() {
            State::Lazy(Box::new(recording))
        } else {
            State::Loaded(SharedStore::new(
                recording.into_store().map_err(open_error)?,
            ))
        };
        Ok(Self {
            state: Mutex::new(state),
            store_info: Mutex::new(store_info),
            source: Some(source),
            read_when_loaded: Mutex::new(None),
        })
    }

    /// Refuses an output that is the store's own source (the file, or a file inside the
    /// directory, it was opened from), as the CLI does.
    fn refuse_overwriting_source(&self, out: &Path) -> PyResult<()> {
        let Some(source) = &self.source else {
            return Ok(());
        };
        if chunkstore::storage::url_scheme(out).is_some() && out == source.as_path() {
            return Err(invalid(format!(
                "{}: the output would overwrite the store's source",
                out.display()
            )));
        }
        let (Ok(source), Ok(out)) = (source.canonicalize(), out.canonicalize()) else {
            return Ok(()); // the output does not exist yet: nothing to overwrite
        };
        if out == source || (source.is_dir() && out.starts_with(&source)) {
            return Err(invalid(format!(
                "{}: the output would overwrite the store's source",
                out.display()
            )));
        }
        Ok(())
    }

    /// The shared store, decoding the rest of a lazy recording first. GIL released.
    fn shared(&self) -> PyResult<SharedStore> {
        let mut state = self.state.lock();
        if let State::Lazy(recording) = &mut *state {
            // Decoded in place first: a chunk that fails leaves the recording lazy (and
            // usable), where `into_store` would have consumed it; then it decodes nothing.
            recording.load_all().map_err(open_error)?;
            *self.read_when_loaded.lock() = recording.lazy().map(LazyRecording::stats);
            let loaded = State::Loaded(SharedStore::new(ChunkStore::new()));
            if let State::Lazy(recording) = std::mem::replace(&mut *state, loaded) {
                let store = recording.into_store().map_err(open_error)?;
                *state = State::Loaded(SharedStore::new(store));
            }
        }
        match &*state {
            State::Loaded(shared) => Ok(shared.clone()),
            State::Lazy { .. } => Err(Error::new_err("the recording could not be loaded")),
        }
    }

    /// A snapshot of the whole store. GIL released.
    fn snapshot(&self) -> PyResult<Snapshot> {
        Ok(self.shared()?.snapshot())
    }

    /// Runs `read` with the GIL released: on the lazy recording if the store is still
    /// lazy, else on a snapshot. A lazy read's fault names the recording's file.
    fn read<T: Send>(
        &self,
        py: Python<'_>,
        read: impl FnOnce(Reader<'_>) -> PyResult<T> + Send,
    ) -> PyResult<T> {
        py.detach(|| {
            no_panic(|| {
                let mut state = self.state.lock();
                match &mut *state {
                    State::Lazy(recording) => {
                        let path = recording.source().to_owned();
                        read(Reader {
                            reads: recording.reader(),
                            path: &path,
                        })
                    }
                    State::Loaded(shared) => {
                        let snapshot = shared.snapshot();
                        drop(state);
                        read(Reader {
                            reads: RecordingReader::view(&snapshot),
                            path: Path::new(""),
                        })
                    }
                }
            })
        })
    }

    /// Runs `work` on a snapshot of the whole store, with the GIL released.
    fn with_snapshot<T: Send>(
        &self,
        py: Python<'_>,
        work: impl FnOnce(&StoreView) -> PyResult<T> + Send,
    ) -> PyResult<T> {
        py.detach(|| no_panic(|| work(self.snapshot()?.view())))
    }

    /// Runs `write` on the shared store, with the GIL released.
    fn write<T: Send>(
        &self,
        py: Python<'_>,
        write: impl FnOnce(&SharedStore) -> PyResult<T> + Send,
    ) -> PyResult<T> {
        py.detach(|| no_panic(|| write(&self.shared()?)))
    }
}

/// What a read runs on: the recording's reads, and the file a lazy read's fault names.
struct Reader<'a> {
    reads: RecordingReader<'a>,
    path: &'a Path,
}

impl Reader<'_> {
    fn time_type(&self, timeline: &str) -> PyResult<TimeType> {
        self.reads
            .time_type(timeline)
            .map_err(|e| unknown_timeline(&e))
    }

    fn component_names(&self, entity: &EntityPath) -> Vec<chunkstore::ComponentName> {
        self.reads.component_names(entity)
    }

    fn latest_at(
        &mut self,
        query: &LatestAtQuery,
        entity: &EntityPath,
        component: &str,
    ) -> PyResult<Option<chunkstore::QueryCell>> {
        self.reads
            .latest_at(query, entity, component)
            .map_err(|e| rrd_error(self.path, e))
    }

    /// The entity, which must hold data.
    fn entity(&self, text: &str) -> PyResult<EntityPath> {
        let entity = parse_entity(text)?;
        if self.component_names(&entity).is_empty() {
            let known: Vec<String> = self
                .reads
                .entity_paths()
                .iter()
                .map(ToString::to_string)
                .collect();
            return Err(invalid(format!(
                "no data at entity {entity} (the store has: {})",
                listing(&known, "nothing")
            )));
        }
        Ok(entity)
    }
}

fn parse_entity(text: &str) -> PyResult<EntityPath> {
    EntityPath::parse(text).map_err(|e| invalid(format!("entity path {text:?}: {e}")))
}

pub(crate) fn time_type_name(time_type: TimeType) -> &'static str {
    match time_type {
        TimeType::Sequence => "sequence",
        TimeType::DurationNs => "duration",
        TimeType::TimestampNs => "timestamp",
    }
}

fn count_deleted(events: &[StoreEvent]) -> (u64, u64) {
    let mut chunks = 0;
    let mut rows = 0;
    for event in events {
        if let StoreEvent::Deletion { chunk, .. } = event {
            chunks += 1;
            rows += chunk.num_rows() as u64;
        }
    }
    (chunks, rows)
}

#[pymethods]
impl NativeStore {
    /// The answer of a SQL query over a snapshot of the store's tables, streamed: see
    /// `chunkstore.Store.sql`. A lazy recording is decoded whole first.
    fn sql(
        &self,
        py: Python<'_>,
        query: &str,
    ) -> PyResult<PyArrowType<Box<dyn arrow_array::RecordBatchReader + Send>>> {
        py.detach(|| {
            no_panic(|| {
                let snapshot = self.snapshot()?;
                let ctx = chunkstore::sql::session_context();
                chunkstore::sql::register(&ctx, &snapshot).map_err(crate::errors::sql_error)?;
                let answer = chunkstore::sql::SqlReader::run(&ctx, query)
                    .map_err(crate::errors::sql_error)?;
                Ok(PyArrowType(
                    Box::new(answer) as Box<dyn arrow_array::RecordBatchReader + Send>
                ))
            })
        })
    }

    /// An empty store; `compaction=False` keeps chunks as inserted.
    #[new]
    #[pyo3(signature = (compaction = true))]
    fn new(compaction: bool) -> PyResult<Self> {
        let config = if compaction {
            StoreConfig::DEFAULT
        } else {
            StoreConfig::COMPACTION_OFF
        };
        let store = ChunkStore::with_config(config).map_err(|e| invalid(e.to_string()))?;
        Ok(Self::loaded(store, None, None))
    }

    /// Is the store still reading its recording lazily?
    fn is_lazy(&self, py: Python<'_>) -> bool {
        py.detach(|| matches!(&*self.state.lock(), State::Lazy(_)))
    }

    /// What a store opened lazily has read from its source so far: `(chunks in the
    /// file, chunks decoded, bytes read, requests, bytes fetched)`; `None` for a store
    /// that was never lazy.
    fn read_stats(&self, py: Python<'_>) -> Option<(usize, usize, u64, u64, u64)> {
        py.detach(|| {
            let stats = match &*self.state.lock() {
                State::Lazy(recording) => recording.lazy().map(LazyRecording::stats),
                State::Loaded(_) => *self.read_when_loaded.lock(),
            }?;
            Some((
                stats.chunks_in_file,
                stats.chunks_decoded,
                stats.bytes_read,
                stats.requests,
                stats.bytes_fetched,
            ))
        })
    }

    /// Inserts one record batch in Rerun's chunk layout; returns its rows.
    fn insert(&self, py: Python<'_>, batch: PyArrowType<RecordBatch>) -> PyResult<usize> {
        let batch = batch.0;
        self.write(py, move |shared| {
            let chunk = Chunk::from_record_batch(&batch).map_err(chunk_error)?;
            let rows = chunk.num_rows();
            shared.insert(chunk).map_err(insert_error)?;
            Ok(rows)
        })
    }

    /// Every entity with data, sorted, as text.
    fn entities(&self, py: Python<'_>) -> PyResult<Vec<String>> {
        self.read(py, |source| {
            Ok(source
                .reads
                .entity_paths()
                .iter()
                .map(ToString::to_string)
                .collect())
        })
    }

    /// The components of an entity, sorted.
    fn components(&self, py: Python<'_>, entity: &str) -> PyResult<Vec<String>> {
        let entity = parse_entity(entity)?;
        self.read(py, move |source| {
            Ok(source
                .component_names(&entity)
                .iter()
                .map(|c| c.as_str().to_owned())
                .collect())
        })
    }

    /// `(name, type, min, max)` per timeline, sorted by name; type is `"sequence"`,
    /// `"duration"` or `"timestamp"`; min and max are `None` when no data is left.
    #[allow(
        clippy::type_complexity,
        reason = "the tuple Python unpacks into a Timeline, spelled out"
    )]
    fn timelines(
        &self,
        py: Python<'_>,
    ) -> PyResult<Vec<(String, &'static str, Option<i64>, Option<i64>)>> {
        self.read(py, |source| {
            Ok(source
                .reads
                .timelines()
                .into_iter()
                .map(|t| {
                    let range = source.reads.time_range(t.name());
                    (
                        t.name().to_owned(),
                        time_type_name(t.time_type()),
                        range.map(|r| r.min().as_i64()),
                        range.map(|r| r.max().as_i64()),
                    )
                })
                .collect())
        })
    }

    /// The type name of a timeline (`"sequence"`, `"duration"`, `"timestamp"`).
    fn time_type(&self, py: Python<'_>, timeline: &str) -> PyResult<&'static str> {
        self.read(py, |source| source.time_type(timeline).map(time_type_name))
    }

    /// `(rows, chunks)`: for a lazy recording, as its footer lists them.
    fn counts(&self, py: Python<'_>) -> PyResult<(u64, u64)> {
        self.read(py, |source| Ok(source.reads.num_rows_and_chunks()))
    }

    /// Heap bytes the store holds (decodes a lazy recording).
    fn heap_bytes(&self, py: Python<'_>) -> PyResult<u64> {
        self.with_snapshot(py, |view| Ok(view.stats().heap_bytes))
    }

    /// The latest-at table: see `tables::latest_at_batch`.
    #[pyo3(signature = (timeline, at, entity, components = None))]
    fn latest_at(
        &self,
        py: Python<'_>,
        timeline: &str,
        at: i64,
        entity: &str,
        components: Option<Vec<String>>,
    ) -> PyResult<PyArrowType<RecordBatch>> {
        let at = time(at)?;
        self.read(py, move |mut source| {
            let time_type = source.time_type(timeline)?;
            let entity = source.entity(entity)?;
            let known = source.component_names(&entity);
            let wanted = match components {
                None => known.clone(),
                Some(names) => names
                    .iter()
                    .map(|name| {
                        known
                            .iter()
                            .find(|k| k.as_str() == name)
                            .cloned()
                            .ok_or_else(|| {
                                invalid(format!(
                                    "entity {entity} has no component {name:?} (it has: {})",
                                    known
                                        .iter()
                                        .map(chunkstore::ComponentName::as_str)
                                        .collect::<Vec<_>>()
                                        .join(", ")
                                ))
                            })
                    })
                    .collect::<PyResult<Vec<_>>>()?,
            };
            let query = LatestAtQuery::new(timeline, at);
            let mut answers = Vec::with_capacity(wanted.len());
            for component in wanted {
                let cell = source.latest_at(&query, &entity, component.as_str())?;
                let answer = match cell {
                    Some(cell) => Answer::Found(cell),
                    None => Answer::Missing(list_type(&mut source, &entity, component.as_str())),
                };
                answers.push((component, answer));
            }
            latest_at_batch(timeline, time_type, &entity, answers)
                .map(PyArrowType)
                .map_err(|e| invalid(e.to_string()))
        })
    }

    /// Every row of one component in `[lo, hi]` on `timeline`, in `(time, row id)` order.
    fn range(
        &self,
        py: Python<'_>,
        timeline: &str,
        lo: i64,
        hi: i64,
        entity: &str,
        component: &str,
    ) -> PyResult<PyArrowType<Table>> {
        let span = time_range(lo, hi)?;
        self.read(py, move |mut source| {
            let time_type = source.time_type(timeline)?;
            let entity = source.entity(entity)?;
            if !source
                .component_names(&entity)
                .iter()
                .any(|c| c.as_str() == component)
            {
                return Err(invalid(format!(
                    "entity {entity} has no component {component:?}"
                )));
            }
            let query = RangeQuery::new(timeline, span);
            let result = source
                .reads
                .range(&query, &entity, component)
                .map_err(|e| rrd_error(source.path, e))?;
            let list_type = result.runs().next().map_or_else(
                || list_type(&mut source, &entity, component),
                |run| run.column().list_array().data_type().clone(),
            );
            let (batches, schema) =
                range_batches(timeline, time_type, &entity, component, list_type, &result)
                    .map_err(|e| invalid(e.to_string()))?;
            Table::try_new(batches, schema)
                .map(PyArrowType)
                .map_err(|e| invalid(e.to_string()))
        })
    }

    /// The dataframe schema for `index` (see `dataframe`).
    #[pyo3(signature = (index, contents = None))]
    fn schema(
        &self,
        py: Python<'_>,
        index: &str,
        contents: Option<Vec<String>>,
    ) -> PyResult<PyArrowType<Schema>> {
        let query = base_query(index, contents)?;
        self.with_snapshot(py, move |view| {
            let stream = view.dataframe(&query).map_err(dataframe_error)?;
            Ok(PyArrowType(Arc::unwrap_or_clone(stream.schema())))
        })
    }

    /// A dataframe view (SEMANTICS.md section 9), streamed from one snapshot: see
    /// `chunkstore.Store.dataframe`.
    fn dataframe(
        &self,
        py: Python<'_>,
        args: DataframeArgs,
    ) -> PyResult<PyArrowType<Box<dyn RecordBatchReader + Send>>> {
        let query = args.reader_query()?;
        py.detach(|| {
            no_panic(|| {
                let stream = self
                    .snapshot()?
                    .into_dataframe(&query)
                    .map_err(dataframe_error)?;
                Ok(PyArrowType(
                    Box::new(stream) as Box<dyn RecordBatchReader + Send>
                ))
            })
        })
    }

    /// Garbage collection; returns `(chunks dropped, rows dropped)`.
    #[pyo3(signature = (fraction = None, bytes = None, protect_latest = 0))]
    fn gc(
        &self,
        py: Python<'_>,
        fraction: Option<f64>,
        bytes: Option<u64>,
        protect_latest: usize,
    ) -> PyResult<(u64, u64)> {
        let target = match (fraction, bytes) {
            (Some(_), Some(_)) => {
                return Err(invalid(
                    "gc: give a fraction or a number of bytes, not both",
                ));
            }
            (Some(fraction), None) => GcTarget::drop_at_least_fraction(fraction)
                .map_err(|e| invalid(format!("gc: {e}")))?,
            (None, Some(bytes)) => GcTarget::DropAtLeastBytes(bytes),
            (None, None) => GcTarget::Everything,
        };
        let options = GcOptions::everything()
            .with_target(target)
            .with_protect_latest(protect_latest);
        self.write(py, move |shared| {
            Ok(count_deleted(&shared.write(|store| store.gc(&options))))
        })
    }

    /// Compaction; returns `(chunks before, chunks after)`.
    fn compact(&self, py: Python<'_>) -> PyResult<(u64, u64)> {
        self.write(py, |shared| {
            let before = shared.snapshot().stats().num_chunks();
            // Group by group, each group's events dropped: `compact()`'s events would
            // hold every replaced chunk, the old and new copies of the store at once.
            shared.write(|store| store.compact_group_by_group(drop));
            Ok((before, shared.snapshot().stats().num_chunks()))
        })
    }

    /// Writes every chunk to an `.rrd` file (atomically); returns the bytes written. The
    /// recording keeps the store info it was read with; `recording_id` renames it (and
    /// names one that had none, as `application_id` does).
    #[pyo3(signature = (path, application_id = "chunkstore", recording_id = None, storage_options = None))]
    fn write_rrd(
        &self,
        py: Python<'_>,
        path: PathBuf,
        application_id: &str,
        recording_id: Option<String>,
        storage_options: Option<Vec<(String, String)>>,
    ) -> PyResult<u64> {
        let storage = crate::open::storage_from(storage_options);
        py.detach(|| {
            no_panic(|| {
                self.refuse_overwriting_source(&path)?;
                let snapshot = self.snapshot()?;
                let mut info = self.store_info.lock().clone().unwrap_or_else(|| {
                    let recording = path.file_stem().map_or_else(
                        || "recording".to_owned(),
                        |s| s.to_string_lossy().into_owned(),
                    );
                    StoreInfo::new(StoreId::recording(application_id, recording))
                });
                if let Some(recording_id) = recording_id {
                    info.store_id.recording_id = recording_id.into();
                }
                written(
                    &path,
                    &storage,
                    |out| {
                        chunkstore::rrd::write_rrd_file(
                            out,
                            &info,
                            snapshot.export_chunks(),
                            |_| {},
                        )
                    },
                    rrd_error,
                )
            })
        })
    }

    /// Writes a dataframe view to a Parquet file (atomically); returns the rows written.
    #[pyo3(signature = (path, args, row_group_rows = None, storage_options = None))]
    fn write_parquet(
        &self,
        py: Python<'_>,
        path: PathBuf,
        args: DataframeArgs,
        row_group_rows: Option<usize>,
        storage_options: Option<Vec<(String, String)>>,
    ) -> PyResult<u64> {
        let storage = crate::open::storage_from(storage_options);
        let query = args.query()?;
        let sampled = args.is_sampled();
        let index = args.index();
        let mut options = ParquetOptions::default();
        if !sampled {
            // A sampled table's rows follow the values given, not the index.
            options = options.with_sorted_by(index);
        }
        if let Some(rows) = row_group_rows {
            if rows == 0 {
                return Err(invalid("row_group_rows must be at least 1"));
            }
            options = options.with_row_group_rows(rows);
        }
        py.detach(|| self.refuse_overwriting_source(&path))?;
        self.with_snapshot(py, move |view| {
            let stream = view.dataframe(&query).map_err(dataframe_error)?;
            let summary = written(
                &path,
                &storage,
                |out| write_parquet_file(out, stream, &options),
                |out, e| match e {
                    chunkstore::parquet::ParquetExportError::Io { path, source } => {
                        os_error(&path, source)
                    }
                    other => Error::new_err(format!("{}: {other}", out.display())),
                },
            )?;
            Ok(summary.rows)
        })
    }
}

/// Writes the output `out` with `write` (a local file; for a URL, staged and uploaded
/// whole: `chunkstore::storage::write_output`), `error` turning the writer's error into
/// Python's.
fn written<T, E>(
    out: &Path,
    storage: &StorageOptions,
    write: impl FnOnce(&Path) -> Result<T, E>,
    error: impl FnOnce(&Path, E) -> PyErr,
) -> PyResult<T> {
    // Python's Ctrl-C is not seen while the GIL is released: an upload runs to its end or
    // its error (an error aborts it).
    let never = Arc::new(std::sync::atomic::AtomicBool::new(false));
    chunkstore::storage::write_output(out, storage, &never, write).map_err(|e| match e {
        OutputError::Write(e) => error(out, e),
        OutputError::Upload(e) => os_error(out, e.into_io()),
    })
}

/// The list type of a component's column, when no answer carries it: the type of its
/// newest cell on any timeline (a lookup per timeline; a lazy recording decodes the one
/// or two chunks that hold it), so that a missing answer has the same type whether the
/// store is lazy or loaded.
fn list_type(source: &mut Reader<'_>, entity: &EntityPath, component: &str) -> DataType {
    for timeline in source.reads.timelines() {
        let query = LatestAtQuery::new(timeline.name(), TimeInt::MAX);
        // A chunk that cannot be decoded leaves the fallback below; the query that needs
        // it reports the error.
        if let Ok(Some(cell)) = source.reads.latest_at(&query, entity, component) {
            return cell.column().list_array().data_type().clone();
        }
    }
    DataType::List(Arc::new(Field::new_list_field(DataType::Null, true)))
}
