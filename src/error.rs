//! Error types, one `#[non_exhaustive]` enum per family: chunk construction (including
//! transport decoding), insertion, IO, configuration and GC options; the entity path's own
//! [`EntityPathError`] lives with the parser and is re-exported here. Every variant names the offending
//! column, timeline, component or path in a typed field.

use std::fmt;

use arrow_schema::{ArrowError, DataType};

pub use crate::entity_path::EntityPathError;
use crate::{ChunkId, EntityPath, TimeType};

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

/// A valid chunk could not be inserted because it conflicts with the store's contents.
/// The store is left unchanged.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub enum InsertError {
    /// The chunk uses a timeline name with another type than the store knows it by.
    TimelineTypeConflict {
        /// The chunk.
        chunk_id: ChunkId,
        /// The timeline.
        timeline: String,
        /// The type the store knows.
        existing: TimeType,
        /// The type in the chunk.
        incoming: TimeType,
    },
    /// The chunk's data for a component has another Arrow type than that entity's earlier
    /// data for it.
    ComponentTypeConflict {
        /// The chunk.
        chunk_id: ChunkId,
        /// The entity.
        entity_path: EntityPath,
        /// The component.
        component: String,
        /// The element type the store knows.
        existing: DataType,
        /// The element type in the chunk.
        incoming: DataType,
    },
    /// A `Clear:is_recursive` column whose elements are not booleans.
    ClearNotBoolean {
        /// The chunk.
        chunk_id: ChunkId,
        /// The element type found.
        data_type: DataType,
    },
    /// A `Clear:is_recursive` cell that is not exactly one boolean: a Clear says once
    /// whether it is recursive (a null cell, meaning "no Clear in this row", is fine).
    MalformedClear {
        /// The chunk.
        chunk_id: ChunkId,
        /// Its entity.
        entity_path: EntityPath,
        /// The row (0-based).
        row: usize,
        /// How many instances the cell holds (not 1).
        instances: usize,
    },
    /// A `Clear:is_recursive` cell whose one boolean is null: neither flat nor recursive.
    NullClearFlag {
        /// The chunk.
        chunk_id: ChunkId,
        /// Its entity.
        entity_path: EntityPath,
        /// The row (0-based).
        row: usize,
    },
    /// The store holds a chunk with this id and other contents. Chunk ids name one chunk:
    /// the same chunk inserted again changes nothing, another one under its id is refused.
    ChunkIdConflict {
        /// The id both chunks carry.
        chunk_id: ChunkId,
        /// The entity of the chunk the store holds.
        held_entity: EntityPath,
        /// The entity of the chunk refused.
        incoming_entity: EntityPath,
    },
}

impl fmt::Display for InsertError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::TimelineTypeConflict {
                chunk_id,
                timeline,
                existing,
                incoming,
            } => write!(
                f,
                "{chunk_id}: timeline {timeline:?} is {incoming:?} here but {existing:?} in the store"
            ),
            Self::ComponentTypeConflict {
                chunk_id,
                entity_path,
                component,
                existing,
                incoming,
            } => {
                write!(
                    f,
                    "{chunk_id}: component {component:?} of {entity_path} has element type \
                     {incoming} here but {existing} in the store"
                )
            }
            Self::ClearNotBoolean {
                chunk_id,
                data_type,
            } => write!(
                f,
                "{chunk_id}: `Clear:is_recursive` must hold booleans, found {data_type}"
            ),
            Self::MalformedClear {
                chunk_id,
                entity_path,
                row,
                instances,
            } => write!(
                f,
                "{chunk_id} ({entity_path}): the `Clear:is_recursive` cell of row {row} holds \
                 {instances} booleans, not one"
            ),
            Self::NullClearFlag {
                chunk_id,
                entity_path,
                row,
            } => write!(
                f,
                "{chunk_id} ({entity_path}): the `Clear:is_recursive` cell of row {row} holds a \
                 null boolean"
            ),
            Self::ChunkIdConflict {
                chunk_id,
                held_entity,
                incoming_entity,
            } => write!(
                f,
                "{chunk_id}: the store holds another chunk with this id (of {held_entity}); \
                 refused the one of {incoming_entity}"
            ),
        }
    }
}

impl std::error::Error for InsertError {}

/// Reading chunks from Arrow IPC failed.
#[cfg(feature = "ipc")]
#[derive(Debug)]
#[non_exhaustive]
pub enum IoError {
    /// The file could not be read.
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The bytes are not Arrow IPC (file or stream format).
    Ipc(ArrowError),
    /// The IPC framing claims more bytes than the input holds (or negative sizes); rejected
    /// before decoding, because arrow-ipc would allocate the claimed size first.
    MalformedFraming {
        /// What is wrong.
        reason: String,
    },
    /// Arrow's IPC decoder panicked on malformed bytes instead of returning an error (a
    /// known arrow-ipc weakness); the panic was contained and the input rejected.
    DecoderPanicked {
        /// The panic's message.
        message: String,
    },
    /// A batch decoded but is not a valid chunk.
    Chunk {
        /// Which batch of the input (0-based).
        batch: usize,
        /// Why.
        source: ChunkError,
    },
}

#[cfg(feature = "ipc")]
impl fmt::Display for IoError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io { path, source } => write!(f, "{}: {source}", path.display()),
            Self::Ipc(e) => write!(f, "not Arrow IPC: {e}"),
            Self::MalformedFraming { reason } => write!(f, "malformed Arrow IPC framing: {reason}"),
            Self::DecoderPanicked { message } => {
                write!(f, "malformed Arrow IPC (the decoder panicked: {message})")
            }
            Self::Chunk { batch, source } => write!(f, "batch {batch}: {source}"),
        }
    }
}

#[cfg(feature = "ipc")]
impl std::error::Error for IoError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io { source, .. } => Some(source),
            Self::Ipc(e) => Some(e),
            Self::Chunk { source, .. } => Some(source),
            Self::DecoderPanicked { .. } | Self::MalformedFraming { .. } => None,
        }
    }
}

/// A [`crate::StoreConfig`] that cannot work.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum ConfigError {
    /// A threshold is zero: no chunk could hold a row.
    ZeroThreshold {
        /// The field.
        field: &'static str,
    },
    /// Compaction must merge at least two chunks at once.
    FanoutBelowTwo {
        /// The fanout given.
        merge_fanout: usize,
    },
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::ZeroThreshold { field } => {
                write!(f, "store config: {field} must be at least 1")
            }
            Self::FanoutBelowTwo { merge_fanout } => {
                write!(
                    f,
                    "store config: merge_fanout must be at least 2, not {merge_fanout}"
                )
            }
        }
    }
}

impl std::error::Error for ConfigError {}

/// Garbage collection options that cannot mean what they say.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum GcOptionsError {
    /// A fraction of the heap to free must be in `(0, 1]`.
    FractionOutOfRange {
        /// The fraction given.
        fraction: f64,
    },
}

impl fmt::Display for GcOptionsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::FractionOutOfRange { fraction } => write!(
                f,
                "gc options: a fraction of the heap must be in (0, 1], not {fraction}"
            ),
        }
    }
}

impl std::error::Error for GcOptionsError {}
