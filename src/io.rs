//! Arrow IPC helpers (feature `ipc`): decode chunks from IPC files and streams, and encode
//! a chunk as an IPC file. Every decoding failure is an [`IoError`], never a panic.

use std::io::{Cursor, Write};
use std::path::Path;

use arrow_array::RecordBatch;
use arrow_ipc::reader::{FileReader, StreamReader};
use arrow_ipc::writer::FileWriter;
use arrow_schema::ArrowError;

use crate::Chunk;
use crate::error::IoError;

/// The first bytes of an Arrow IPC *file* (a stream starts with a message instead).
const FILE_MAGIC: &[u8] = b"ARROW1";

/// Decodes every chunk in `bytes`, which hold an Arrow IPC file or stream of transport
/// batches (one chunk per batch).
///
/// # Errors
/// [`IoError::Ipc`] if the bytes are not Arrow IPC, [`IoError::Chunk`] naming the batch
/// that is not a valid chunk.
pub fn read_chunks_from_bytes(bytes: &[u8]) -> Result<Vec<Chunk>, IoError> {
    read_batches(bytes)?
        .iter()
        .enumerate()
        .map(|(batch, record_batch)| {
            Chunk::from_record_batch(record_batch)
                .map_err(|source| IoError::Chunk { batch, source })
        })
        .collect()
}

/// Reads a file and decodes it with [`read_chunks_from_bytes`].
///
/// # Errors
/// [`IoError::Io`] if the file cannot be read, otherwise as [`read_chunks_from_bytes`].
pub fn read_chunks_from_path(path: impl AsRef<Path>) -> Result<Vec<Chunk>, IoError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|source| IoError::Io {
        path: path.to_owned(),
        source,
    })?;
    read_chunks_from_bytes(&bytes)
}

/// Decodes the record batches of an Arrow IPC file or stream.
///
/// arrow-ipc 58 panics on some malformed inputs instead of returning an error (e.g. a
/// buffer offset past the end of the body, or schema fields it does not expect; see
/// apache/arrow-rs#10437). Decoding therefore runs under `catch_unwind`, so a bad file
/// is an [`IoError::DecoderPanicked`] rather than a crash of the embedding process. The
/// closure owns only a reader over the caller's bytes, dropped whole on a panic, so no
/// half-updated state can be observed afterwards. (The process's panic hook still runs
/// and, by default, prints the message.)
///
/// # Errors
/// [`IoError::Ipc`] or [`IoError::DecoderPanicked`] if the bytes are not valid Arrow IPC.
pub fn read_batches(bytes: &[u8]) -> Result<Vec<RecordBatch>, IoError> {
    let decode = || -> Result<Vec<RecordBatch>, ArrowError> {
        if bytes.starts_with(FILE_MAGIC) {
            FileReader::try_new(Cursor::new(bytes), None).and_then(Iterator::collect)
        } else {
            StreamReader::try_new(Cursor::new(bytes), None).and_then(Iterator::collect)
        }
    };
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(decode)) {
        Ok(batches) => batches.map_err(IoError::Ipc),
        Err(payload) => {
            let message = payload
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| payload.downcast_ref::<&str>().map(|s| (*s).to_owned()))
                .unwrap_or_else(|| "unknown panic".to_owned());
            Err(IoError::DecoderPanicked { message })
        }
    }
}

/// Writes one chunk as an Arrow IPC file in the transport layout.
///
/// # Errors
/// [`IoError::Ipc`] if Arrow fails to encode or write.
pub fn write_chunk_ipc_file(chunk: &Chunk, writer: impl Write) -> Result<(), IoError> {
    let batch = chunk.to_record_batch().map_err(IoError::Ipc)?;
    let mut writer = FileWriter::try_new(writer, &batch.schema()).map_err(IoError::Ipc)?;
    writer.write(&batch).map_err(IoError::Ipc)?;
    writer.finish().map_err(IoError::Ipc)
}
