//! [`ChunkError`]: why a chunk could not be built (from arrays, a builder, or a transport
//! `RecordBatch`). Every variant names the offending column, timeline or row in a typed
//! field.

use std::fmt;

use arrow_schema::{ArrowError, DataType};

use crate::{EntityPathError, TimeType};

/// A chunk could not be built: from arrays, from a builder, or from a transport
/// `RecordBatch`.
#[derive(Debug)]
#[non_exhaustive]
pub enum ChunkError {
    /// A chunk must have at least one row.
    NoRows,
    /// A chunk must have at least one component column.
    NoComponents,
    /// More rows than a chunk can index (`u32::MAX`).
    TooManyRows {
        /// The number of rows given.
        num_rows: usize,
    },
    /// More time and component columns than a chunk can index (`u32::MAX`).
    TooManyColumns {
        /// The number of columns given.
        num_columns: usize,
    },
    /// A slice of rows reaches past the chunk's end (or is empty).
    SliceOutOfRange {
        /// First row of the slice.
        offset: usize,
        /// Rows in the slice.
        len: usize,
        /// Rows in the chunk.
        num_rows: usize,
    },
    /// A transport batch has two row-id columns.
    DuplicateRowIds {
        /// The second one.
        column: String,
    },
    /// The builder was given cells of different element types for one component.
    CellTypeMismatch {
        /// The component.
        component: String,
        /// The element type of its first cell.
        expected: DataType,
        /// The element type of a later cell.
        found: DataType,
    },
    /// A column's length differs from the number of row ids.
    LengthMismatch {
        /// The column (timeline or component name, or the row-id column).
        column: String,
        /// Number of rows (row ids).
        expected: usize,
        /// The column's length.
        actual: usize,
    },
    /// The row-id column has the wrong Arrow type.
    BadRowIdType {
        /// The type found.
        data_type: DataType,
    },
    /// The row-id column contains nulls.
    NullRowIds {
        /// How many.
        null_count: usize,
    },
    /// A time column has a type that is not a timeline type.
    BadTimeType {
        /// The timeline.
        timeline: String,
        /// The type found.
        data_type: DataType,
    },
    /// A time column contains nulls.
    NullTimes {
        /// The timeline.
        timeline: String,
        /// How many.
        null_count: usize,
    },
    /// A time column contains the reserved `i64::MIN`.
    ReservedTime {
        /// The timeline.
        timeline: String,
        /// The first row holding it.
        row: usize,
    },
    /// A component column is not an Arrow `List` array.
    NotAList {
        /// The component.
        component: String,
        /// The type found.
        data_type: DataType,
    },
    /// Two time columns share a timeline name.
    DuplicateTimeline {
        /// The timeline.
        timeline: String,
    },
    /// Two component columns share a component name.
    DuplicateComponent {
        /// The component.
        component: String,
    },
    /// A builder row gave one timeline two times.
    TimelineRepeatedInRow {
        /// The row (0-based).
        row: usize,
        /// The timeline.
        timeline: String,
    },
    /// A builder row gave one component two cells.
    ComponentRepeatedInRow {
        /// The row (0-based).
        row: usize,
        /// The component.
        component: String,
    },
    /// A builder was given one timeline name with two types.
    TimelineTypeMismatch {
        /// The timeline.
        timeline: String,
        /// The type it was first given with.
        first: TimeType,
        /// The other type.
        second: TimeType,
    },
    /// A component column describes more values than its buffers could hold at 8 a byte
    /// (plus one a row): only a type without data (`Null`, a struct without fields, a
    /// run-end encoding) can, and every copy of such a column (compaction, dataframes)
    /// allocates per value, so a few bytes could claim gigabytes.
    UnbackedValues {
        /// The component.
        component: String,
        /// The values its cells describe, every nesting level together.
        values: usize,
        /// The bytes of its buffers.
        bytes: usize,
    },
    /// A component or timeline name is empty.
    EmptyName {
        /// Which kind of column.
        kind: &'static str,
    },
    /// The transport batch has no `rerun.controls.RowId` column.
    MissingRowIds,
    /// The transport batch lacks a required schema metadata key.
    MissingMetadata {
        /// The key, e.g. `rerun:entity_path`.
        key: &'static str,
    },
    /// The `rerun:id` metadata is not a chunk id.
    BadChunkId(crate::ids::ParseChunkIdError),
    /// The entity path is invalid.
    BadEntityPath(EntityPathError),
    /// A transport column's `rerun:kind` metadata is not `control`, `index` or `data`.
    UnknownColumnKind {
        /// The column.
        column: String,
        /// The kind found.
        kind: String,
    },
    /// Arrow rejected the data.
    Arrow(ArrowError),
}

