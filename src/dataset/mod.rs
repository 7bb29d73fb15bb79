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
mod prune;
mod schema;
mod stream;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use parking_lot::Mutex;

pub use error::DatasetError;
#[cfg(feature = "parquet")]
pub use hive::SEGMENT_PARTITION_KEY;
pub use schema::DatasetTables;
#[cfg(feature = "datafusion")]
pub(crate) use schema::Placed;
pub use stream::DatasetStream;

use crate::recording::{
    LoadFault, LoadObserver, LoadedRecording, OpenError, OpenOptions, Recording,
};
use crate::rrd::{LazyRecording, StoreInfo};
use crate::{EntityPath, Snapshot, StoreConfig, TimeRange, TimeType, Timeline};
use cache::SegmentCache;

pub use crate::dataframe::SEGMENT_ID_COLUMN;

/// How to open a dataset.
#[derive(Clone, Debug)]
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
    /// in part. `None` (the default): such a file is read whole at every open. Not used
    /// with `skip_bad`, which reads such a file whole to skip what is bad in it.
    pub index_cache: Option<PathBuf>,
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
        }
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
}

impl ReadStats {
    /// Adds `other`'s counts to these.
    pub fn add(&mut self, other: Self) {
        self.segment_reads += other.segment_reads;
        self.chunks_decoded += other.chunks_decoded;
        self.bytes_read += other.bytes_read;
    }
}

/// What a query read of one segment.
pub(crate) struct SegmentRead {
    /// The store of what was read: the whole segment, or the chunks the query needs.
    pub snapshot: Snapshot,
    /// Is it kept for the rows' pass (see [`Dataset::segment_for`])?
    pub keep: bool,
    /// What was read from the file for it (nothing when the cache had it).
    pub read: ReadStats,
}

/// One file opened: its segment, and its store if it had to be read whole.
struct Opened {
    info: SegmentInfo,
    loaded: Option<Snapshot>,
}

impl Dataset {
    /// Opens a dataset directory (its regular `*.rrd` files) or a single `.rrd` file,
    /// reading footers only.
    ///
    /// # Errors
    /// A directory without `.rrd` files, a file that cannot be opened (unless skipped),
    /// two files of one recording, a timeline of different types in two segments.
    pub fn open(path: &Path, options: &DatasetOptions) -> Result<Self, DatasetError> {
        let files = if std::fs::metadata(path)
            .map_err(|source| DatasetError::Io {
                path: path.to_owned(),
                source,
            })?
            .is_dir()
        {
            rrd_files(path, options.index_cache.as_deref())?
        } else {
            (vec![path.to_owned()], Vec::new())
        };
        let (files, notes) = files;
        if files.is_empty() {
            return Err(DatasetError::NoRrdFiles {
                dir: path.to_owned(),
            });
        }
        Self::open_files_noting(&files, options, notes)
    }

    /// Opens a dataset of these `.rrd` files.
    ///
    /// # Errors
    /// As [`Dataset::open`].
    pub fn open_files(files: &[PathBuf], options: &DatasetOptions) -> Result<Self, DatasetError> {
        Self::open_files_noting(files, options, Vec::new())
    }

