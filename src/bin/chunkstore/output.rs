//! Writing what the commands answer: lines to stdout (a reader that stops reading, as
//! `| head` does, is no error), and tables to stdout or to a file (Parquet or Arrow IPC,
//! by the file's name, written atomically).

use std::io::Write as _;
use std::path::Path;

use arrow_array::RecordBatchReader;
use arrow_schema::ArrowError;
use chunkstore::parquet::{ParquetOptions, write_parquet_file};
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
