//! Datasets (feature `rrd`): many recordings, one `.rrd` file each, queried as one table
//! with a segment column, as Rerun's catalog serves them (SEMANTICS.md section 15).
//!
//! A dataset is a directory (its regular `*.rrd` files, not its subdirectories) or a list
//! of `.rrd` files. Each file is a *segment*, named by its recording id (from the file's
//! store info, never its name). Opening reads each file's footer only, on several threads;
//! a file without a footer is read once, whole, and kept in the segment cache if it fits.
//! Queries load the segments they need one at a time into a store, through a cache of
//! loaded segments bounded by a byte budget ([`DatasetOptions::memory_budget`]), so a
//! dataset far larger than memory is read in bounded memory.
//!
//! The files: `open.rs` lists a directory and opens each file (on `threads.rs`'s worker
//! threads), `index_cache.rs` keeps the index of a file without a footer, `segment.rs`
//! reads a segment for a query (whole, cached, or the chunks it needs through the footer,
//! as `prune.rs` picks them), `schema.rs` plans the tables' columns, `stream.rs` streams a
//! query's rows segment by segment, `hive.rs` writes a Hive copy.
//!
//! ```no_run
//! use chunkstore::dataset::{Dataset, DatasetOptions};
//! use chunkstore::DataframeQuery;
//!
//! let dataset = Dataset::open("episodes/".as_ref(), &DatasetOptions::default())?;
//! for segment in dataset.segments() {
//!     println!("{} ({} rows)", segment.id, segment.num_rows);
//! }
//! let stream = dataset.dataframe(&DataframeQuery::new("frame"))?;
//! let rows: usize = stream.map(|batch| batch.map_or(0, |b| b.num_rows())).sum();
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod cache;
mod error;
#[cfg(feature = "parquet")]
mod hive;
mod index_cache;
mod open;
mod prune;
mod remote;
mod schema;
mod segment;
mod stream;
mod threads;

use std::path::PathBuf;
use std::sync::Arc;

use parking_lot::Mutex;

pub use error::DatasetError;
#[cfg(feature = "parquet")]
pub use hive::SEGMENT_PARTITION_KEY;
pub use open::is_dataset_dir;
pub use schema::DatasetTables;
#[cfg(feature = "datafusion")]
pub(crate) use schema::Placed;
use segment::SegmentRead;
pub use stream::DatasetStream;

use crate::recording::{LoadFault, LoadObserver, OpenOptions, Recording, RecordingReader};
use crate::rrd::StoreId;
use crate::storage::StorageOptions;
use crate::{EntityPath, Snapshot, StoreConfig, TimeRange, TimeType, Timeline};
use cache::SegmentCache;

/// Segments read at once, at least, from a dataset in an object store
/// ([`Dataset::read_threads`]). A read there mostly waits: with 20 ms added to each
/// request, a 1% range of a thousand segments took 30 s on the machine's 2 threads, 2.1 s
/// on 16 and 1.4–1.5 s on 64 (1.3 s with no latency added, where the two cores are the
/// bound); 128 were no faster and held 50 MiB more (docs/performance-log.md).
pub const OBJECT_READ_THREADS: usize = 64;

/// How to open a dataset: from [`DatasetOptions::default`] with the `with_*` methods (the
/// struct may gain fields).
///
/// ```
/// use chunkstore::dataset::DatasetOptions;
/// let options = DatasetOptions::default().with_memory_budget(512 << 20).with_threads(4);
/// assert_eq!((options.memory_budget, options.threads), (512 << 20, 4));
/// ```
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct DatasetOptions {
    /// The configuration of each segment's store when loaded.
    pub config: StoreConfig,
    /// Skip what cannot be read (a file that is not a readable `.rrd`, a bad message or
    /// chunk inside one), with a warning ([`Dataset::take_warnings`]), and answer from the
    /// rest; without it the first such fault is the error.
    pub skip_bad: bool,
    /// Bytes of loaded segments kept between uses (least recently used first out). A
    /// segment larger than this is loaded for each use and never kept.
    pub memory_budget: u64,
    /// Threads that read footers when the dataset opens (at least 1).
    pub threads: usize,
    /// Where to keep the index of each file without a footer (`dataset/index_cache.rs`):
    /// such a file is scanned once and its detached index written here (never beside the
    /// data), so that later opens read the index, not the file, and queries read the file
    /// in part. An object in a bucket is known by its URL, size and `ETag`. `None` (the
    /// default): such a file is read whole at every open. Not used with `skip_bad`, which
    /// reads such a file whole to skip what is bad in it.
    pub index_cache: Option<PathBuf>,
    /// Options of the object store a dataset named by URL is in ([`crate::storage`]).
    pub storage: StorageOptions,
}