impl fmt::Display for ChunkError {
    #[expect(clippy::too_many_lines, reason = "one arm per variant")]
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NoRows => write!(f, "a chunk needs at least one row"),
            Self::NoComponents => write!(f, "a chunk needs at least one component column"),
            Self::TooManyRows { num_rows } => {
                write!(
                    f,
                    "{num_rows} rows is more than a chunk can index (u32::MAX)"
                )
            }
            Self::TooManyColumns { num_columns } => write!(
                f,
                "{num_columns} columns is more than a chunk can index (u32::MAX)"
            ),
            Self::SliceOutOfRange {
                offset,
                len,
                num_rows,
            } => write!(
                f,
                "rows {offset}..{} are not a non-empty slice of a chunk of {num_rows} rows",
                offset.saturating_add(*len)
            ),
            Self::DuplicateRowIds { column } => {
                write!(f, "column {column:?} is a second row-id column")
            }
            Self::CellTypeMismatch {
                component,
                expected,
                found,
            } => write!(
                f,
                "component {component:?} has cells of type {expected} and of type {found}"
            ),
            Self::LengthMismatch {
                column,
                expected,
                actual,
            } => write!(
                f,
                "column {column:?} has {actual} rows but the row-id column has {expected}"
            ),
            Self::BadRowIdType { data_type } => {
                write!(
                    f,
                    "row-id column must be FixedSizeBinary(16), found {data_type}"
                )
            }
            Self::NullRowIds { null_count } => {
                write!(f, "row-id column has {null_count} null values")
            }
            Self::BadTimeType {
                timeline,
                data_type,
            } => write!(
                f,
                "time column {timeline:?} must be Int64, Duration(ns) or Timestamp(ns), \
                 found {data_type}"
            ),
            Self::NullTimes {
                timeline,
                null_count,
            } => {
                write!(f, "time column {timeline:?} has {null_count} null values")
            }
            Self::ReservedTime { timeline, row } => {
                write!(
                    f,
                    "time column {timeline:?} holds the reserved i64::MIN at row {row}"
                )
            }
            Self::NotAList {
                component,
                data_type,
            } => {
                write!(
                    f,
                    "component column {component:?} must be a List array, found {data_type}"
                )
            }
            Self::DuplicateTimeline { timeline } => {
                write!(f, "timeline {timeline:?} appears twice in one chunk")
            }
            Self::DuplicateComponent { component } => {
                write!(f, "component {component:?} appears twice in one chunk")
            }
            Self::TimelineRepeatedInRow { row, timeline } => {
                write!(f, "row {row} gives timeline {timeline:?} two times")
            }
            Self::ComponentRepeatedInRow { row, component } => {
                write!(f, "row {row} gives component {component:?} two cells")
            }
            Self::TimelineTypeMismatch {
                timeline,
                first,
                second,
            } => write!(
                f,
                "timeline {timeline:?} is given as {first:?} and as {second:?}"
            ),
            Self::UnbackedValues {
                component,
                values,
                bytes,
            } => write!(
                f,
                "component column {component:?} describes {values} values in {bytes} bytes of \
                 buffers (more than 8 a byte, as only a type without data can): refused, as \
                 every copy of it would allocate per value"
            ),
            Self::EmptyName { kind } => write!(f, "a {kind} name must not be empty"),
            Self::MissingRowIds => write!(f, "batch has no `rerun.controls.RowId` column"),
            Self::MissingMetadata { key } => write!(f, "batch schema lacks metadata {key:?}"),
            Self::BadChunkId(e) => write!(f, "{e}"),
            Self::BadEntityPath(e) => write!(f, "{e}"),
            Self::UnknownColumnKind { column, kind } => {
                write!(f, "column {column:?} has unknown rerun:kind {kind:?}")
            }
            Self::Arrow(e) => write!(f, "arrow: {e}"),
        }
    }
}

impl std::error::Error for ChunkError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::BadChunkId(e) => Some(e),
            Self::BadEntityPath(e) => Some(e),
            Self::Arrow(e) => Some(e),
            _ => None,
        }
    }
}

impl From<ArrowError> for ChunkError {
    fn from(e: ArrowError) -> Self {
        Self::Arrow(e)
    }
}

impl From<EntityPathError> for ChunkError {
    fn from(e: EntityPathError) -> Self {
        Self::BadEntityPath(e)
    }
}
