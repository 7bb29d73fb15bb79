//! Writing what the commands answer: lines to stdout (a reader that stops reading, as
//! `| head` does, is no error), and tables to stdout or to a file (Parquet or Arrow IPC,
//! by the file's name, written atomically), a local one or an object named by URL
//! ([`write_output`]).

use std::io::Write as _;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use arrow_array::RecordBatchReader;
use arrow_schema::ArrowError;
use chunkstore::parquet::{ParquetOptions, write_parquet_file};
use chunkstore::storage::StorageOptions;
use chunkstore::{TimeRange, TimeType, Timeline};

use crate::Failure;

pub type Out<'a> = std::io::BufWriter<std::io::StdoutLock<'a>>;

pub fn stdout() -> Out<'static> {
    std::io::BufWriter::new(std::io::stdout().lock())
}

pub fn write_line(out: &mut Out<'_>, line: &str) -> Result<(), Failure> {
    writeln!(out, "{line}").map_err(|e| stdout_failure(&e))
}

pub fn flush(out: &mut Out<'_>) -> Result<(), Failure> {
    out.flush().map_err(|e| stdout_failure(&e))
}

/// A failed write to stdout: a reader that went away is no error of ours.
fn stdout_failure(error: &std::io::Error) -> Failure {
    match error.kind() {
        std::io::ErrorKind::BrokenPipe => Failure::BrokenPipe,
        _ => Failure::Message(format!("stdout: {error}")),
    }
}

pub fn type_name(time_type: TimeType) -> &'static str {
    match time_type {
        TimeType::Sequence => "sequence",
        TimeType::DurationNs => "duration_ns",
        TimeType::TimestampNs => "timestamp_ns",
    }
}

/// A timeline as `stats` and `print --json` show it: its name, its type and the times
/// its data spans (`null` without any).
pub fn timeline_json(timeline: &Timeline, range: Option<TimeRange>) -> serde_json::Value {
    serde_json::json!({
        "name": timeline.name(),
        "type": type_name(timeline.time_type()),
        "min": range.map(|r| r.min().as_i64()),
        "max": range.map(|r| r.max().as_i64()),
    })
}

/// Writes `table` to the file `out`: Parquet for a name ending `.parquet` (with
/// `parquet`'s options), else an Arrow IPC file; atomically, the output appearing whole or
/// not at all.
pub fn write_file(
    out: &Path,
    table: impl RecordBatchReader,
    parquet: &ParquetOptions,
) -> Result<(), Failure> {
    write_output(out, |out| write_local_file(out, table, parquet))
}

fn write_local_file(
    out: &Path,
    table: impl RecordBatchReader,
    parquet: &ParquetOptions,
) -> Result<(), Failure> {
    let is_parquet = out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("parquet"));
    let written = if is_parquet {
        write_parquet_file(out, table, parquet)
            .map(drop)
            .map_err(|e| e.to_string())
    } else {
        chunkstore::ipc::write_ipc_file(out, table)
            .map(drop)
            .map_err(|e| e.to_string())
    };
    written.map_err(|e| crate::about_path(out, e).into())
}

/// A failed stream to stdout: a reader that went away (`| head -c`) is no error of ours.
pub fn stream_failure(error: &chunkstore::ipc::IpcError) -> Failure {
    match error {
        chunkstore::ipc::IpcError::Ipc(ArrowError::IoError(_, e))
            if e.kind() == std::io::ErrorKind::BrokenPipe =>
        {
            Failure::BrokenPipe
        }
        other => Failure::Message(format!("stdout: {other}")),
    }
}

/// The `--storage-option`s, for outputs named by URL: one set per run of the tool.
static STORAGE: std::sync::OnceLock<StorageOptions> = std::sync::OnceLock::new();

/// Sets the options of the object stores outputs are written to (once, at the start).
pub fn set_storage(options: StorageOptions) {
    let _ = STORAGE.set(options);
}

/// Set while an upload runs: Ctrl-C then cancels it ([`cancel_upload`]) rather than
/// exiting at once, so that it is aborted and leaves nothing in the bucket.
static UPLOADING: AtomicBool = AtomicBool::new(false);

fn cancel_flag() -> &'static Arc<AtomicBool> {
    static CANCEL: std::sync::OnceLock<Arc<AtomicBool>> = std::sync::OnceLock::new();
    CANCEL.get_or_init(|| Arc::new(AtomicBool::new(false)))
}

/// For the Ctrl-C handler: cancels the upload that runs, if one does (it is then aborted
/// and the command exits as interrupted); `false` if none runs.
pub fn cancel_upload() -> bool {
    if UPLOADING.load(Ordering::SeqCst) {
        cancel_flag().store(true, Ordering::SeqCst);
        return true;
    }
    false
}

/// A write's uploads start now (a Delta table's files are placed): from here until
/// [`uploads_ended`], Ctrl-C cancels the upload in progress instead of exiting at once.
pub fn uploads_started() {
    UPLOADING.store(true, Ordering::SeqCst);
}

/// The end of what [`uploads_started`] began: if Ctrl-C cancelled an upload, the command
/// exits as interrupted (the write has removed what it uploaded; `what` names it).
pub fn uploads_ended(what: &str) {
    UPLOADING.store(false, Ordering::SeqCst);
    if cancel_flag().load(Ordering::SeqCst) {
        chunkstore::output::remove_unfinished_outputs();
        eprintln!("error: interrupted ({what})");
        std::process::exit(130);
    }
}

/// The cancel flag of uploads, for a writer that uploads itself.
#[cfg(feature = "object-store")]
pub fn upload_cancel() -> Arc<AtomicBool> {
    Arc::clone(cancel_flag())
}

/// The `--storage-option`s of outputs.
#[cfg(feature = "object-store")]
pub fn storage() -> &'static StorageOptions {
    STORAGE.get_or_init(StorageOptions::default)
}

/// Writes the output `out` with `write`: to the local path itself, or, for a URL, to a
/// local staging file (removed after) that is then uploaded, appearing in the bucket whole
/// or not at all (a multipart upload is completed only once every part is in, and aborted
/// on an error or Ctrl-C).
pub fn write_output(
    out: &Path,
    write: impl FnOnce(&Path) -> Result<(), Failure>,
) -> Result<(), Failure> {
    let is_url = chunkstore::storage::url_scheme(out).is_some();
    let result = chunkstore::storage::write_output(
        out,
        STORAGE.get_or_init(StorageOptions::default),
        cancel_flag(),
        |staged| {
            let written = write(staged);
            // What follows is the upload: Ctrl-C now cancels it (before, it exits at once,
            // removing the staging file).
            UPLOADING.store(is_url, Ordering::SeqCst);
            written
        },
    );
    UPLOADING.store(false, Ordering::SeqCst);
    if is_url && cancel_flag().load(Ordering::SeqCst) {
        // The upload was aborted (nothing of it is in the bucket): exit as interrupted.
        chunkstore::output::remove_unfinished_outputs();
        eprintln!(
            "error: interrupted (the upload to {} was aborted)",
            out.display()
        );
        std::process::exit(130);
    }
    result.map_err(|error| match error {
        chunkstore::storage::OutputError::Write(failure) => failure,
        chunkstore::storage::OutputError::Upload(error) => Failure::Message(error.to_string()),
    })
}
