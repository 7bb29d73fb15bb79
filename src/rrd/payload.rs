//! An `ArrowMsg`'s payload: one chunk as an Arrow IPC stream, LZ4-compressed as one block
//! (or not compressed), to and from a [`Chunk`].

use arrow_array::RecordBatch;
use arrow_buffer::Buffer;
use arrow_ipc::writer::StreamWriter;
use arrow_schema::{ArrowError, Schema};

use super::error::{RrdError, RrdErrorKind};
use super::messages::{ArrowMsg, Compression, StoreId};
use crate::Chunk;
use crate::ipc::IpcError;

/// LZ4 cannot expand more than about 255 times (a match of at most 255 × 255 + … bytes per
/// few bytes of input): a claimed size beyond this is a lie, refused before allocating it.
const LZ4_MAX_RATIO: u64 = 256;

/// An uncompressed payload this small that is not aligned to [`REALIGN_TO`] bytes is
/// copied whole into an aligned buffer before decoding.
const REALIGN_WHOLE_MAX: usize = 64 * 1024;

/// The alignment an IPC body's buffers need (8 for 64-bit values, 16 for 128-bit
/// decimals); the body pads each buffer to 8 bytes from its start.
const REALIGN_TO: usize = 16;

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
    let ipc = ipc_stream_of(payload, compression, uncompressed_size)?;
    chunk_of_stream(crate::ipc::read_stream_zero_copy(&ipc))
}

/// A payload's IPC stream: decompressed, or the payload itself (shared where it can be).
pub(crate) fn ipc_stream_of(
    payload: PayloadBytes<'_>,
    compression: Compression,
    uncompressed_size: u64,
) -> Result<Buffer, RrdErrorKind> {
    Ok(match (compression, payload) {
        (Compression::None, PayloadBytes::Shared(buffer))
            if buffer.len() <= REALIGN_WHOLE_MAX && buffer.as_ptr().addr() % REALIGN_TO != 0 =>
        {
            // arrow-ipc copies each misaligned buffer of the batch on its own (an allocation
            // and a copy per array); one copy of a small payload into an aligned buffer is
            // cheaper. A larger payload stays shared: its byte arrays (images, blobs), which
            // need no alignment, are not copied.
            Buffer::from_slice_ref(buffer.as_slice())
        }
        (Compression::None, PayloadBytes::Shared(buffer)) => buffer,
        (Compression::None, PayloadBytes::Borrowed(bytes)) => Buffer::from(bytes.to_vec()),
        (Compression::Lz4, payload) => {
            Buffer::from_vec(decompress(payload.as_slice(), uncompressed_size)?)
        }
    })
}

