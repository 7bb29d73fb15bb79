//! Arrow IPC helpers (feature `ipc`): decode chunks from IPC files and streams, and encode
//! a chunk as an IPC file. Every decoding failure is an [`IpcError`], never a panic.

use std::fmt;
use std::io::{Cursor, Write};
use std::path::Path;

use arrow_array::{RecordBatch, RecordBatchReader};
use arrow_buffer::Buffer;
use arrow_ipc::reader::{FileReader, StreamReader};
use arrow_ipc::writer::{FileWriter, StreamWriter};
use arrow_schema::ArrowError;

use crate::{Chunk, ChunkError};

mod batch_decoder;
mod batch_message;
mod schema_cache;
mod schema_layout;
mod stream;

#[cfg(feature = "rrd")]
pub(crate) use stream::StreamBatches;
#[cfg(test)]
mod tests;

/// The first bytes of an Arrow IPC *file* (a stream starts with a message instead).
const FILE_MAGIC: &[u8] = b"ARROW1";

/// Decodes every chunk in `bytes`, which hold an Arrow IPC file or stream of transport
/// batches (one chunk per batch).
///
/// # Errors
/// [`IpcError::Ipc`] if the bytes are not Arrow IPC, [`IpcError::Chunk`] naming the batch
/// that is not a valid chunk.
pub fn read_chunks_from_bytes(bytes: &[u8]) -> Result<Vec<Chunk>, IpcError> {
    read_batches(bytes)?
        .iter()
        .enumerate()
        .map(|(batch, record_batch)| {
            Chunk::from_record_batch(record_batch)
                .map_err(|source| IpcError::Chunk { batch, source })
        })
        .collect()
}

/// Reads a file and decodes it with [`read_chunks_from_bytes`].
///
/// # Errors
/// [`IpcError::Io`] if the file cannot be read, otherwise as [`read_chunks_from_bytes`].
pub fn read_chunks_from_path(path: impl AsRef<Path>) -> Result<Vec<Chunk>, IpcError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|source| IpcError::Io {
        path: path.to_owned(),
        source,
    })?;
    read_chunks_from_bytes(&bytes)
}

/// File name extensions [`chunk_files`] takes for Arrow IPC.
pub const IPC_EXTENSIONS: [&str; 4] = ["arrow", "arrows", "ipc", "feather"];

/// The Arrow IPC files of a directory (by extension: [`IPC_EXTENSIONS`]), sorted by
/// name: a directory of chunk files, as Rerun's exports and `chunkstore convert` write
/// them. Empty if there are none (the caller decides whether that is an error).
///
/// # Errors
/// [`IpcError::Io`] if the directory cannot be listed.
pub fn chunk_files(dir: impl AsRef<Path>) -> Result<Vec<std::path::PathBuf>, IpcError> {
    let dir = dir.as_ref();
    let io = |source| IpcError::Io {
        path: dir.to_owned(),
        source,
    };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        let is_ipc = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| IPC_EXTENSIONS.contains(&e));
        if is_ipc && path.is_file() {
            files.push(path);
        }
    }
    files.sort();
    Ok(files)
}

/// Decodes the record batches of an Arrow IPC file or stream.
///
/// The framing is checked first ([`IpcError::MalformedFraming`]): arrow-ipc allocates
/// whatever size a message or footer block claims before reading it, so a few hostile
/// bytes could otherwise request terabytes, which aborts the process.
///
/// arrow-ipc 58 panics on some malformed inputs instead of returning an error (e.g. a
/// buffer offset past the end of the body, or schema fields it does not expect; see
/// apache/arrow-rs#10437). Decoding therefore runs under `catch_unwind`, so a bad file
/// is an [`IpcError::DecoderPanicked`] rather than a crash of the embedding process. The
/// closure owns only a reader over the caller's bytes, dropped whole on a panic, so no
/// half-updated state can be observed afterwards. (The process's panic hook still runs
/// and, by default, prints the message.)
///
/// # Errors
/// [`IpcError::Ipc`] or [`IpcError::DecoderPanicked`] if the bytes are not valid Arrow IPC.
pub fn read_batches(bytes: &[u8]) -> Result<Vec<RecordBatch>, IpcError> {
    check_framing(bytes)?;
    contain_panics(|| {
        if bytes.starts_with(FILE_MAGIC) {
            FileReader::try_new(Cursor::new(bytes), None).and_then(Iterator::collect)
        } else {
            StreamReader::try_new(Cursor::new(bytes), None).and_then(Iterator::collect)
        }
        .map_err(IpcError::Ipc)
    })
}

