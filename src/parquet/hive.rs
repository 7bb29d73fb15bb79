//! Partitioned Parquet datasets in Hive layout (feature `parquet`): a directory of
//! `key=value/part-0.parquet` files that DuckDB
//! (`read_parquet('dir/**/*.parquet', hive_partitioning = true)`), Polars (`scan_parquet(..., hive_partitioning=True)`),
//! Spark, pyarrow datasets and DataFusion-based engines (Ballista among them) read as
//! one table, skipping the partitions a filter on the key rules out. Every file has the
//! same schema (the whole table's), so no reader has to merge schemas.
//!
//! Two layouts ([`HiveLayout`]):
//! - by entity: the raw chunk table (`StoreView::chunk_table`), one partition per entity,
//!   `entity=<path>/part-0.parquet`, rows in `(time, row id)` order on the timeline given;
//! - by time bucket: one timeline's dataframe view (`StoreView::dataframe`), one
//!   partition per bucket of `width` index values, `<timeline>_bucket=<k>/part-0.parquet`
//!   holding the rows with `k * width <= index < (k + 1) * width` (empty buckets have no
//!   file).
//!
//! Partition values are percent-encoded as Hive encodes them (`/` is `%2F`): DuckDB,
//! Spark, pyarrow and Polars decode them back into the entity path; DataFusion 54 keeps
//! them as written (`%2Fworld%2Frobot`). Every file also holds the `entity_path` column,
//! whose row-group statistics let any engine prune on the path itself. Each file carries
//! the min/max statistics and the sort order of [`write_parquet_file`]; the whole
//! directory appears at once (written under a temporary name and renamed) or not at all.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::{RecordBatch, RecordBatchReader};
use arrow_schema::{ArrowError, DataType, SchemaRef};

use super::file::{ParquetExportError, ParquetOptions, ParquetSummary, write_parquet_file};
use crate::{ChunkTableQuery, ChunkTableStream, DataframeError, DataframeQuery, StoreView};

/// Why a dataset could not be written. Nothing is left under its directory.
#[derive(Debug)]
#[non_exhaustive]
pub enum HiveExportError {
    /// The dataset's directory exists already (a dataset is always a new directory).
    Exists {
        /// The directory.
        dir: PathBuf,
    },
    /// The directory's parent does not exist (a typo in the path makes no directories).
    NoParent {
        /// The directory asked for.
        dir: PathBuf,
        /// Its missing parent.
        parent: PathBuf,
    },
    /// A time bucket narrower than one index value.
    BucketWidth {
        /// The width asked for.
        width: i64,
    },
    /// A [`HiveLayout::ByTimeBucket`] query whose index is not the bucketed timeline.
    QueryIndex {
        /// The query's index.
        index: String,
        /// The bucketed timeline.
        timeline: String,
    },
    /// The store cannot answer the table (an unknown timeline, say).
    Table(DataframeError),
    /// The file system refused (creating a partition, renaming the finished dataset).
    Io {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A partition's file could not be written.
    Write(ParquetExportError),
}

impl std::fmt::Display for HiveExportError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Exists { dir } => write!(f, "{}: the dataset directory exists", dir.display()),
            Self::NoParent { dir, parent } => write!(
                f,
                "{}: the directory {} does not exist",
                dir.display(),
                parent.display()
            ),
            Self::BucketWidth { width } => {
                write!(f, "a time bucket is at least 1 wide, not {width}")
            }
            Self::QueryIndex { index, timeline } => write!(
                f,
                "the query's index {index:?} is not the bucketed timeline {timeline:?}"
            ),
            Self::Table(error) => write!(f, "{error}"),
            Self::Io { path, source } => write!(f, "{}: {source}", path.display()),
            Self::Write(error) => write!(f, "{error}"),
        }
    }
}