impl Default for DatasetOptions {
    /// The default store configuration, nothing skipped, a quarter of the machine's memory
    /// for loaded segments, one footer-reading thread per core.
    fn default() -> Self {
        Self {
            config: StoreConfig::DEFAULT,
            skip_bad: false,
            memory_budget: default_memory_budget(),
            threads: std::thread::available_parallelism().map_or(1, usize::from),
            index_cache: None,
            storage: StorageOptions::default(),
        }
    }
}

impl DatasetOptions {
    /// With each segment's store configuration.
    #[must_use]
    pub fn with_config(mut self, config: StoreConfig) -> Self {
        self.config = config;
        self
    }

    /// Skipping what cannot be read, or not ([`DatasetOptions::skip_bad`]).
    #[must_use]
    pub fn with_skip_bad(mut self, skip_bad: bool) -> Self {
        self.skip_bad = skip_bad;
        self
    }

    /// With this many bytes of loaded segments kept ([`DatasetOptions::memory_budget`]).
    #[must_use]
    pub fn with_memory_budget(mut self, bytes: u64) -> Self {
        self.memory_budget = bytes;
        self
    }

    /// With this many threads reading footers (at least 1).
    #[must_use]
    pub fn with_threads(mut self, threads: usize) -> Self {
        self.threads = threads.max(1);
        self
    }

    /// Keeping the indices of files without a footer in `dir`
    /// ([`DatasetOptions::index_cache`]).
    #[must_use]
    pub fn with_index_cache(mut self, dir: impl Into<PathBuf>) -> Self {
        self.index_cache = Some(dir.into());
        self
    }

    /// With the options of the object store a dataset named by URL is in.
    #[must_use]
    pub fn with_storage(mut self, storage: StorageOptions) -> Self {
        self.storage = storage;
        self
    }
}

/// A quarter of the machine's memory (`/proc/meminfo`), or 1 GiB where it cannot be read.
fn default_memory_budget() -> u64 {
    const FALLBACK: u64 = 1 << 30;
    let Ok(text) = std::fs::read_to_string("/proc/meminfo") else {
        return FALLBACK;
    };
    text.lines()
        .find_map(|line| line.strip_prefix("MemTotal:"))
        .and_then(|rest| rest.trim().strip_suffix("kB"))
        .and_then(|kib| kib.trim().parse::<u64>().ok())
        .map_or(FALLBACK, |kib| kib.saturating_mul(1024) / 4)
}

/// What a dataset knows of one segment from its file's footer (or, for a file without
/// one, from reading it once).
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct SegmentInfo {
    /// The recording id: the segment's name.
    pub id: String,
    /// The application that logged it.
    pub application_id: String,
    /// The file.
    pub path: PathBuf,
    /// Every timeline of its data, sorted by name, with the times its data spans.
    pub timelines: Vec<(Timeline, TimeRange)>,
    /// Every entity with data, sorted.
    pub entities: Vec<EntityPath>,
    /// Chunks in the file (for a file without a footer: in its loaded store).
    pub num_chunks: u64,
    /// Of them, static.
    pub num_static_chunks: u64,
    /// Rows in all.
    pub num_rows: u64,
    /// The file's size in bytes.
    pub file_bytes: u64,
    /// Was this read from the footer (`false`: the file has none and was read whole, or
    /// its index was read from the index cache)?
    pub from_footer: bool,
    /// For a file without a footer, its index in
    /// [`DatasetOptions::index_cache`]: the file is read through it, as through a footer.
    pub index_file: Option<PathBuf>,
}

impl SegmentInfo {
    /// The type of `timeline` in this segment, if its data is on it.
    pub fn time_type(&self, timeline: &str) -> Option<TimeType> {
        self.timelines
            .iter()
            .find(|(t, _)| t.name() == timeline)
            .map(|(t, _)| t.time_type())
    }

    /// The times the segment's data spans on `timeline`, if any is there.
    pub fn time_range(&self, timeline: &str) -> Option<TimeRange> {
        self.timelines
            .iter()
            .find(|(t, _)| t.name() == timeline)
            .map(|(_, range)| *range)
    }