/// Decodes the record batches of an Arrow IPC *stream* held in an Arrow [`Buffer`],
/// without copying: the batches' buffers are slices of `buffer` (which they keep alive).
/// Checked and contained as [`read_batches`] is. A schema message equal to one this thread
/// parsed recently, but for its metadata values, reuses that parse (see
/// [`without_schema_cache`]).
///
/// # Errors
/// As [`read_batches`].
#[allow(
    clippy::needless_pass_by_value,
    reason = "the batches hold slices of the buffer; taking it whole is the public signature"
)]
pub fn read_stream_batches_zero_copy(buffer: Buffer) -> Result<Vec<RecordBatch>, IpcError> {
    read_stream_zero_copy(&buffer)?
        .into_iter()
        .map(stream::StreamBatch::into_record_batch)
        .collect()
}

/// Decodes the chunks of an Arrow IPC *stream* of transport batches (one chunk per batch)
/// held in an Arrow [`Buffer`], without copying: the chunks' buffers are slices of `buffer`.
/// The chunks are those [`Chunk::from_record_batch`] makes of
/// [`read_stream_batches_zero_copy`]'s batches, but a batch whose schema message this
/// thread parsed recently (see [`without_schema_cache`]) goes into its chunk with no
/// `Schema` or `RecordBatch` built for it.
///
/// # Errors
/// As [`read_batches`], and [`IpcError::Chunk`] naming the first batch that is not a valid
/// chunk.
pub fn read_stream_chunks_zero_copy(buffer: &Buffer) -> Result<Vec<Chunk>, IpcError> {
    read_stream_zero_copy(buffer)?
        .into_iter()
        .enumerate()
        .map(|(batch, parts)| {
            parts
                .into_chunk()
                .map_err(|source| IpcError::Chunk { batch, source })
        })
        .collect()
}

/// [`read_stream_batches_zero_copy`]'s batches as the parts a chunk is made of, each
/// turned into a chunk by [`stream::StreamBatch::into_chunk`] without a `RecordBatch`.
///
/// # Errors
/// As [`read_batches`].
pub(crate) fn read_stream_zero_copy(
    buffer: &Buffer,
) -> Result<stream::StreamBatches<'_>, IpcError> {
    contain_panics(|| stream::decode_stream(buffer))
}

/// Runs `decode` with this thread's cache of parsed IPC schemas off: every schema message
/// met inside is verified and parsed in full, and none is kept. Decoding gives the same
/// answer either way (the cache only reuses a schema where it can prove the full decode
/// would give it); this is how the fuzz target and the tests check that.
///
/// The cache: every chunk of an `.rrd` stream carries an IPC schema message that differs
/// from its entity's previous ones only in metadata values (the chunk id), so
/// [`read_stream_batches_zero_copy`] keeps, per thread, the last few schema messages it
/// parsed (at most 64, 1 MiB in all) and reuses one for a message equal to it but in those
/// values.
// Not part of the API: a hook for the fuzz targets and tests, hidden from the docs.
#[doc(hidden)]
pub fn without_schema_cache<T>(decode: impl FnOnce() -> T) -> T {
    schema_cache::without(decode)
}