impl std::error::Error for HiveExportError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Table(error) => Some(error),
            Self::Io { source, .. } => Some(source),
            Self::Write(error) => Some(error),
            Self::Exists { .. }
            | Self::NoParent { .. }
            | Self::BucketWidth { .. }
            | Self::QueryIndex { .. } => None,
        }
    }
}

impl From<ParquetExportError> for HiveExportError {
    fn from(error: ParquetExportError) -> Self {
        Self::Write(error)
    }
}

/// What [`write_hive_dataset`] checks before it reads anything: `dir` must be new, with an
/// existing parent, and a time bucket at least 1 wide. A caller with a costly source to
/// load checks first.
///
/// # Errors
/// [`HiveExportError::Exists`], [`HiveExportError::NoParent`],
/// [`HiveExportError::BucketWidth`].
pub fn check_new_dataset(dir: &Path, layout: &HiveLayout) -> Result<(), HiveExportError> {
    if dir.exists() {
        return Err(HiveExportError::Exists {
            dir: dir.to_owned(),
        });
    }
    if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty())
        && !parent.is_dir()
    {
        return Err(HiveExportError::NoParent {
            dir: dir.to_owned(),
            parent: parent.to_owned(),
        });
    }
    check_bucket_width(layout)
}

/// A time bucket layout's width must be at least 1 ([`HiveExportError::BucketWidth`]).
pub(crate) fn check_bucket_width(layout: &HiveLayout) -> Result<(), HiveExportError> {
    if let HiveLayout::ByTimeBucket { width, .. } = layout
        && *width < 1
    {
        return Err(HiveExportError::BucketWidth { width: *width });
    }
    Ok(())
}

/// How a dataset is partitioned: see the module docs.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum HiveLayout {
    /// The chunk table, a partition per entity, rows ordered on `timeline` when given.
    ByEntity {
        /// The timeline rows are ordered by within a file (else chunk by chunk).
        timeline: Option<Arc<str>>,
    },
    /// A timeline's dataframe view, a partition per `width` index values.
    ByTimeBucket {
        /// The index timeline.
        timeline: Arc<str>,
        /// Index values per bucket (at least 1).
        width: i64,
        /// The view's query (contents, fill); its index must be `timeline`, and its range
        /// narrows what is written.
        query: Option<DataframeQuery>,
    },
}

/// What a dataset write produced: each partition's file and summary, in order.
#[derive(Clone, Debug, Default)]
#[non_exhaustive]
pub struct HiveSummary {
    /// `(file, what was written to it)` per partition.
    pub files: Vec<(PathBuf, ParquetSummary)>,
}

impl HiveSummary {
    /// Rows written, over every file.
    pub fn rows(&self) -> u64 {
        self.files.iter().map(|(_, s)| s.rows).sum()
    }
}

/// Percent-encodes a partition value as Hive does: every byte outside `[A-Za-z0-9._-]`
/// becomes `%XX`.
///
/// ```
/// assert_eq!(chunkstore::parquet::escape_partition_value("/robot/arm 1"), "%2Frobot%2Farm%201");
/// ```
pub fn escape_partition_value(value: &str) -> String {
    let mut out = String::with_capacity(value.len());
    for byte in value.bytes() {
        if byte.is_ascii_alphanumeric() || matches!(byte, b'.' | b'_' | b'-') {
            out.push(char::from(byte));
        } else {
            const HEX: &[u8; 16] = b"0123456789ABCDEF";
            out.push('%');
            out.push(char::from(HEX[usize::from(byte >> 4)]));
            out.push(char::from(HEX[usize::from(byte & 0xF)]));
        }
    }
    out
}

