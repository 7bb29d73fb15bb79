//! The package's exceptions, and how each crate error maps to one.

use chunkstore::ipc::IpcError;
use chunkstore::recording::{LoadFault, OpenError};
use chunkstore::rrd::{RrdError, RrdErrorKind};
use chunkstore::{ChunkError, DataframeError, InsertError, UnknownTimeline};
use pyo3::PyErr;
use pyo3::import_exception;

// Defined in Python (`chunkstore/_errors.py`), so that each also subclasses the built-in
// exception a caller expects (`ValueError`, `KeyError`), which an exception type created
// here could not: it has one base.
import_exception!(chunkstore._errors, Error);
import_exception!(chunkstore._errors, InvalidInputError);
import_exception!(chunkstore._errors, CorruptFileError);
import_exception!(chunkstore._errors, UnknownTimelineError);

/// `chunkstore.InvalidInputError` with `message`.
pub fn invalid(message: impl Into<String>) -> PyErr {
    InvalidInputError::new_err(message.into())
}

/// An I/O error as Python's own `OSError` subclass, the path named.
pub fn os_error(path: &std::path::Path, error: std::io::Error) -> PyErr {
    let error = std::io::Error::new(
        error.kind(),
        chunkstore::storage::io_error_text(path, &error),
    );
    PyErr::from(error)
}

/// A `.rrd` error: the file system's own, or the file's fault.
pub fn rrd_error(path: &std::path::Path, error: RrdError) -> PyErr {
    if let RrdErrorKind::Io(io) = &error.kind
        && io.kind() != std::io::ErrorKind::UnexpectedEof
    {
        return PyErr::from(std::io::Error::new(
            io.kind(),
            chunkstore::storage::io_error_text(path, io),
        ));
    }
    CorruptFileError::new_err(format!("{}: {error}", path.display()))
}

/// A file holding several recordings where none was chosen, or not the one asked for:
/// `InvalidInputError`, naming the recordings it holds (the file itself is fine).
pub fn recording_error(path: &std::path::Path, kind: RrdErrorKind) -> PyErr {
    let error = RrdError { offset: 0, kind };
    invalid(format!(
        "{}: {error} (open(path, recording=ID) chooses)",
        path.display()
    ))
}

/// A source that could not be opened: the file system's own error as `OSError`, a
/// recording choice as `InvalidInputError`, the file's fault as `CorruptFileError`.
pub fn open_error(error: OpenError) -> PyErr {
    match error {
        OpenError::Io { path, source } => os_error(&path, source),
        OpenError::Recording { path, error } => recording_error(&path, error.kind),
        OpenError::Rrd { path, error }
        | OpenError::Footer { path, error }
        | OpenError::StoreInfo { path, error } => rrd_error(&path, error),
        OpenError::Ipc { error, .. } => ipc_error(error),
        OpenError::Fault(fault) => match *fault {
            LoadFault::Message { path, error } => rrd_error(&path, error),
            LoadFault::File { error, .. } => ipc_error(error),
            other => CorruptFileError::new_err(OpenError::Fault(Box::new(other)).to_string()),
        },
        OpenError::Config(error) => invalid(error.to_string()),
        other => CorruptFileError::new_err(other.to_string()),
    }
}

/// An Arrow IPC error: the file system's own, or the file's fault.
pub fn ipc_error(error: IpcError) -> PyErr {
    match error {
        IpcError::Io { path, source } => os_error(&path, source),
        other => CorruptFileError::new_err(other.to_string()),
    }
}

/// A chunk the store refuses.
pub fn chunk_error(error: ChunkError) -> PyErr {
    invalid(format!("not a valid chunk: {error}"))
}

/// An insert the store refuses.
pub fn insert_error(error: InsertError) -> PyErr {
    invalid(error.to_string())
}

/// A dataframe query the store cannot answer.
pub fn dataframe_error(error: DataframeError) -> PyErr {
    match error {
        DataframeError::UnknownIndex(unknown) => unknown_timeline(&unknown),
        other => invalid(other.to_string()),
    }
}

/// `known` for a message, comma-separated; `none` if there is nothing.
pub fn listing(known: &[String], none: &str) -> String {
    if known.is_empty() {
        none.to_owned()
    } else {
        known.join(", ")
    }
}

/// An unknown timeline, the known ones named.
pub fn unknown_timeline(error: &UnknownTimeline) -> PyErr {
    UnknownTimelineError::new_err(error.to_string())
}

/// Runs `work`, turning a panic (a bug in the store: user data never panics it) into
/// `chunkstore.Error`, so that Python never sees pyo3's `PanicException`.
pub fn no_panic<T>(work: impl FnOnce() -> Result<T, PyErr>) -> Result<T, PyErr> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(work)).unwrap_or_else(|panic| {
        let message = panic
            .downcast_ref::<&str>()
            .map(|s| (*s).to_owned())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".to_owned());
        Err(Error::new_err(format!(
            "internal error in chunkstore (a bug, please report it): {message}"
        )))
    })
}

/// A dataset that could not be opened or queried: a file's fault as `CorruptFileError`
/// (the file system's own as `OSError`), an unknown index as `UnknownTimelineError`,
/// anything else the caller asked for as `InvalidInputError`.
pub fn dataset_error(error: chunkstore::dataset::DatasetError) -> PyErr {
    use chunkstore::dataset::DatasetError;
    match error {
        DatasetError::Io { path, source } => os_error(&path, source),
        DatasetError::Open(error) => open_error(*error),
        DatasetError::UnknownIndex(unknown) => unknown_timeline(&unknown),
        DatasetError::Dataframe { error, .. } => dataframe_error(error),
        DatasetError::Delta(chunkstore::parquet::delta::DeltaError::Io { path, source }) => {
            os_error(std::path::Path::new(&path), source)
        }
        error @ DatasetError::Delta(chunkstore::parquet::delta::DeltaError::Exists { .. }) => {
            pyo3::exceptions::PyFileExistsError::new_err(error.to_string())
        }
        error @ (DatasetError::NotRrd { .. }
        | DatasetError::NoRecordingId { .. }
        | DatasetError::NoRrdFiles { .. }) => CorruptFileError::new_err(error.to_string()),
        other => invalid(other.to_string()),
    }
}

/// A query SQL could not plan or answer: `InvalidInputError` with DataFusion's message
/// (a table, column or function the query names that is not there, SQL that does not
/// parse); a segment's file that fails while the answer streams is raised from the
/// reader, as pyarrow raises a stream's errors.
pub fn sql_error(error: chunkstore::sql::DataFusionError) -> PyErr {
    invalid(error.to_string())
}