/// Runs `decode` with this thread's own batch decoder off: every record batch met inside
/// is decoded by arrow-ipc's reader. Decoding gives the same answer either way (the own
/// decoder builds only batches it checks as arrow-ipc would accept them, and hands anything
/// else to arrow-ipc), but for inputs on which arrow-ipc's reader panics (reported as
/// [`IpcError::DecoderPanicked`]) and the own decoder builds a valid batch. The
/// `ipc_batch_decoder` fuzz target checks exactly that.
///
/// The own decoder (`ipc/batch_decoder.rs`) builds the arrays chunks are made of with
/// arrow's typed constructors, which check what they need once, where arrow-ipc's reader
/// validates a generic `ArrayData` per array.
// Not part of the API: a hook for the fuzz targets and tests, hidden from the docs.
#[doc(hidden)]
pub fn without_own_batch_decoder<T>(decode: impl FnOnce() -> T) -> T {
    batch_decoder::without(decode)
}

/// Empties this thread's cache of parsed IPC schemas (see [`without_schema_cache`]), so
/// that what follows starts from nothing, as a fuzz input must.
// Not part of the API: a hook for the fuzz targets and tests, hidden from the docs.
#[doc(hidden)]
pub fn clear_schema_cache() {
    schema_cache::clear();
}

/// Runs `decode` with this thread's `flag` set (a part of decoding turned off), and sets it
/// back as it was however `decode` ends (a contained panic included).
fn with_flag_set<T>(
    flag: &'static std::thread::LocalKey<std::cell::Cell<bool>>,
    decode: impl FnOnce() -> T,
) -> T {
    struct Restore(&'static std::thread::LocalKey<std::cell::Cell<bool>>, bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            self.0.with(|flag| flag.set(self.1));
        }
    }
    let _restore = Restore(flag, flag.with(|flag| flag.replace(true)));
    decode()
}

/// Runs an arrow-ipc decode, turning a panic into [`IpcError::DecoderPanicked`] with its
/// message (see [`read_batches`]).
fn contain_panics<T>(decode: impl FnOnce() -> Result<T, IpcError>) -> Result<T, IpcError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(decode)).unwrap_or_else(|payload| {
        let message = payload
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| payload.downcast_ref::<&str>().map(|s| (*s).to_owned()))
            .unwrap_or_else(|| "unknown panic".to_owned());
        Err(IpcError::DecoderPanicked { message })
    })
}

/// Writes one chunk as an Arrow IPC file in the transport layout, its rows in row-id order.
///
/// # Errors
/// [`IpcError::Ipc`] if Arrow fails to encode or write.
pub fn write_chunk_ipc_file(chunk: &Chunk, writer: impl Write) -> Result<(), IpcError> {
    let batch = export_batch(chunk)?;
    let mut writer = FileWriter::try_new(writer, &batch.schema()).map_err(IpcError::Ipc)?;
    writer.write(&batch).map_err(IpcError::Ipc)?;
    writer.finish().map_err(IpcError::Ipc)
}

/// The chunk as it goes into a file: in the transport layout, its rows in row-id order
/// (Rerun refuses a chunk whose row ids are out of order; see [`Chunk::sorted_by_row_id`]).
pub(crate) fn export_batch(chunk: &Chunk) -> Result<arrow_array::RecordBatch, IpcError> {
    let sorted = chunk
        .sorted_by_row_id()
        .map_err(|e| IpcError::Ipc(ArrowError::ComputeError(e.to_string())))?;
    sorted
        .as_ref()
        .unwrap_or(chunk)
        .to_record_batch()
        .map_err(IpcError::Ipc)
}

/// Writes every batch `reader` yields as an Arrow IPC **file** at `path`, atomically: the
/// file appears whole, or (on any error, the reader's included) not at all. Returns the
/// number of rows written.
///
/// # Errors
/// [`IpcError::Io`] for the file system, [`IpcError::Ipc`] for Arrow (or the reader's own
/// error).
pub fn write_ipc_file(path: &Path, reader: impl RecordBatchReader) -> Result<u64, IpcError> {
    let io = |source| IpcError::Io {
        path: path.to_owned(),
        source,
    };
    // Arrow reports the file system's errors as its own: a full disk is not bad Arrow.
    let written = |error: ArrowError| match error {
        ArrowError::IoError(_, source) => io(source),
        other => IpcError::Ipc(other),
    };
    crate::output::atomic_write(path, io, |file| {
        let schema = reader.schema();
        let mut writer =
            FileWriter::try_new(std::io::BufWriter::new(file), &schema).map_err(written)?;
        let mut rows = 0;
        for batch in reader {
            let batch = batch.map_err(IpcError::Ipc)?;
            rows += batch.num_rows() as u64;
            writer.write(&batch).map_err(written)?;
        }
        writer.finish().map_err(written)?;
        let file = writer
            .into_inner()
            .map_err(written)?
            .into_inner()
            .map_err(|e| io(e.into_error()))?;
        Ok((file, rows))
    })
}