/// The one chunk of a payload's decoded IPC stream.
pub(crate) fn chunk_of_stream(
    decoded: Result<crate::ipc::StreamBatches<'_>, IpcError>,
) -> Result<Chunk, RrdErrorKind> {
    let mut batches = decoded.map_err(RrdErrorKind::Ipc)?;
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
    batch.into_chunk().map_err(RrdErrorKind::Chunk)
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

/// An Arrow IPC stream: the schema, then `batch` if given, then the end marker.
pub(crate) fn ipc_stream(
    schema: &Schema,
    batch: Option<&RecordBatch>,
) -> Result<Vec<u8>, ArrowError> {
    let mut out = Vec::new();
    let mut writer = StreamWriter::try_new(&mut out, schema)?;
    if let Some(batch) = batch {
        writer.write(batch)?;
    }
    writer.finish()?;
    drop(writer);
    Ok(out)
}

/// Encodes a chunk as a payload: the IPC stream and, if compressing, its LZ4 block.
/// Returns the payload and the IPC stream's size.
pub(crate) fn encode_chunk(chunk: &Chunk, compress: bool) -> Result<(Vec<u8>, u64), IpcError> {
    let batch = crate::ipc::export_batch(chunk)?;
    let ipc = ipc_stream(&batch.schema(), Some(&batch)).map_err(IpcError::Ipc)?;
    let size = ipc.len() as u64;
    if compress {
        Ok((lz4_flex::block::compress(&ipc), size))
    } else {
        Ok((ipc, size))
    }
}

/// An `ArrowMsg` body carrying `chunk` of `store_id`, its payload LZ4-compressed if
/// `compress`; and the size of the payload's uncompressed IPC stream.
pub(crate) fn encode_arrow_msg(
    store_id: &StoreId,
    chunk: &Chunk,
    compress: bool,
) -> Result<(Vec<u8>, u64), IpcError> {
    let (payload, uncompressed_size) = encode_chunk(chunk, compress)?;
    let compression = if compress {
        Compression::Lz4
    } else {
        Compression::None
    };
    let body = ArrowMsg::encode(
        store_id,
        chunk.id(),
        chunk.is_static(),
        compression,
        uncompressed_size,
        &payload,
    );
    Ok((body, uncompressed_size))
}

/// The chunk an `ArrowMsg` carries, checked against what the message says of it (its id
/// and static flag). `body_at` is where the message body starts in the input, for errors.
pub(crate) fn decode_message_chunk(
    msg: &ArrowMsg,
    payload: PayloadBytes<'_>,
    body_at: u64,
) -> Result<Chunk, RrdError> {
    let chunk = decode_chunk(payload, msg.compression, msg.uncompressed_size)
        .map_err(|kind| RrdError::new(payload_at(msg, body_at), kind))?;
    check_message_chunk(msg, chunk, body_at)
}

/// Where a message's payload starts, for its errors.
pub(crate) fn payload_at(msg: &ArrowMsg, body_at: u64) -> u64 {
    body_at + msg.payload.start as u64
}

/// The chunk of a message, checked against what the message says of it.
pub(crate) fn check_message_chunk(
    msg: &ArrowMsg,
    chunk: Chunk,
    body_at: u64,
) -> Result<Chunk, RrdError> {
    let mismatch = |reason| RrdError::new(body_at, RrdErrorKind::Payload { reason });
    if let Some(is_static) = msg.is_static
        && is_static != chunk.is_static()
    {
        return Err(mismatch(format!(
            "the message says is_static = {is_static}, its chunk {} is not",
            chunk.id()
        )));
    }
    if let Some(id) = msg.chunk_id
        && id != chunk.id()
    {
        return Err(mismatch(format!(
            "the message says chunk {id}, its payload is chunk {}",
            chunk.id()
        )));
    }
    Ok(chunk)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on unexpected values")]

    use std::sync::Arc;

    use arrow_array::{ArrayRef, Float64Array, Int64Array, ListArray};
    use arrow_buffer::OffsetBuffer;
    use arrow_schema::{DataType, Field};

    use super::*;
    use crate::{ChunkId, EntityPath, RowId, Timeline};

    /// An uncompressed payload decodes to the same chunk wherever it lies in its buffer:
    /// aligned and shared, misaligned and copied whole (small), or misaligned and left to
    /// arrow-ipc's per-array copies (large).
    #[test]
    fn an_uncompressed_payload_decodes_alike_at_every_alignment() {
        for rows in [3_usize, 5_000] {
            let values = Float64Array::from_iter_values(
                (0..rows * 2).map(|v| f64::from(u32::try_from(v).unwrap())),
            );
            let list = ListArray::new(
                Arc::new(Field::new("item", DataType::Float64, true)),
                OffsetBuffer::from_lengths(std::iter::repeat_n(2, rows)),
                Arc::new(values),
                None,
            );
            let n = i64::try_from(rows).unwrap();
            let chunk = Chunk::try_new(
                ChunkId::new(),
                EntityPath::parse("/a").unwrap(),
                (1..=u128::try_from(rows).unwrap())
                    .map(RowId::from_u128)
                    .collect(),
                vec![(
                    Timeline::sequence("frame"),
                    Arc::new(Int64Array::from_iter_values(0..n)) as ArrayRef,
                )],
                vec![("x".into(), Arc::new(list) as ArrayRef)],
            )
            .unwrap();
            let (ipc, size) = encode_chunk(&chunk, false).unwrap();
            assert_eq!(
                rows > 3,
                ipc.len() > REALIGN_WHOLE_MAX,
                "one payload of each kind"
            );
            let expected = chunk.to_record_batch().unwrap();
            for shift in 0..REALIGN_TO {
                let mut bytes = vec![0u8; shift];
                bytes.extend_from_slice(&ipc);
                let buffer = Buffer::from_vec(bytes).slice(shift);
                let decoded =
                    decode_chunk(PayloadBytes::Shared(buffer), Compression::None, size).unwrap();
                assert_eq!(
                    decoded.to_record_batch().unwrap(),
                    expected,
                    "shift {shift}"
                );
            }
        }
    }
}