    /// [`Dataset::open_files`], with warnings from listing the directory first.
    fn open_files_noting(
        files: &[PathBuf],
        options: &DatasetOptions,
        notes: Vec<String>,
    ) -> Result<Self, DatasetError> {
        if files.is_empty() {
            return Err(DatasetError::NoRrdFiles {
                dir: PathBuf::new(),
            });
        }
        let warnings = Mutex::new(notes);
        let results = in_parallel(files, options.threads, |path| {
            open_file(path, options, &warnings)
        });
        let mut opened = Vec::with_capacity(files.len());
        for (path, result) in files.iter().zip(results) {
            match result {
                Ok(file) => opened.push(file),
                Err(error) if options.skip_bad => {
                    warnings
                        .lock()
                        .push(format!("skipped {}: {error}", path.display()));
                }
                Err(error) => return Err(error),
            }
        }
        opened.sort_by(|a, b| a.info.id.cmp(&b.info.id));
        if let Some(pair) = opened.windows(2).find(|w| w[0].info.id == w[1].info.id) {
            if !options.skip_bad {
                return Err(DatasetError::DuplicateRecording {
                    id: pair[0].info.id.clone(),
                    first: pair[0].info.path.clone(),
                    second: pair[1].info.path.clone(),
                });
            }
            // With skip_bad, a second file of a recording is a bad file like any other:
            // the first (in path order) stays.
            let mut kept: Vec<Opened> = Vec::with_capacity(opened.len());
            for file in opened {
                match kept.last() {
                    Some(last) if last.info.id == file.info.id => warnings.lock().push(format!(
                        "skipped {}: recording {:?} is in {} already",
                        file.info.path.display(),
                        file.info.id,
                        last.info.path.display()
                    )),
                    _ => kept.push(file),
                }
            }
            opened = kept;
        }
        check_timeline_types(opened.iter().map(|o| &o.info))?;
        let mut cache = SegmentCache::new(options.memory_budget);
        for (number, file) in opened.iter_mut().enumerate() {
            if let Some(snapshot) = file.loaded.take() {
                cache.insert(number, snapshot);
            }
        }
        Ok(Self {
            inner: Arc::new(Inner {
                segments: opened.into_iter().map(|o| o.info).collect(),
                options: options.clone(),
                cache: Mutex::new(cache),
                warnings,
                read: Mutex::new(ReadStats::default()),
                tables: Mutex::new(None),
            }),
        })
    }

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