/// Writes every batch `reader` yields as an Arrow IPC **stream** to `writer` (a pipe, a
/// socket, stdout), batch by batch. Returns the number of rows written.
///
/// # Errors
/// [`IpcError::Ipc`] for Arrow, the writer (its I/O errors come wrapped by Arrow) or the
/// reader.
pub fn write_ipc_stream(
    writer: impl Write,
    reader: impl RecordBatchReader,
) -> Result<u64, IpcError> {
    let mut writer = StreamWriter::try_new(writer, &reader.schema()).map_err(IpcError::Ipc)?;
    let mut rows = 0;
    for batch in reader {
        let batch = batch.map_err(IpcError::Ipc)?;
        rows += batch.num_rows() as u64;
        writer.write(&batch).map_err(IpcError::Ipc)?;
    }
    writer.finish().map_err(IpcError::Ipc)?;
    Ok(rows)
}

/// Checks that every size the IPC framing claims fits in `bytes`, so that no decoder
/// allocation can exceed the input.
fn check_framing(bytes: &[u8]) -> Result<(), IpcError> {
    if bytes.starts_with(FILE_MAGIC) {
        check_file_footer(bytes)
    } else {
        check_stream_messages(bytes)
    }
}

/// The little-endian `i32` at byte `at`, if four bytes are there.
fn read_i32_le(bytes: &[u8], at: usize) -> Option<i32> {
    let four = bytes.get(at..at.checked_add(4)?)?;
    Some(i32::from_le_bytes([four[0], four[1], four[2], four[3]]))
}

fn malformed(reason: String) -> IpcError {
    IpcError::MalformedFraming { reason }
}

/// Does `start + lengths...` stay within `total`, with no negative part?
fn fits(total: usize, parts: &[i64]) -> bool {
    parts.iter().all(|&p| p >= 0)
        && parts.iter().map(|&p| i128::from(p)).sum::<i128>() <= total as i128
}

/// File format: the footer must fit before the trailer, and its dictionary and record
/// batch blocks (the ones arrow-ipc allocates for) inside the file.
fn check_file_footer(bytes: &[u8]) -> Result<(), IpcError> {
    let len = bytes.len();
    let trailer = len
        .checked_sub(FILE_MAGIC.len() + 4)
        .filter(|_| bytes.ends_with(FILE_MAGIC));
    let Some(trailer) = trailer else {
        return Err(malformed(
            "file does not end with the ARROW1 trailer".into(),
        ));
    };
    let footer_len = read_i32_le(bytes, trailer).unwrap_or(-1);
    let footer_start = usize::try_from(footer_len)
        .ok()
        .and_then(|n| trailer.checked_sub(n));
    let Some(footer_start) = footer_start else {
        return Err(malformed(format!(
            "footer length {footer_len} does not fit the file"
        )));
    };
    let footer = arrow_ipc::root_as_footer(&bytes[footer_start..trailer])
        .map_err(|e| malformed(format!("footer: {e}")))?;
    let blocks = footer
        .recordBatches()
        .into_iter()
        .chain(footer.dictionaries())
        .flatten();
    for block in blocks {
        let parts = [
            block.offset(),
            i64::from(block.metaDataLength()),
            block.bodyLength(),
        ];
        if !fits(len, &parts) {
            return Err(malformed(format!(
                "block {parts:?} (offset, metadata, body) exceeds the {len}-byte file"
            )));
        }
    }
    Ok(())
}

