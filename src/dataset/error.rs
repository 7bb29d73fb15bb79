//! Why a dataset could not be opened or queried. Every variant about a file names it.

use std::fmt;
use std::path::PathBuf;

use crate::recording::OpenError;
use crate::{DataframeError, TimeType, UnknownTimeline};

/// Why a [`Dataset`](super::Dataset) could not be opened or answer a query.
#[derive(Debug)]
#[non_exhaustive]
pub enum DatasetError {
    /// The directory could not be listed.
    Io {
        /// The directory.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A dataset directory holds no regular `.rrd` file (subdirectories are not looked
    /// into), or a list of files was empty.
    NoRrdFiles {
        /// The directory (empty for an empty list).
        dir: PathBuf,
    },
    /// A segment's file could not be opened or loaded.
    Open(Box<OpenError>),
    /// A file is not an `.rrd` (a dataset's segments are `.rrd` files).
    NotRrd {
        /// The file.
        path: PathBuf,
    },
    /// An `.rrd` holds no store info, so its segment has no recording id to be named by.
    NoRecordingId {
        /// The file.
        path: PathBuf,
    },
    /// Two files hold the same recording: a segment is one file (a recording split
    /// across files is not supported).
    DuplicateRecording {
        /// The recording id.
        id: String,
        /// One file holding it.
        first: PathBuf,
        /// Another.
        second: PathBuf,
    },
    /// A timeline has one type in one segment and another in another.
    TimelineTypeConflict {
        /// The timeline.
        timeline: String,
        /// A segment and its type there.
        first: (String, TimeType),
        /// Another segment and its type there.
        second: (String, TimeType),
    },
    /// A column has one Arrow type in one segment and another in another, so the
    /// segments cannot be one table.
    ColumnTypeConflict {
        /// The column's name.
        column: String,
        /// A segment holding it.
        first: String,
        /// Another, with another type.
        second: String,
    },
    /// The index is no segment's timeline.
    UnknownIndex(UnknownTimeline),
    /// [`DataframeQuery::with_columns`](crate::DataframeQuery::with_columns) named a
    /// column no segment has.
    UnknownColumn {
        /// The name asked for.
        name: String,
        /// How many columns the dataset's table has.
        num_columns: usize,
    },
    /// No segment has this id.
    UnknownSegment {
        /// The id asked for.
        id: String,
        /// How many segments the dataset has.
        num_segments: usize,
    },
    /// A segment's dataframe could not be made.
    Dataframe {
        /// The segment.
        segment: String,
        /// Why.
        error: DataframeError,
    },
    /// A Hive-partitioned copy of the dataset could not be written (nothing is left of
    /// it): [`Dataset::write_hive`](super::Dataset::write_hive).
    #[cfg(feature = "parquet")]
    Hive(crate::parquet::HiveExportError),
    /// A Delta table of the dataset could not be written or appended to (no commit was
    /// made, and nothing the write placed is left): [`Dataset::write_delta`](super::Dataset::write_delta).
    #[cfg(feature = "parquet")]
    Delta(crate::parquet::delta::DeltaError),
}

#[cfg(feature = "parquet")]
impl From<crate::parquet::delta::DeltaError> for DatasetError {
    fn from(error: crate::parquet::delta::DeltaError) -> Self {
        Self::Delta(error)
    }
}

#[cfg(feature = "parquet")]
impl From<crate::parquet::HiveExportError> for DatasetError {
    fn from(error: crate::parquet::HiveExportError) -> Self {
        Self::Hive(error)
    }
}

impl From<OpenError> for DatasetError {
    fn from(error: OpenError) -> Self {
        Self::Open(Box::new(error))
    }
}

impl fmt::Display for DatasetError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io { path, source } => {
                write!(f, "{}", crate::storage::io_error_text(path, source))
            }
            Self::NoRrdFiles { dir } if dir.as_os_str().is_empty() => {
                write!(f, "a dataset needs at least one .rrd file")
            }
            Self::NoRrdFiles { dir } => write!(
                f,
                "{}: no .rrd file in the directory (a dataset's segments are the regular \
                 .rrd files directly in it)",
                dir.display()
            ),
            Self::Open(error) => write!(f, "{error}"),
            Self::NotRrd { path } => write!(
                f,
                "{}: not an .rrd file (a dataset's segments are .rrd files)",
                path.display()
            ),
            Self::NoRecordingId { path } => write!(
                f,
                "{}: the file names no recording (no store info), so its segment has no id",
                path.display()
            ),
            Self::DuplicateRecording { id, first, second } => write!(
                f,
                "recording {id:?} is in two files, {} and {} (a segment is one file)",
                first.display(),
                second.display()
            ),
            Self::TimelineTypeConflict {
                timeline,
                first,
                second,
            } => write!(
                f,
                "timeline {timeline:?} is {:?} in segment {:?} and {:?} in segment {:?}",
                first.1, first.0, second.1, second.0
            ),
            Self::ColumnTypeConflict {
                column,
                first,
                second,
            } => write!(
                f,
                "column {column:?} has one type in segment {first:?} and another in \
                 segment {second:?}"
            ),
            Self::UnknownIndex(unknown) => write!(f, "no segment has the index: {unknown}"),
            Self::UnknownColumn { name, num_columns } => write!(
                f,
                "the dataset's table has no column {name:?} (it has {num_columns} columns)"
            ),
            Self::UnknownSegment { id, num_segments } => write!(
                f,
                "the dataset has no segment {id:?} (it has {num_segments} segments)"
            ),
            Self::Dataframe { segment, error } => write!(f, "segment {segment:?}: {error}"),
            #[cfg(feature = "parquet")]
            Self::Hive(error) => write!(f, "{error}"),
            #[cfg(feature = "parquet")]
            Self::Delta(error) => write!(f, "{error}"),
        }
    }
}

impl std::error::Error for DatasetError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io { source, .. } => Some(source),
            Self::Open(error) => Some(&**error),
            Self::UnknownIndex(unknown) => Some(unknown),
            Self::Dataframe { error, .. } => Some(error),
            #[cfg(feature = "parquet")]
            Self::Hive(error) => Some(error),
            #[cfg(feature = "parquet")]
            Self::Delta(error) => Some(error),
            _ => None,
        }
    }
}
