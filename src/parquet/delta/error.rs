//! [`DeltaError`]: why a Delta table could not be written.

use crate::parquet::HiveExportError;
use crate::parquet::delta_types::Unrepresentable;

/// Why a Delta table could not be written or appended to. Nothing the write placed is
/// left behind, and no commit was made.
#[derive(Debug)]
#[non_exhaustive]
pub enum DeltaError {
    /// A new table was asked for and something is at its location already.
    Exists {
        /// The table's directory or URL.
        table: String,
    },
    /// An append to a location without a Delta log.
    NotATable {
        /// The table's directory or URL.
        table: String,
    },
    /// The table is partitioned differently from the write.
    Partitions {
        /// The table's partition columns.
        table: Vec<String>,
        /// The write's.
        write: Vec<String>,
    },
    /// A segment the write adds is in the table already (perhaps added by another writer
    /// a moment ago).
    SegmentExists {
        /// The segment (recording id).
        segment: String,
    },
    /// A column the table has with another type than the write's.
    ColumnType {
        /// The column.
        column: String,
        /// Its Delta type in the table.
        table: String,
        /// Its Delta type in the write.
        write: String,
    },
    /// A column whose Arrow type Delta cannot hold (a union, say).
    UnsupportedType {
        /// The column.
        column: String,
        /// Its Arrow type.
        data_type: String,
    },
    /// A column (or struct field) name Delta cannot hold: empty, or with one of
    /// ` ,;{}()\n\t=`.
    ColumnName {
        /// The top-level column.
        column: String,
    },
    /// A table chunkstore does not append to: a checkpointed log, a protocol above reader
    /// version 1 and writer version 2, a log that does not start at version 0.
    UnsupportedTable {
        /// Why.
        reason: String,
    },
    /// A log entry that is not valid JSON actions.
    BadLog {
        /// The log file.
        file: String,
        /// What is wrong in it.
        reason: String,
    },
    /// The table's store refused (a file system's or a bucket's error).
    Io {
        /// The file, directory or URL.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The data files could not be written.
    Hive(HiveExportError),
}

impl std::fmt::Display for DeltaError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Exists { table } => {
                write!(f, "{table}: already exists (a new table is asked for)")
            }
            Self::NotATable { table } => {
                write!(f, "{table}: not a Delta table (it has no _delta_log/)")
            }
            Self::Partitions { table, write: ours } => write!(
                f,
                "the table is partitioned by {} and the write by {}",
                table.join(", "),
                ours.join(", ")
            ),
            Self::SegmentExists { segment } => {
                write!(f, "segment {segment:?} is in the table already")
            }
            Self::ColumnType {
                column,
                table,
                write,
            } => write!(
                f,
                "column {column:?} is {table} in the table and {write} in the write"
            ),
            // One wording with the file writer's (`delta_types`).
            Self::UnsupportedType { column, data_type } => Unrepresentable::Type {
                column: column.clone(),
                data_type: data_type.clone(),
            }
            .fmt(f),
            Self::ColumnName { column } => Unrepresentable::Name {
                column: column.clone(),
            }
            .fmt(f),
            Self::UnsupportedTable { reason } => {
                write!(f, "chunkstore does not append to this table: {reason}")
            }
            Self::BadLog { file, reason } => write!(f, "{file}: not a Delta log entry: {reason}"),
            Self::Io { path, source } => {
                // An object's error names its URL already.
                let text = source.to_string();
                if text.starts_with(path.as_str()) {
                    write!(f, "{text}")
                } else {
                    write!(f, "{path}: {text}")
                }
            }
            Self::Hive(error) => write!(f, "{error}"),
        }
    }
}

impl std::error::Error for DeltaError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io { source, .. } => Some(source),
            Self::Hive(error) => Some(error),
            _ => None,
        }
    }
}

impl From<Unrepresentable> for DeltaError {
    fn from(error: Unrepresentable) -> Self {
        match error {
            Unrepresentable::Type { column, data_type } => {
                Self::UnsupportedType { column, data_type }
            }
            Unrepresentable::Name { column } => Self::ColumnName { column },
        }
    }
}

impl From<HiveExportError> for DeltaError {
    fn from(error: HiveExportError) -> Self {
        Self::Hive(error)
    }
}

impl DeltaError {
    /// The store's error at `path`: what a [`TableStore`](super::TableStore) of one's own
    /// returns when its storage fails.
    pub fn io(path: impl Into<String>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }
}