    /// Counts a read in the dataset's stats; returns it alone.
    fn count_read(&self, chunks: u64, bytes: u64) -> ReadStats {
        let this = ReadStats {
            segment_reads: 1,
            chunks_decoded: chunks,
            bytes_read: bytes,
        };
        self.inner.read.lock().add(this);
        this
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
            ..OpenOptions::default()
        }
    }

    /// Segment number `number` loaded whole, from the cache or from its file.
    pub(crate) fn loaded_segment(
        &self,
        number: usize,
    ) -> Result<(Snapshot, ReadStats), DatasetError> {
        if let Some(snapshot) = self.inner.cache.lock().get(number) {
            return Ok((snapshot, ReadStats::default()));
        }
        let segment = &self.inner.segments[number];
        let options = OpenOptions {
            lazy: false,
            ..self.open_options(&segment.id)
        };
        let mut observer = Warnings(&self.inner.warnings);
        let loaded = LoadedRecording::load(&segment.path, &options, &mut observer)?;
        let read = self.count_read(segment.num_chunks, segment.file_bytes);
        let snapshot = loaded.store.snapshot();
        self.inner.cache.lock().insert(number, snapshot.clone());
        Ok((snapshot, read))
    }

    /// Can segment number `number` be read in part, through its footer's manifest? Not
    /// without a footer, nor with `skip_bad` (a bad chunk is skipped, which only a whole
    /// load does).
    fn reads_in_part(&self, number: usize) -> bool {
        let segment = &self.inner.segments[number];
        (segment.from_footer || segment.index_file.is_some()) && !self.inner.options.skip_bad
    }

    /// Segment number `number`'s file opened through its footer; `None` when it has none.
    fn footer(&self, number: usize) -> Result<Option<LazyRecording>, DatasetError> {
        let segment = &self.inner.segments[number];
        match &segment.index_file {
            Some(index) => LazyRecording::open_indexed(&segment.path, index, Some(&segment.id)),
            None => LazyRecording::open_recording(&segment.path, Some(&segment.id)),
        }
        .map_err(|error| OpenError::rrd(&segment.path, error).into())
    }

    /// The chunks of segment number `number` that `pick` picks from its manifest, read
    /// through its footer; `None` when the file has no footer to read them by.
    fn read_part(
        &self,
        number: usize,
        pick: impl FnOnce(&crate::rrd::Manifest) -> PickedChunks,
    ) -> Result<Option<(Snapshot, ReadStats, PickedChunks)>, DatasetError> {
        let Some(mut lazy) = self.footer(number)? else {
            return Ok(None);
        };
        let segment = &self.inner.segments[number];
        let picked = pick(lazy.manifest());
        let store = lazy
            .load_where(|entry| picked.chunks.contains(&entry.chunk_id))
            .map_err(|error| OpenError::rrd(&segment.path, error))?;
        let snapshot = store.snapshot();
        let stats = lazy.stats();
        let read = self.count_read(stats.chunks_decoded as u64, stats.bytes_read);
        Ok(Some((snapshot, read, picked)))
    }

    /// The chunks of segment number `number` that `pick` picks from its manifest (the
    /// whole segment where it cannot be read in part, or is kept).
    pub(crate) fn segment_chunks(
        &self,
        number: usize,
        pick: impl FnOnce(&crate::rrd::Manifest) -> std::collections::HashSet<crate::ChunkId>,
    ) -> Result<(Snapshot, ReadStats), DatasetError> {
        if let Some(snapshot) = self.inner.cache.lock().get(number) {
            return Ok((snapshot, ReadStats::default()));
        }
        if self.reads_in_part(number) {
            let part = self.read_part(number, |manifest| PickedChunks {
                chunks: pick(manifest),
                kept: false,
            })?;
            if let Some((snapshot, read, _)) = part {
                return Ok((snapshot, read));
            }
        }
        self.loaded_segment(number)
    }

    #[cfg(feature = "datafusion")]
    /// How many chunks of these segments (by number) reads for `query`'s rows decode (see
    /// [`Dataset::chunks_counted`]).
    ///
    /// # Errors
    /// A footer that cannot be read (its file changed since the dataset opened).
    pub(crate) fn chunks_for_rows(
        &self,
        numbers: &[usize],
        query: &crate::DataframeQuery,
    ) -> Result<u64, DatasetError> {
        self.chunks_counted(numbers, prune::prunable(query), |manifest| {
            prune::needed(manifest, query, prune::Needs::Rows).len()
        })
    }

    #[cfg(feature = "datafusion")]
    /// How many chunks of these segments (by number) `keep` keeps of their manifests (see
    /// [`Dataset::chunks_counted`]).
    ///
    /// # Errors
    /// A footer that cannot be read (its file changed since the dataset opened).
    pub(crate) fn chunks_picked(
        &self,
        numbers: &[usize],
        keep: impl Fn(&crate::rrd::ManifestEntry) -> bool + Sync,
    ) -> Result<u64, DatasetError> {
        self.chunks_counted(numbers, true, |manifest| {
            manifest.entries.iter().filter(|e| keep(e)).count()
        })
    }

    #[cfg(feature = "datafusion")]
    /// The chunks `count` counts in these segments' manifests, read from their footers on
    /// the dataset's threads; a segment read whole (no footer, `skip_bad`, or `in_part`
    /// false) counts all its chunks.
    fn chunks_counted(
        &self,
        numbers: &[usize],
        in_part: bool,
        count: impl Fn(&crate::rrd::Manifest) -> usize + Sync,
    ) -> Result<u64, DatasetError> {
        let counts = in_parallel(numbers, self.inner.options.threads, |&number| {
            if in_part
                && self.reads_in_part(number)
                && let Some(lazy) = self.footer(number)?
            {
                return Ok(count(lazy.manifest()) as u64);
            }
            Ok::<_, DatasetError>(self.inner.segments[number].num_chunks)
        });
        counts.into_iter().sum()
    }

    /// What segment number `number` holds that `query` needs: the whole segment if it is
    /// kept, else, through its footer, only the chunks the query needs (`prune.rs`; not
    /// kept in the cache, they are the query's); the whole segment where that cannot be
    /// told.
    ///
    /// For planning (`plan_room`: the bytes the query may still keep until it reads its
    /// rows), the rows' chunks are read too if they fit in that room, which they then
    /// take; otherwise only the columns' chunks. Without a room, for the rows, only the
    /// rows' chunks: the store may lack columns (and the index) the segment has, which
    /// hold nothing in the rows. Says whether what was read is kept for the rows (never
    /// without a room).
    pub(crate) fn segment_for(
        &self,
        number: usize,
        query: &crate::DataframeQuery,
        plan_room: Option<&AtomicU64>,
    ) -> Result<SegmentRead, DatasetError> {
        let reserve = |bytes: u64| {
            plan_room.is_some_and(|room| {
                room.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |left| {
                    left.checked_sub(bytes)
                })
                .is_ok()
            })
        };
        let whole = |(snapshot, read): (Snapshot, ReadStats)| {
            let keep = reserve(snapshot.stats().heap_bytes);
            SegmentRead {
                snapshot,
                keep,
                read,
            }
        };
        if let Some(snapshot) = self.inner.cache.lock().get(number) {
            return Ok(whole((snapshot, ReadStats::default())));
        }
        if self.reads_in_part(number) && prune::prunable(query) {
            let part = self.read_part(number, |manifest| {
                if plan_room.is_none() {
                    return PickedChunks {
                        chunks: prune::needed(manifest, query, prune::Needs::Rows),
                        kept: false,
                    };
                }
                let both = prune::needed(manifest, query, prune::Needs::Both);
                let bytes = manifest
                    .entries
                    .iter()
                    .filter(|e| both.contains(&e.chunk_id))
                    .map(|e| e.uncompressed_size)
                    .sum();
                if reserve(bytes) {
                    PickedChunks {
                        chunks: both,
                        kept: true,
                    }
                } else {
                    PickedChunks {
                        chunks: prune::needed(manifest, query, prune::Needs::Columns),
                        kept: false,
                    }
                }
            })?;
            if let Some((snapshot, read, picked)) = part {
                // For the rows, a store without the index holds none. For planning, where
                // none of the chunks it needs is on the index, the segment's own view (its
                // columns, which other timelines give) needs the whole segment.
                if plan_room.is_none() || snapshot.time_type(query.index()).is_some() {
                    return Ok(SegmentRead {
                        snapshot,
                        keep: picked.kept,
                        read,
                    });
                }
            }
        }
        self.loaded_segment(number).map(whole)
    }
}

