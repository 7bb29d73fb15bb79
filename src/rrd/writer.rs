//! [`RrdWriter`]: chunks out as an `.rrd` stream Rerun 0.41 opens, with the footer's chunk
//! manifest; and [`write_rrd_file`], which writes a file atomically.

use std::io::Write;
use std::path::Path;
use std::sync::Arc;

use super::error::{RrdError, RrdErrorKind};
use super::frames::{self, MessageKind, StreamFooter, StreamHeader};
use super::manifest::{self, WrittenChunk};
use super::messages::{StoreId, StoreInfo};
use super::payload;
use crate::Chunk;

/// Writes one recording as an `.rrd` stream: the stream header and store info at once,
/// each chunk as it comes, and the footer (chunk manifest) on [`RrdWriter::finish`].
/// Without `finish`, the stream has no footer (readers still read its chunks).
pub struct RrdWriter<W: Write> {
    out: W,
    position: u64,
    store_id: StoreId,
    compress: bool,
    written: Vec<WrittenChunk>,
    /// The ids of `written`, to refuse a second chunk under one.
    written_ids: ahash::HashSet<crate::ChunkId>,
}

impl<W: Write> RrdWriter<W> {
    /// Starts a stream for the recording `store_id`, LZ4-compressed (as Rerun writes).
    ///
    /// # Errors
    /// If writing fails.
    pub fn new(out: W, store_id: StoreId) -> Result<Self, RrdError> {
        Self::with_store_info(out, &StoreInfo::new(store_id), true)
    }

    /// Starts a stream with the given store info (e.g. the one read from a source file, so
    /// that a copy says which SDK logged it), compressing payloads or not.
    ///
    /// # Errors
    /// If writing fails.
    pub fn with_store_info(out: W, info: &StoreInfo, compress: bool) -> Result<Self, RrdError> {
        let mut writer = Self {
            out,
            position: 0,
            store_id: info.store_id.clone(),
            compress,
            written: Vec::new(),
            written_ids: ahash::HashSet::default(),
        };
        let header = StreamHeader {
            version: frames::WRITTEN_VERSION,
            compressed: compress,
        };
        writer.write_bytes(&header.encode())?;
        let row_id = crate::RowId::new().as_u128();
        writer.write_message(
            MessageKind::SetStoreInfo,
            &info.encode_set_store_info(row_id),
        )?;
        Ok(writer)
    }

    fn write_bytes(&mut self, bytes: &[u8]) -> Result<(), RrdError> {
        self.out
            .write_all(bytes)
            .map_err(|e| RrdError::new(self.position, RrdErrorKind::Io(e)))?;
        self.position += bytes.len() as u64;
        Ok(())
    }

    /// Writes a message; returns where its body starts.
    fn write_message(&mut self, kind: MessageKind, body: &[u8]) -> Result<u64, RrdError> {
        self.write_bytes(&frames::encode_message_header(kind, body.len() as u64))?;
        let at = self.position;
        self.write_bytes(body)?;
        Ok(at)
    }

    /// Writes one chunk.
    ///
    /// # Errors
    /// If encoding or writing fails, or ([`RrdErrorKind::DuplicateChunkId`]) if a chunk
    /// under the same id was written already; nothing is written then, and the stream
    /// stays valid.
    pub fn write_chunk(&mut self, chunk: &Arc<Chunk>) -> Result<(), RrdError> {
        if self.written_ids.contains(&chunk.id()) {
            return Err(RrdError::new(
                self.position,
                RrdErrorKind::DuplicateChunkId {
                    chunk_id: chunk.id(),
                },
            ));
        }
        let (body, uncompressed_size) =
            payload::encode_arrow_msg(&self.store_id, chunk, self.compress)
                .map_err(|e| RrdError::new(self.position, RrdErrorKind::Ipc(e)))?;
        let at = self.write_message(MessageKind::ArrowMsg, &body)?;
        self.written.push(WrittenChunk::new(
            chunk,
            at,
            body.len() as u64,
            uncompressed_size,
        ));
        self.written_ids.insert(chunk.id());
        Ok(())
    }

    /// Lists in the footer a chunk this stream does not hold: its message's body is
    /// `byte_size` bytes at `byte_offset` of another file (a detached index,
    /// [`super::index`]).
    pub(crate) fn note_chunk_elsewhere(&mut self, chunk: &Chunk, byte_offset: u64, byte_size: u64) {
        self.written.push(WrittenChunk::new(
            chunk,
            byte_offset,
            byte_size,
            chunk.heap_size_bytes(),
        ));
        self.written_ids.insert(chunk.id());
    }

    /// Bytes written so far.
    pub fn position(&self) -> u64 {
        self.position
    }

    /// Writes the footer (the `End` message with the chunk manifest, then the stream
    /// footer), flushes, and gives back the output.
    ///
    /// # Errors
    /// If encoding or writing fails.
    pub fn finish(mut self) -> Result<W, RrdError> {
        let footer = manifest::encode_footer(&self.store_id, &self.written).map_err(|e| {
            RrdError::new(
                self.position,
                RrdErrorKind::Ipc(crate::ipc::IpcError::Ipc(e)),
            )
        })?;
        let at = self.write_message(MessageKind::End, &footer)?;
        self.write_bytes(&StreamFooter::for_footer(at, &footer).encode())?;
        self.out
            .flush()
            .map_err(|e| RrdError::new(self.position, RrdErrorKind::Io(e)))?;
        Ok(self.out)
    }
}

/// Writes `chunks` as an `.rrd` file at `path`, atomically: into a temporary file in the
/// same directory, synced, then renamed over `path`. If anything fails (or the process
/// dies), `path` is untouched and the temporary file is removed (or, after a crash, left
/// under a name starting with `.` and ending `.tmp`). `progress` is called after each
/// chunk with the bytes written so far. Returns the file's size in bytes, footer included.
///
/// # Errors
/// [`RrdErrorKind::Io`] if the file cannot be created, written, synced or renamed.
pub fn write_rrd_file(
    path: &Path,
    info: &StoreInfo,
    chunks: impl IntoIterator<Item = Arc<Chunk>>,
    mut progress: impl FnMut(u64),
) -> Result<u64, RrdError> {
    crate::output::atomic_write(
        path,
        |e| RrdError::new(0, RrdErrorKind::Io(e)),
        |file| {
            let mut writer = RrdWriter::with_store_info(std::io::BufWriter::new(file), info, true)?;
            for chunk in chunks {
                writer.write_chunk(&chunk)?;
                progress(writer.position());
            }
            let before_footer = writer.position();
            let out = writer.finish()?;
            let file = out
                .into_inner()
                .map_err(|e| RrdError::new(before_footer, RrdErrorKind::Io(e.into_error())))?;
            // The footer's length is the encoder's business: the file says what it came to.
            let size = file
                .metadata()
                .map_err(|e| RrdError::new(before_footer, RrdErrorKind::Io(e)))?
                .len();
            Ok((file, size))
        },
    )
}