    /// What a dataset knows of the recording `store` names, in the file at `path` of
    /// `file_bytes` bytes, read through `reader`: its footer (`from_footer`), or its store
    /// after a whole read or from an index.
    fn read(
        path: &std::path::Path,
        store: &StoreId,
        reader: &RecordingReader<'_>,
        file_bytes: u64,
        from_footer: bool,
    ) -> Self {
        let timelines = reader
            .timelines()
            .into_iter()
            .filter_map(|t| Some((t.clone(), reader.time_range(t.name())?)))
            .collect();
        let (num_rows, num_chunks) = reader.num_rows_and_chunks();
        Self {
            id: store.recording_id.to_string(),
            application_id: store.application_id.to_string(),
            path: path.to_owned(),
            timelines,
            entities: reader.entity_paths(),
            num_chunks,
            num_static_chunks: reader.num_static_chunks(),
            num_rows,
            file_bytes,
            from_footer,
            index_file: None,
        }
    }
}

/// Many recordings queried as one: see the module docs. Cheap to clone (the clones share
/// the segments and the cache).
#[derive(Clone, Debug)]
pub struct Dataset {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    /// Sorted by id.
    segments: Vec<SegmentInfo>,
    options: DatasetOptions,
    cache: Mutex<SegmentCache>,
    warnings: Mutex<Vec<String>>,
    read: Mutex<ReadStats>,
    /// The tables' columns, once planned ([`Dataset::tables`]).
    tables: Mutex<Option<Arc<DatasetTables>>>,
    /// Per segment in an object store, its object with the footer fetched when the dataset
    /// opened: a query reads its chunks without fetching the footer again.
    #[cfg(feature = "object-store")]
    objects: Vec<Option<crate::storage::object::ObjectReader>>,
}

/// What a dataset's queries have read from its files so far ([`Dataset::read_stats`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct ReadStats {
    /// Times a segment was read from its file (whole, or the chunks a query needed).
    pub segment_reads: u64,
    /// Chunks decoded.
    pub chunks_decoded: u64,
    /// Bytes read from the files.
    pub bytes_read: u64,
    /// GET requests made to an object store for them (0 for local files): one per
    /// coalesced range of the chunks a query needs, or one for a whole object.
    pub requests: u64,
    /// Bytes those requests brought (0 for local files; see
    /// [`LazyStats::bytes_fetched`](crate::rrd::LazyStats::bytes_fetched)).
    pub bytes_fetched: u64,
}

impl ReadStats {
    /// Adds `other`'s counts to these.
    pub fn add(&mut self, other: Self) {
        self.segment_reads += other.segment_reads;
        self.chunks_decoded += other.chunks_decoded;
        self.bytes_read += other.bytes_read;
        self.requests += other.requests;
        self.bytes_fetched += other.bytes_fetched;
    }

    /// What was read between `earlier` and these counts.
    #[must_use]
    pub fn since(&self, earlier: &Self) -> Self {
        Self {
            segment_reads: self.segment_reads - earlier.segment_reads,
            chunks_decoded: self.chunks_decoded - earlier.chunks_decoded,
            bytes_read: self.bytes_read - earlier.bytes_read,
            requests: self.requests - earlier.requests,
            bytes_fetched: self.bytes_fetched - earlier.bytes_fetched,
        }
    }
}

/// One file opened: its segment, and its store if it had to be read whole.
struct Opened {
    info: SegmentInfo,
    loaded: Option<Snapshot>,
    /// Its object, for a segment in an object store read through its footer.
    #[cfg(feature = "object-store")]
    object: Option<crate::storage::object::ObjectReader>,
}

impl Opened {
    fn new(info: SegmentInfo, loaded: Option<Snapshot>) -> Self {
        Self {
            info,
            loaded,
            #[cfg(feature = "object-store")]
            object: None,
        }
    }
}

impl Dataset {
    /// The segments, sorted by id.
    pub fn segments(&self) -> &[SegmentInfo] {
        &self.inner.segments
    }

    /// The segment with this id.
    pub fn segment(&self, id: &str) -> Option<&SegmentInfo> {
        let position = self.position(id)?;
        self.inner.segments.get(position)
    }

    fn position(&self, id: &str) -> Option<usize> {
        self.inner
            .segments
            .binary_search_by(|s| s.id.as_str().cmp(id))
            .ok()
    }