/// The chunks a read of part of a segment picked, and whether they are kept for the rows.
pub(crate) struct PickedChunks {
    chunks: std::collections::HashSet<crate::ChunkId>,
    kept: bool,
}

/// Passes the faults a load skips to the dataset's warnings.
struct Warnings<'a>(&'a Mutex<Vec<String>>);

impl LoadObserver for Warnings<'_> {
    fn skipped(&mut self, fault: &LoadFault) {
        self.0.lock().push(fault.to_string());
    }
}

/// The regular `.rrd` files directly in `dir`, sorted by name, each file once (a link to
/// a file beside it is the same file); and what to warn of: the links left out, the
/// subdirectories holding `.rrd` files but `index_cache` (a dataset is the files directly
/// in `dir`).
fn rrd_files(
    dir: &Path,
    index_cache: Option<&Path>,
) -> Result<(Vec<PathBuf>, Vec<String>), DatasetError> {
    let cache = index_cache.and_then(|c| std::fs::canonicalize(c).ok());
    let io = |source| DatasetError::Io {
        path: dir.to_owned(),
        source,
    };
    // Each `.rrd` file with whether its entry is a link (the entry says so: no call).
    let mut files: Vec<(PathBuf, bool)> = Vec::new();
    let mut subdirectories = 0usize;
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let entry = entry.map_err(io)?;
        let is_link = entry.file_type().is_ok_and(|kind| kind.is_symlink());
        let path = entry.path();
        if is_rrd_name(&path) && path.is_file() {
            files.push((path, is_link));
        } else if path.is_dir()
            && cache.as_deref() != std::fs::canonicalize(&path).ok().as_deref()
            && std::fs::read_dir(&path).is_ok_and(|mut inner| {
                inner.any(|e| e.is_ok_and(|e| is_rrd_name(&e.path()) && e.path().is_file()))
            })
        {
            subdirectories += 1;
        }
    }
    let mut notes = Vec::new();
    if subdirectories > 0 {
        notes.push(format!(
            "{}: {subdirectories} subdirectories hold .rrd files, which are not read (a \
             dataset is the .rrd files directly in the directory)",
            dir.display()
        ));
    }
    // A link to a file of the dataset: the file is read once, under its own name. A
    // regular file's real path is the real directory's and its name; only links need
    // resolving.
    let real_dir = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.to_owned());
    // Real files first, so that a link gives way to the file it names.
    files.sort_by(|a, b| (a.1, &a.0).cmp(&(b.1, &b.0)));
    let mut by_real: ahash::HashMap<PathBuf, PathBuf> = ahash::HashMap::default();
    let mut unique = Vec::with_capacity(files.len());
    for (path, is_link) in files {
        let real = if is_link {
            std::fs::canonicalize(&path).unwrap_or_else(|_| path.clone())
        } else {
            path.file_name()
                .map_or_else(|| path.clone(), |name| real_dir.join(name))
        };
        match by_real.entry(real) {
            std::collections::hash_map::Entry::Occupied(first) => notes.push(format!(
                "{}: the same file as {}, read once",
                path.display(),
                first.get().display()
            )),
            std::collections::hash_map::Entry::Vacant(slot) => {
                slot.insert(path.clone());
                unique.push(path);
            }
        }
    }
    unique.sort();
    Ok((unique, notes))
}

