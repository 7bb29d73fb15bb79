//! An `ArrowMsg`'s payload: one chunk as an Arrow IPC stream, LZ4-compressed as one block
//! (or not compressed), to and from a [`Chunk`].

use arrow_buffer::Buffer;
use arrow_ipc::writer::StreamWriter;

use super::error::RrdErrorKind;
use super::messages::Compression;
use crate::Chunk;
use crate::error::IoError;

/// LZ4 cannot expand more than about 255 times (a match of at most 255 × 255 + … bytes per
/// few bytes of input): a claimed size beyond this is a lie, refused before allocating it.
const LZ4_MAX_RATIO: u64 = 256;

/// A payload's bytes: part of a buffer the chunk may share, or borrowed (copied if the
/// chunk must keep them).
pub(crate) enum PayloadBytes<'a> {
    Shared(Buffer),
    Borrowed(&'a [u8]),
}

impl PayloadBytes<'_> {
    fn as_slice(&self) -> &[u8] {
        match self {
            Self::Shared(buffer) => buffer.as_slice(),
            Self::Borrowed(bytes) => bytes,
        }
    }
}

/// Decompresses (if needed) and decodes a payload into a chunk. An uncompressed shared
/// payload is decoded in place: the chunk's buffers are slices of it.
pub(crate) fn decode_chunk(
    payload: PayloadBytes<'_>,
    compression: Compression,
    uncompressed_size: u64,
) -> Result<Chunk, RrdErrorKind> {
    let ipc = match (compression, payload) {
        (Compression::None, PayloadBytes::Shared(buffer)) => buffer,
        (Compression::None, PayloadBytes::Borrowed(bytes)) => Buffer::from(bytes.to_vec()),
        (Compression::Lz4, payload) => {
            Buffer::from_vec(decompress(payload.as_slice(), uncompressed_size)?)
        }
    };
    let mut batches = crate::io::read_stream_batches_zero_copy(ipc).map_err(RrdErrorKind::Ipc)?;
    if batches.len() != 1 {
        return Err(RrdErrorKind::Payload {
            reason: format!(
                "{} record batches where one chunk was expected",
                batches.len()
            ),
        });
    }
    let batch = batches.pop().ok_or_else(|| RrdErrorKind::Payload {
        reason: "no record batch".to_owned(),
    })?;
    Chunk::from_record_batch(&batch).map_err(RrdErrorKind::Chunk)
}

/// One LZ4 block of known decompressed size.
pub(crate) fn decompress(block: &[u8], uncompressed_size: u64) -> Result<Vec<u8>, RrdErrorKind> {
    let limit = (block.len() as u64).saturating_mul(LZ4_MAX_RATIO) + 64;
    let size = usize::try_from(uncompressed_size)
        .ok()
        .filter(|_| uncompressed_size <= limit)
        .ok_or_else(|| RrdErrorKind::Payload {
            reason: format!(
                "claims {uncompressed_size} bytes decompressed from a {}-byte LZ4 block",
                block.len()
            ),
        })?;
    let mut out = vec![0u8; size];
    let written =
        lz4_flex::block::decompress_into(block, &mut out).map_err(|e| RrdErrorKind::Payload {
            reason: format!("corrupt LZ4 block: {e}"),
        })?;
    if written != size {
        return Err(RrdErrorKind::Payload {
            reason: format!("LZ4 block decompressed to {written} bytes, not the {size} claimed"),
        });
    }
    Ok(out)
}

/// Encodes a chunk as a payload: the IPC stream and, if compressing, its LZ4 block.
/// Returns the payload and the IPC stream's size.
pub(crate) fn encode_chunk(chunk: &Chunk, compress: bool) -> Result<(Vec<u8>, u64), IoError> {
    let batch = chunk.to_record_batch().map_err(IoError::Ipc)?;
    let mut ipc = Vec::new();
    let mut writer = StreamWriter::try_new(&mut ipc, &batch.schema()).map_err(IoError::Ipc)?;
    writer.write(&batch).map_err(IoError::Ipc)?;
    writer.finish().map_err(IoError::Ipc)?;
    drop(writer);
    let size = ipc.len() as u64;
    if compress {
        Ok((lz4_flex::block::compress(&ipc), size))
    } else {
        Ok((ipc, size))
    }
}