    /// Every timeline of any segment, sorted by name.
    pub fn timelines(&self) -> Vec<Timeline> {
        let mut timelines: Vec<Timeline> = self
            .inner
            .segments
            .iter()
            .flat_map(|s| s.timelines.iter().map(|(t, _)| t.clone()))
            .collect();
        timelines.sort();
        timelines.dedup();
        timelines
    }

    /// The type of `timeline` in the segments whose data is on it (one type: checked on
    /// opening).
    pub fn time_type(&self, timeline: &str) -> Option<TimeType> {
        self.inner
            .segments
            .iter()
            .find_map(|s| s.time_type(timeline))
    }

    /// The times the dataset's data spans on `timeline`, over all segments.
    pub fn time_range(&self, timeline: &str) -> Option<TimeRange> {
        self.inner
            .segments
            .iter()
            .filter_map(|s| s.time_range(timeline))
            .reduce(TimeRange::union)
    }

    /// Every entity of any segment, sorted.
    pub fn entity_paths(&self) -> Vec<EntityPath> {
        let mut entities: Vec<EntityPath> = self
            .inner
            .segments
            .iter()
            .flat_map(|s| s.entities.iter().cloned())
            .collect();
        entities.sort();
        entities.dedup();
        entities
    }

    /// The options it was opened with.
    pub fn options(&self) -> &DatasetOptions {
        &self.inner.options
    }

    /// Segments a query reads at once: [`DatasetOptions::threads`], and at least
    /// [`OBJECT_READ_THREADS`] when any segment is in an object store (a read there waits
    /// on the network far longer than it decodes).
    pub fn read_threads(&self) -> usize {
        let threads = self.inner.options.threads.max(1);
        if self.in_object_store() {
            return threads.max(OBJECT_READ_THREADS);
        }
        threads
    }

    /// Whether any segment is read from an object store (each read a request).
    #[cfg_attr(
        not(feature = "object-store"),
        expect(
            clippy::unused_self,
            reason = "no segment is in one without the feature"
        )
    )]
    pub(crate) fn in_object_store(&self) -> bool {
        #[cfg(feature = "object-store")]
        if self.inner.objects.iter().any(Option::is_some) {
            return true;
        }
        false
    }

    /// Opens one segment as a recording (lazily through its footer where it has one), for
    /// its reads: [`Recording::reader`]'s latest-at, range and discovery.
    ///
    /// # Errors
    /// [`DatasetError::UnknownSegment`], or the file's fault.
    pub fn recording(&self, id: &str) -> Result<Recording, DatasetError> {
        let segment = self
            .segment(id)
            .ok_or_else(|| self.unknown_segment_error(id))?;
        let options = self.open_options(&segment.id);
        let mut observer = Warnings(&self.inner.warnings);
        Ok(Recording::open(&segment.path, &options, &mut observer)?)
    }

    /// The error for a segment id the dataset does not have.
    pub fn unknown_segment_error(&self, id: &str) -> DatasetError {
        DatasetError::UnknownSegment {
            id: id.to_owned(),
            num_segments: self.inner.segments.len(),
        }
    }

    /// The error for an index no segment has, naming the dataset's timelines.
    pub(crate) fn unknown_index_error(&self, index: &str) -> DatasetError {
        DatasetError::UnknownIndex(crate::UnknownTimeline::new(index, &self.timelines()))
    }

    /// What queries have read from the files so far (opening aside).
    pub fn read_stats(&self) -> ReadStats {
        *self.inner.read.lock()
    }

    /// The warnings of what was skipped so far ([`DatasetOptions::skip_bad`]), each once.
    pub fn take_warnings(&self) -> Vec<String> {
        std::mem::take(&mut *self.inner.warnings.lock())
    }

    fn open_options(&self, id: &str) -> OpenOptions {
        OpenOptions {
            config: self.inner.options.config,
            skip_bad: self.inner.options.skip_bad,
            recording: Some(id.to_owned()),
            storage: self.inner.options.storage.clone(),
            ..OpenOptions::default()
        }
    }
}

/// Passes the faults a load skips to the dataset's warnings.
struct Warnings<'a>(&'a Mutex<Vec<String>>);

impl LoadObserver for Warnings<'_> {
    fn skipped(&mut self, fault: &LoadFault) {
        self.0.lock().push(fault.to_string());
    }
}