fn is_rrd_name(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("rrd"))
}

/// Does `dir` hold a regular `.rrd` file (is it a dataset directory)? `false` if it
/// cannot be listed.
pub fn is_dataset_dir(dir: &Path) -> bool {
    rrd_files(dir, None).is_ok_and(|(files, _)| !files.is_empty())
}

/// `f` of every item on up to `threads` threads, the results in the items' order.
pub(super) fn in_parallel<T: Sync, R: Send>(
    items: &[T],
    threads: usize,
    f: impl Fn(&T) -> R + Sync,
) -> Vec<R> {
    let threads = threads.clamp(1, items.len().max(1));
    if threads == 1 {
        return items.iter().map(f).collect();
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut results: Vec<(usize, R)> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                scope.spawn(|| {
                    let mut done = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(item) = items.get(i) else {
                            break;
                        };
                        done.push((i, f(item)));
                    }
                    done
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|worker| {
                worker
                    .join()
                    .unwrap_or_else(|p| std::panic::resume_unwind(p))
            })
            .collect()
    });
    results.sort_by_key(|(i, _)| *i);
    results.into_iter().map(|(_, r)| r).collect()
}

/// One file's segment: from its footer, or read whole if it has none.
fn open_file(
    path: &Path,
    options: &DatasetOptions,
    warnings: &Mutex<Vec<String>>,
) -> Result<Opened, DatasetError> {
    let open_error = |error| OpenError::rrd(path, error);
    let metadata = std::fs::metadata(path).map_err(|source| OpenError::Io {
        path: path.to_owned(),
        source,
    })?;
    let file_bytes = metadata.len();
    if crate::recording::SourceKind::detect(path)? != crate::recording::SourceKind::Rrd {
        return Err(DatasetError::NotRrd {
            path: path.to_owned(),
        });
    }
    match LazyRecording::open(path) {
        Ok(Some(lazy)) => {
            let info = lazy
                .store_info()
                .ok_or_else(|| DatasetError::NoRecordingId {
                    path: path.to_owned(),
                })?;
            Ok(Opened {
                info: info_from_footer(path, info, &lazy, file_bytes),
                loaded: None,
            })
        }
        Ok(None) => match &options.index_cache {
            Some(dir) if !options.skip_bad => {
                index_cache::open_indexed(path, dir, options, &metadata)
            }
            _ => load_whole(path, options, warnings, file_bytes),
        },
        Err(error) if error.is_recording_choice() => Err(open_error(error).into()),
        // A corrupt footer: the file may still be read whole, message by message.
        Err(_) if options.skip_bad => load_whole(path, options, warnings, file_bytes),
        Err(error) => Err(OpenError::Footer {
            path: path.to_owned(),
            error,
        }
        .into()),
    }
}