/// The value [`escape_partition_value`] escaped (a `%` not followed by two hex digits is
/// kept as it is).
///
/// ```
/// use chunkstore::parquet::{escape_partition_value, unescape_partition_value};
/// assert_eq!(unescape_partition_value("%2Frobot%2Farm%201"), "/robot/arm 1");
/// assert_eq!(unescape_partition_value(&escape_partition_value("é/%")), "é/%");
/// ```
pub fn unescape_partition_value(escaped: &str) -> String {
    let bytes = escaped.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut at = 0;
    while at < bytes.len() {
        let hex = |b: u8| char::from(b).to_digit(16);
        if bytes[at] == b'%'
            && let (Some(high), Some(low)) = (
                bytes.get(at + 1).copied().and_then(hex),
                bytes.get(at + 2).copied().and_then(hex),
            )
        {
            // Two hex digits are at most 255.
            out.push(u8::try_from(high * 16 + low).unwrap_or(b'?'));
            at += 3;
        } else {
            out.push(bytes[at]);
            at += 1;
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// How a partition's file is written: its name in its directory, and whether its columns
/// take a Delta table's types (`parquet/delta_types.rs`).
#[derive(Clone, Debug)]
pub(crate) struct PartFile {
    /// The file's name.
    pub name: String,
    /// Cast the columns to their Delta types.
    #[cfg(feature = "rrd")]
    pub delta: bool,
}

impl Default for PartFile {
    fn default() -> Self {
        Self {
            name: "part-0.parquet".into(),
            #[cfg(feature = "rrd")]
            delta: false,
        }
    }
}

impl PartFile {
    /// Writes `reader` to `path` as this says.
    #[cfg_attr(
        not(feature = "rrd"),
        expect(clippy::unused_self, reason = "Delta needs `rrd`")
    )]
    fn write(
        &self,
        path: &Path,
        reader: impl RecordBatchReader,
        options: &ParquetOptions,
    ) -> Result<ParquetSummary, HiveExportError> {
        #[cfg(feature = "rrd")]
        if self.delta {
            let typed = super::delta_types::DeltaTyped::new(reader).map_err(|e| {
                HiveExportError::Write(ParquetExportError::Arrow(ArrowError::InvalidArgumentError(
                    e.to_string(),
                )))
            })?;
            return Ok(write_parquet_file(path, typed, options)?);
        }
        Ok(write_parquet_file(path, reader, options)?)
    }
}

/// Writes `view` as a Hive-partitioned Parquet dataset in the new directory `dir` (which
/// must not exist), laid out as `layout` says. An empty store writes an empty directory.
///
/// # Errors
/// What [`check_new_dataset`] checks, an unknown timeline ([`HiveExportError::Table`]),
/// the file system's errors and the Parquet writer's; nothing is left under `dir` on error.
pub fn write_hive_dataset(
    view: &StoreView,
    dir: &Path,
    layout: &HiveLayout,
) -> Result<HiveSummary, HiveExportError> {
    check_new_dataset(dir, layout)?;
    write_new_directory(dir, |partial| match layout {
        HiveLayout::ByEntity { timeline } => by_entity(view, partial, timeline.as_deref()),
        HiveLayout::ByTimeBucket {
            timeline,
            width,
            query,
        } => by_time_bucket(view, partial, timeline, *width, query.as_ref()),
    })
}

/// Makes the new directory `dir` appear whole or not at all: `write` fills a temporary
/// sibling (registered for [`crate::output::remove_unfinished_outputs`]), which is renamed to `dir`
/// once `write` succeeds and removed when it fails. The summary's files are named under
/// `dir`.
pub(crate) fn write_new_directory<E: From<HiveExportError>>(
    dir: &Path,
    write: impl FnOnce(&Path) -> Result<HiveSummary, E>,
) -> Result<HiveSummary, E> {
    let io = |path: &Path, source| HiveExportError::Io {
        path: path.to_owned(),
        source,
    };
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let partial = dir.with_file_name(format!(".{name}.partial-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&partial);
    // `create_dir`, not `create_dir_all`: a missing parent is an error, as it is for
    // every other output (a typo in the path should not make directories).
    let (_unfinished, ()) =
        crate::output::UnfinishedOutput::create(&partial, |p| std::fs::create_dir(p))
            .map_err(|e| io(&partial, e))?;
    let mut summary = match write(&partial) {
        Ok(summary) => summary,
        Err(error) => {
            let _ = std::fs::remove_dir_all(&partial);
            return Err(error);
        }
    };
    if let Err(error) = std::fs::rename(&partial, dir) {
        let _ = std::fs::remove_dir_all(&partial);
        return Err(io(dir, error).into());
    }
    for (file, _) in &mut summary.files {
        if let Ok(relative) = file.strip_prefix(&partial) {
            *file = dir.join(relative);
        }
    }
    Ok(summary)
}

/// `dir/key=value/<part file>` (the value escaped), its directories made.
fn partition_file(
    dir: &Path,
    key: &str,
    value: &str,
    part: &PartFile,
) -> Result<PathBuf, HiveExportError> {
    let partition = dir.join(format!("{key}={}", escape_partition_value(value)));
    std::fs::create_dir_all(&partition).map_err(|source| HiveExportError::Io {
        path: partition.clone(),
        source,
    })?;
    Ok(partition.join(&part.name))
}

fn by_entity(
    view: &StoreView,
    dir: &Path,
    timeline: Option<&str>,
) -> Result<HiveSummary, HiveExportError> {
    let mut summary = HiveSummary::default();
    write_entities(
        view,
        dir,
        timeline,
        |table| table,
        &PartFile::default(),
        &mut summary,
    )?;
    Ok(summary)
}

/// Writes `view`'s chunk table, a partition per entity under `dir` (in path order), each
/// table through `shape` (which gives it the dataset's columns), into `summary`.
pub(crate) fn write_entities<R: RecordBatchReader>(
    view: &StoreView,
    dir: &Path,
    timeline: Option<&str>,
    shape: impl Fn(ChunkTableStream) -> R,
    part: &PartFile,
    summary: &mut HiveSummary,
) -> Result<(), HiveExportError> {
    let mut entities = view.entity_paths();
    entities.sort();
    for entity in entities {
        let mut query = ChunkTableQuery::new().with_row_entities([entity.clone()]);
        if let Some(timeline) = timeline {
            query = query.with_index(timeline);
        }
        let table = view.chunk_table(&query).map_err(HiveExportError::Table)?;
        let path = partition_file(dir, "entity", &entity.to_string(), part)?;
        let written = part.write(&path, shape(table), &ParquetOptions::default())?;
        summary.files.push((path, written));
    }
    Ok(())
}

fn by_time_bucket(
    view: &StoreView,
    dir: &Path,
    timeline: &Arc<str>,
    width: i64,
    query: Option<&DataframeQuery>,
) -> Result<HiveSummary, HiveExportError> {
    let query = bucket_query(timeline, query)?;
    let stream = view.dataframe(&query).map_err(HiveExportError::Table)?;
    let mut summary = HiveSummary::default();
    write_buckets(
        stream,
        dir,
        timeline,
        width,
        &PartFile::default(),
        &mut summary,
    )?;
    Ok(summary)
}

/// The dataframe query a [`HiveLayout::ByTimeBucket`] writes: its own, whose index must be
/// the bucketed timeline, or every column on it.
pub(crate) fn bucket_query(
    timeline: &Arc<str>,
    query: Option<&DataframeQuery>,
) -> Result<DataframeQuery, HiveExportError> {
    match query {
        Some(query) if query.index() == &**timeline => Ok(query.clone()),
        Some(query) => Err(HiveExportError::QueryIndex {
            index: query.index().to_owned(),
            timeline: timeline.to_string(),
        }),
        None => Ok(DataframeQuery::new(Arc::clone(timeline))),
    }
}

/// Writes `stream` (a dataframe on `timeline`, in index order) under `dir`, a partition
/// per bucket of `width` index values, into `summary`.
pub(crate) fn write_buckets(
    stream: impl RecordBatchReader,
    dir: &Path,
    timeline: &str,
    width: i64,
    part: &PartFile,
    summary: &mut HiveSummary,
) -> Result<(), HiveExportError> {
    let schema = stream.schema();
    let index = schema
        .index_of(timeline)
        .map_err(|e| HiveExportError::Write(ParquetExportError::Arrow(e)))?;
    let key = bucket_key(timeline);
    let options = ParquetOptions::default().with_sorted_by(timeline);
    let mut pieces = Buckets {
        batches: Box::new(stream),
        index,
        width,
        pending: None,
    };
    while let Some(bucket) = pieces
        .next_bucket()
        .map_err(|e| HiveExportError::Write(ParquetExportError::Arrow(e)))?
    {
        let path = partition_file(dir, &key, &bucket.to_string(), part)?;
        let reader = BucketReader {
            buckets: &mut pieces,
            bucket,
            schema: Arc::clone(&schema),
        };
        let written = part.write(&path, reader, &options)?;
        summary.files.push((path, written));
    }
    Ok(())
}

/// The partition key of `timeline`'s buckets: `<timeline>_bucket`.
pub(crate) fn bucket_key(timeline: &str) -> String {
    format!("{timeline}_bucket")
}

/// A dataframe's batches cut where the index crosses into the next bucket.
struct Buckets<'a> {
    batches: Box<dyn Iterator<Item = Result<RecordBatch, ArrowError>> + 'a>,
    index: usize,
    width: i64,
    /// A batch read, its index values, and where its rows not handed out yet start
    /// (always before its end).
    pending: Option<(RecordBatch, Vec<i64>, usize)>,
}

impl Buckets<'_> {
    /// The bucket of the next row (reading a batch if none is pending), or `None` at the
    /// end.
    fn next_bucket(&mut self) -> Result<Option<i64>, ArrowError> {
        loop {
            if let Some((_, times, start)) = &self.pending {
                return Ok(Some(times[*start].div_euclid(self.width)));
            }
            let Some(batch) = self.batches.next() else {
                return Ok(None);
            };
            let batch = batch?;
            if batch.num_rows() > 0 {
                let times = index_values(batch.column(self.index).as_ref())?;
                self.pending = Some((batch, times, 0));
            }
        }
    }

    /// The pending rows of `bucket` (index values ascend, so they come first); the rows
    /// after them stay pending.
    fn take(&mut self, bucket: i64) -> Result<Option<RecordBatch>, ArrowError> {
        if self.next_bucket()? != Some(bucket) {
            return Ok(None);
        }
        let Some((batch, times, start)) = self.pending.take() else {
            return Ok(None);
        };
        let end = start + times[start..].partition_point(|&t| t.div_euclid(self.width) == bucket);
        let piece = batch.slice(start, end - start);
        if end < times.len() {
            self.pending = Some((batch, times, end));
        }
        Ok(Some(piece))
    }
}

/// The index column's values as `i64` (sequence, duration and timestamp timelines all
/// hold 64-bit integers).
fn index_values(column: &dyn arrow_array::Array) -> Result<Vec<i64>, ArrowError> {
    let data = column.to_data();
    match column.data_type() {
        DataType::Int64 | DataType::Duration(_) | DataType::Timestamp(..) => {
            let ints = arrow_array::Int64Array::from(
                data.into_builder().data_type(DataType::Int64).build()?,
            );
            Ok(ints.values().to_vec())
        }
        other => Err(ArrowError::InvalidArgumentError(format!(
            "an index column of type {other}"
        ))),
    }
}

/// The pieces of one bucket, as a reader for [`write_parquet_file`].
struct BucketReader<'a, 'b> {
    buckets: &'a mut Buckets<'b>,
    bucket: i64,
    schema: SchemaRef,
}

impl Iterator for BucketReader<'_, '_> {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.buckets.take(self.bucket).transpose()
    }
}

impl RecordBatchReader for BucketReader<'_, '_> {
    fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }
}
