//! Parquet files (feature `parquet`) that `pyarrow`, pandas, Polars, `DuckDB` and Spark read
//! as they are: a dataframe view ([`StoreView::dataframe`](crate::StoreView::dataframe))
//! or the raw chunk table ([`StoreView::chunk_table`](crate::StoreView::chunk_table)),
//! streamed batch by batch into row groups, with min/max statistics on every column (the
//! index and the entity path included, so readers prune row groups on time), the sort
//! order recorded, the Arrow schema embedded (field metadata included), Snappy pages, and
//! written atomically (a temporary file renamed into place).

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use ::parquet::arrow::ArrowWriter;
use ::parquet::basic::Compression;
use ::parquet::errors::ParquetError;
use ::parquet::file::metadata::SortingColumn;
use ::parquet::file::properties::{EnabledStatistics, WriterProperties};
use arrow_array::{RecordBatch, RecordBatchReader};
use arrow_schema::ArrowError;

/// Cells per row group when [`ParquetOptions::with_row_group_rows`] is not given: the
/// writer holds one row group's encoded pages in memory, so a wide table gets shorter
/// row groups (at least 1,024 rows, at most 1,048,576).
pub const DEFAULT_ROW_GROUP_CELLS: usize = 8 << 20;

/// Encoded bytes a row group buffers, about, before it is written, when
/// [`ParquetOptions::with_row_group_rows`] is not given (see
/// [`ParquetOptions::with_row_group_bytes`]).
pub const DEFAULT_ROW_GROUP_BYTES: usize = 128 << 20;

/// How to write a Parquet file.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct ParquetOptions {
    row_group_rows: Option<usize>,
    row_group_bytes: Option<usize>,
    sorted_by: Vec<Arc<str>>,
}

impl ParquetOptions {
    /// At most `rows` rows per row group (default: about [`DEFAULT_ROW_GROUP_CELLS`]
    /// cells).
    #[must_use]
    pub fn with_row_group_rows(mut self, rows: usize) -> Self {
        self.row_group_rows = Some(rows);
        self
    }

    /// Without [`Self::with_row_group_rows`], a row group is also written once its
    /// encoded pages, buffered in memory until then, reach about `bytes` (default
    /// [`DEFAULT_ROW_GROUP_BYTES`]): large cells make fewer rows per row group.
    #[must_use]
    pub fn with_row_group_bytes(mut self, bytes: usize) -> Self {
        self.row_group_bytes = Some(bytes.max(1));
        self
    }

    /// Records in the file's metadata that rows ascend by this (top-level, primitive or
    /// text) column, as a dataframe's rows ascend by its index: engines that read the sort
    /// order skip sorting. Called again, rows ascend by the first column, then the next
    /// (a dataset's by segment, then index). Each column must come before any nested one.
    #[must_use]
    pub fn with_sorted_by(mut self, column: impl Into<Arc<str>>) -> Self {
        self.sorted_by.push(column.into());
        self
    }
}

/// What a write produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct ParquetSummary {
    /// Rows written.
    pub rows: u64,
    /// Row groups written.
    pub row_groups: usize,
    /// The file's size in bytes.
    pub bytes: u64,
}

/// A Parquet file could not be written; nothing was left under its name.
#[derive(Debug)]
#[non_exhaustive]
pub enum ParquetExportError {
    /// The file system refused.
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The batches could not be read (the reader's own error).
    Arrow(ArrowError),
    /// The Parquet encoder refused.
    Parquet(ParquetError),
    /// The column named in [`ParquetOptions::with_sorted_by`] is not in the schema, or
    /// comes after a nested column.
    SortColumn {
        /// The name.
        column: String,
    },
}

impl fmt::Display for ParquetExportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io { path, source } => write!(f, "{}: {source}", path.display()),
            Self::Arrow(error) => write!(f, "reading batches: {error}"),
            Self::Parquet(error) => write!(f, "writing parquet: {error}"),
            Self::SortColumn { column } => write!(
                f,
                "sort column {column:?} is not a top-level column before the nested ones"
            ),
        }
    }
}

impl std::error::Error for ParquetExportError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io { source, .. } => Some(source),
            Self::Arrow(error) => Some(error),
            Self::Parquet(error) => Some(error),
            Self::SortColumn { .. } => None,
        }
    }
}

/// Bytes of a batch of byte lists handed to the Parquet writer at once, about: the writer
/// computes a column's levels for all its values at once, 12 bytes a value (two 16-bit
/// levels and a 64-bit index), and a list of bytes (an image) has a value per byte. A
/// batch of 32 MB of images took 400 MB to write; `sql --out` of 850 MB of images peaked
/// at 1.2 GB.
const WRITE_SLICE_BYTES: usize = 8 << 20;

/// `batch` in slices of about [`WRITE_SLICE_BYTES`] (at least a row each) where it has
/// byte lists (`byte_lists`: by column, is it nested over small integers: an image, a
/// blob), whose levels take twelve times their bytes; whole otherwise (levels of wider
/// values take 1.5 to 3 times theirs, and slices of 8 MiB made a scalar dataset's export
/// 12% slower). The byte lists are copied: the writer converts such a leaf array whole
/// (to 32-bit integers) whatever part of it the rows use, so that zero-copy slices of a
/// batch of images converted the whole batch once per slice (twice the time of writing
/// it unsliced).
fn write_slices<'a>(
    batch: &'a RecordBatch,
    byte_lists: &'a [bool],
) -> impl Iterator<Item = RecordBatch> + 'a {
    let rows = batch.num_rows();
    let bytes = batch.get_array_memory_size().max(1);
    let per_slice = if bytes <= WRITE_SLICE_BYTES || !byte_lists.contains(&true) {
        rows.max(1)
    } else {
        usize::try_from(rows as u128 * WRITE_SLICE_BYTES as u128 / bytes as u128)
            .unwrap_or(rows)
            .max(1)
    };
    let whole = per_slice >= rows;
    (0..rows.max(1)).step_by(per_slice).map(move |start| {
        let start = start.min(rows);
        let slice = batch.slice(start, per_slice.min(rows - start));
        if whole {
            return slice;
        }
        let columns = slice
            .columns()
            .iter()
            .zip(byte_lists)
            .map(|(column, &copy)| {
                if copy {
                    compacted(column)
                } else {
                    Arc::clone(column)
                }
            })
            .collect();
        let options = arrow_array::RecordBatchOptions::new().with_row_count(Some(slice.num_rows()));
        // The same schema and lengths as the slice: cannot fail.
        RecordBatch::try_new_with_options(slice.schema(), columns, &options).unwrap_or(slice)
    })
}