fn load_whole(
    path: &Path,
    options: &DatasetOptions,
    warnings: &Mutex<Vec<String>>,
    file_bytes: u64,
) -> Result<Opened, DatasetError> {
    let open = OpenOptions {
        config: options.config,
        skip_bad: options.skip_bad,
        lazy: false,
        ..OpenOptions::default()
    };
    let loaded = LoadedRecording::load(path, &open, &mut Warnings(warnings))?;
    let info = loaded
        .store_info
        .as_ref()
        .ok_or_else(|| DatasetError::NoRecordingId {
            path: path.to_owned(),
        })?;
    let store = &loaded.store;
    Ok(Opened {
        info: info_from_store(path, info, store, file_bytes),
        loaded: Some(store.snapshot()),
    })
}

/// What a dataset knows of a segment read whole into `store`.
fn info_from_store(
    path: &Path,
    info: &StoreInfo,
    store: &crate::ChunkStore,
    file_bytes: u64,
) -> SegmentInfo {
    let stats = store.stats();
    let timelines = store
        .timelines()
        .into_iter()
        .filter_map(|t| Some((t.clone(), store.time_range(t.name())?)))
        .collect();
    SegmentInfo {
        id: info.store_id.recording_id.to_string(),
        application_id: info.store_id.application_id.to_string(),
        path: path.to_owned(),
        timelines,
        entities: store.entity_paths(),
        num_chunks: stats.num_chunks(),
        num_static_chunks: stats.num_static_chunks,
        num_rows: stats.num_rows(),
        file_bytes,
        from_footer: false,
        index_file: None,
    }
}

fn info_from_footer(
    path: &Path,
    info: &StoreInfo,
    lazy: &LazyRecording,
    file_bytes: u64,
) -> SegmentInfo {
    let entries = &lazy.manifest().entries;
    let timelines = lazy
        .timelines()
        .into_iter()
        .filter_map(|t| Some((t.clone(), lazy.time_range(t.name())?)))
        .collect();
    SegmentInfo {
        id: info.store_id.recording_id.to_string(),
        application_id: info.store_id.application_id.to_string(),
        path: path.to_owned(),
        timelines,
        entities: lazy.entity_paths(),
        num_chunks: entries.len() as u64,
        num_static_chunks: entries.iter().filter(|e| e.is_static).count() as u64,
        num_rows: entries.iter().map(|e| e.num_rows).sum(),
        file_bytes,
        from_footer: true,
        index_file: None,
    }
}

/// A timeline has one type across the segments.
fn check_timeline_types<'a>(
    segments: impl Iterator<Item = &'a SegmentInfo>,
) -> Result<(), DatasetError> {
    let mut seen: ahash::HashMap<&str, (&str, TimeType)> = ahash::HashMap::default();
    for segment in segments {
        for (timeline, _) in &segment.timelines {
            let here = (segment.id.as_str(), timeline.time_type());
            match seen.get(timeline.name()) {
                Some(&(first, time_type)) if time_type != here.1 => {
                    return Err(DatasetError::TimelineTypeConflict {
                        timeline: timeline.name().to_owned(),
                        first: (first.to_owned(), time_type),
                        second: (here.0.to_owned(), here.1),
                    });
                }
                Some(_) => {}
                None => {
                    seen.insert(timeline.name(), here);
                }
            }
        }
    }
    Ok(())
}