/// Stream format: each message's metadata and body must lie inside the input.
fn check_stream_messages(bytes: &[u8]) -> Result<(), IpcError> {
    for_each_stream_message(bytes, |_, _| Ok(()))
}

/// One message of an IPC stream: where its metadata (a flatbuffer) lies in the input.
struct Frame {
    metadata: std::ops::Range<usize>,
}

/// The next message's metadata after byte `pos`, advancing `pos` past the framing: `None`
/// at the end-of-stream marker or the end of the input. Bytes after the marker are an
/// error, as in arrow-ipc's own readers.
fn next_frame(bytes: &[u8], pos: &mut usize) -> Result<Option<Frame>, IpcError> {
    let len = bytes.len();
    if *pos >= len {
        return Ok(None);
    }
    let Some(mut meta_len) = read_i32_le(bytes, *pos) else {
        return Err(malformed(format!("truncated message length at byte {pos}")));
    };
    *pos += 4;
    if meta_len == -1 {
        // Continuation marker; the length follows.
        meta_len = read_i32_le(bytes, *pos)
            .ok_or_else(|| malformed(format!("truncated message length at byte {pos}")))?;
        *pos += 4;
    }
    if meta_len == 0 {
        // The end-of-stream marker.
        if *pos < len {
            return Err(malformed(format!(
                "{} bytes after the end-of-stream marker at byte {pos}",
                len - *pos
            )));
        }
        return Ok(None);
    }
    let meta_end = usize::try_from(meta_len)
        .ok()
        .and_then(|n| pos.checked_add(n))
        .filter(|&end| end <= len);
    let Some(meta_end) = meta_end else {
        return Err(malformed(format!(
            "message metadata of {meta_len} bytes at byte {pos} exceeds the input"
        )));
    };
    let frame = Frame {
        metadata: *pos..meta_end,
    };
    *pos = meta_end;
    Ok(Some(frame))
}

/// The body a message declares, checked to lie inside the input, right after the message's
/// metadata.
fn body_range(
    bytes: &[u8],
    frame: &Frame,
    body_length: i64,
) -> Result<std::ops::Range<usize>, IpcError> {
    let meta_end = frame.metadata.end;
    if !fits(
        bytes.len(),
        &[i64::try_from(meta_end).unwrap_or(i64::MAX), body_length],
    ) {
        return Err(malformed(format!(
            "message body of {body_length} bytes at byte {meta_end} exceeds the input"
        )));
    }
    Ok(meta_end..meta_end + usize::try_from(body_length).unwrap_or(usize::MAX))
}

/// Verifies a message's flatbuffer.
fn verify_message<'a>(bytes: &'a [u8], frame: &Frame) -> Result<arrow_ipc::Message<'a>, IpcError> {
    arrow_ipc::root_as_message(&bytes[frame.metadata.clone()])
        .map_err(|e| malformed(format!("message at byte {}: {e}", frame.metadata.start)))
}

/// Walks the messages of an IPC stream, each verified as a flatbuffer once and its body
/// checked to lie inside `bytes`, calling `visit` with the message and its body's range,
/// until the end-of-stream marker or the end of the input.
fn for_each_stream_message(
    bytes: &[u8],
    mut visit: impl FnMut(arrow_ipc::Message<'_>, std::ops::Range<usize>) -> Result<(), IpcError>,
) -> Result<(), IpcError> {
    let mut pos = 0usize;
    while let Some(frame) = next_frame(bytes, &mut pos)? {
        let message = verify_message(bytes, &frame)?;
        let body = body_range(bytes, &frame, message.bodyLength())?;
        pos = body.end;
        visit(message, body)?;
    }
    Ok(())
}

/// Reading chunks from Arrow IPC failed.
#[derive(Debug)]
#[non_exhaustive]
pub enum IpcError {
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

impl fmt::Display for IpcError {
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

impl std::error::Error for IpcError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io { source, .. } => Some(source),
            Self::Ipc(e) => Some(e),
            Self::Chunk { source, .. } => Some(source),
            Self::DecoderPanicked { .. } | Self::MalformedFraming { .. } => None,
        }
    }
}