/// `array` with buffers of its own (a slice's children then hold only its values).
fn compacted(array: &arrow_array::ArrayRef) -> arrow_array::ArrayRef {
    let data = array.to_data();
    let mut copy = arrow_data::transform::MutableArrayData::new(vec![&data], false, data.len());
    copy.extend(0, 0, data.len());
    arrow_array::make_array(copy.freeze())
}

/// Is `data_type` nested over an integer type the Parquet writer widens (to `INT32`)
/// array by array: a list of bytes?
fn is_byte_list(data_type: &arrow_schema::DataType) -> bool {
    data_type.is_nested() && has_small_integer_leaf(data_type)
}

fn has_small_integer_leaf(data_type: &arrow_schema::DataType) -> bool {
    use arrow_schema::DataType;
    match data_type {
        DataType::Int8
        | DataType::Int16
        | DataType::UInt8
        | DataType::UInt16
        | DataType::UInt32 => true,
        DataType::List(item)
        | DataType::LargeList(item)
        | DataType::FixedSizeList(item, _)
        | DataType::Map(item, _) => has_small_integer_leaf(item.data_type()),
        DataType::Struct(fields) => fields.iter().any(|f| has_small_integer_leaf(f.data_type())),
        _ => false,
    }
}

/// Writes every batch of `reader` to a Parquet file at `path`, atomically: the file
/// appears whole or, on any error (the reader's included), not at all. Memory is one
/// batch plus one row group's encoded pages, however long the table.
///
/// # Errors
/// See [`ParquetExportError`].
pub fn write_parquet_file(
    path: &Path,
    reader: impl RecordBatchReader,
    options: &ParquetOptions,
) -> Result<ParquetSummary, ParquetExportError> {
    let schema = reader.schema();
    let sorting = if options.sorted_by.is_empty() {
        None
    } else {
        let mut sorting = Vec::with_capacity(options.sorted_by.len());
        for column in &options.sorted_by {
            let position = schema
                .fields()
                .iter()
                .position(|f| f.name() == &**column)
                .filter(|&p| {
                    schema.fields()[..=p]
                        .iter()
                        .all(|f| !f.data_type().is_nested())
                })
                .ok_or_else(|| ParquetExportError::SortColumn {
                    column: column.to_string(),
                })?;
            sorting.push(SortingColumn {
                column_idx: i32::try_from(position).unwrap_or(i32::MAX),
                descending: false,
                nulls_first: true,
            });
        }
        Some(sorting)
    };
    let row_group_rows = options.row_group_rows.unwrap_or_else(|| {
        (DEFAULT_ROW_GROUP_CELLS / schema.fields().len().max(1)).clamp(1 << 10, 1 << 20)
    });
    let properties = WriterProperties::builder()
        .set_compression(Compression::SNAPPY)
        .set_statistics_enabled(EnabledStatistics::Page)
        .set_max_row_group_row_count(Some(row_group_rows.max(1)))
        .set_sorting_columns(sorting)
        .set_created_by(format!("chunkstore {}", env!("CARGO_PKG_VERSION")))
        .build();
    let io = |source| ParquetExportError::Io {
        path: path.to_owned(),
        source,
    };
    let byte_lists: Vec<bool> = schema
        .fields()
        .iter()
        .map(|f| is_byte_list(f.data_type()))
        .collect();
    crate::output::atomic_write(path, io, |file| {
        let mut writer = ArrowWriter::try_new(
            std::io::BufWriter::new(file),
            Arc::clone(&schema),
            Some(properties),
        )
        .map_err(ParquetExportError::Parquet)?;
        let mut rows = 0;
        for batch in reader {
            let batch = batch.map_err(ParquetExportError::Arrow)?;
            rows += batch.num_rows() as u64;
            for part in write_slices(&batch, &byte_lists) {
                writer.write(&part).map_err(ParquetExportError::Parquet)?;
                // A row group is buffered whole until it is written: bound it by bytes
                // as well as rows (large cells, or a static one repeated on every row,
                // made a row group of gigabytes).
                if options.row_group_rows.is_none()
                    && writer.in_progress_size()
                        >= options.row_group_bytes.unwrap_or(DEFAULT_ROW_GROUP_BYTES)
                {
                    writer.flush().map_err(ParquetExportError::Parquet)?;
                }
            }
        }
        // `into_inner` writes the footer: `finish` before it would write a second one.
        writer.flush().map_err(ParquetExportError::Parquet)?;
        let row_groups = writer.flushed_row_groups().len();
        let file = writer
            .into_inner()
            .map_err(ParquetExportError::Parquet)?
            .into_inner()
            .map_err(|e| io(e.into_error()))?;
        let bytes = file.metadata().map_err(io)?.len();
        let summary = ParquetSummary {
            rows,
            row_groups,
            bytes,
        };
        Ok((file, summary))
    })
}
