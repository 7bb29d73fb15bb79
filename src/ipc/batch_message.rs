//! A record batch message's header (its row count, nodes and buffers), read from the
//! message's flatbuffer with the checks flatbuffers' verifier makes, and no more.
//!
//! Verifying each batch message with flatbuffers' generic verifier was a twentieth of
//! decoding a one-row chunk. This reader walks the two tables such a message has (the
//! `Message` and its `RecordBatch`) with exactly the verifier's checks on what it reads:
//! every offset, vtable, field and vector in bounds, aligned relative to the message's
//! start as the verifier requires. It reads only messages whose other fields the verifier
//! would not descend into: no `custom_metadata`, `compression` or
//! `variadicBufferCounts`. So a message it reads is one the verifier accepts, with the
//! same values; anything else (`None`) goes through the verifier and arrow-ipc, whose
//! answer or error stands. The `ipc_batch_decoder` fuzz target compares the two paths.

use smallvec::SmallVec;

/// The `MessageHeader` union's tag of a record batch.
const HEADER_RECORD_BATCH: u8 = 3;

/// A longer message is left to the verifier, which bounds the sum of the sizes it checks
/// (2 GiB); this reader's dozen checked ranges of at most this size stay far below.
const MAX_MESSAGE_BYTES: usize = 1 << 20;

/// What a record batch message says: the body's length, the batch's row count, its nodes
/// (length, null count) and buffers (offset, length) in the IPC format's order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct BatchHeader {
    pub(super) body_length: i64,
    pub(super) length: i64,
    pub(super) nodes: SmallVec<[(i64, i64); 16]>,
    pub(super) buffers: SmallVec<[(i64, i64); 32]>,
}

impl BatchHeader {
    /// The header of a verified arrow-ipc record batch; `None` where the own batch decoder
    /// builds nothing (a compressed body, variadic buffers, no nodes or buffers).
    pub(super) fn of_verified(body_length: i64, batch: arrow_ipc::RecordBatch<'_>) -> Option<Self> {
        if batch.compression().is_some()
            || batch.variadicBufferCounts().is_some_and(|v| !v.is_empty())
        {
            return None;
        }
        Some(Self {
            body_length,
            length: batch.length(),
            nodes: batch
                .nodes()?
                .iter()
                .map(|node| (node.length(), node.null_count()))
                .collect(),
            buffers: batch
                .buffers()?
                .iter()
                .map(|buffer| (buffer.offset(), buffer.length()))
                .collect(),
        })
    }

    /// Reads `message` (one IPC message's metadata bytes, unverified) if it is a record
    /// batch message this reader knows to be one the verifier accepts.
    pub(super) fn read(message: &[u8]) -> Option<Self> {
        if message.len() > MAX_MESSAGE_BYTES {
            return None;
        }
        let bytes = Bytes(message);
        let root = bytes.uoffset_target(0)?;
        let msg = bytes.table(root)?;
        // version: a 16-bit enum, any value.
        match msg.field(&bytes, 4) {
            Field::Absent => {}
            Field::At(at) => {
                bytes.get::<2>(at)?;
            }
            Field::Unreadable => return None,
        }
        // The header union: its tag and its table, both present, a record batch.
        let tag_at = msg.required(&bytes, 6)?;
        let header_at = msg.required(&bytes, 8)?;
        if bytes.get::<1>(tag_at)?[0] != HEADER_RECORD_BATCH {
            return None;
        }
        let body_length = msg.i64_field(&bytes, 10)?;
        // custom_metadata: left to the verifier.
        if !msg.absent(&bytes, 12) {
            return None;
        }
        let batch = bytes.table(bytes.uoffset_target(header_at)?)?;
        let length = batch.i64_field(&bytes, 4)?;
        let nodes = bytes.pairs(batch.required(&bytes, 6)?)?;
        let buffers = bytes.pairs(batch.required(&bytes, 8)?)?;
        // compression, variadicBufferCounts: left to the verifier.
        if !batch.absent(&bytes, 10) || !batch.absent(&bytes, 12) {
            return None;
        }
        Some(Self {
            body_length,
            length,
            nodes: nodes.collect(),
            buffers: buffers.collect(),
        })
    }
}

/// A message's bytes, read as flatbuffers' verifier reads them: a value of `N` bytes must
/// lie inside and start at a multiple of `N` (from the message's start).
#[derive(Clone, Copy)]
struct Bytes<'a>(&'a [u8]);

/// Where a table's field lies, as its vtable says.
enum Field {
    Absent,
    At(usize),
    Unreadable,
}

/// A table: where it is and where its vtable is, with the vtable's length.
struct Table {
    at: usize,
    vtable: usize,
    vtable_len: usize,
}

impl<'a> Bytes<'a> {
    fn get<const N: usize>(self, at: usize) -> Option<[u8; N]> {
        if !at.is_multiple_of(N) {
            return None;
        }
        self.0.get(at..at.checked_add(N)?)?.try_into().ok()
    }

    fn u16(self, at: usize) -> Option<usize> {
        Some(usize::from(u16::from_le_bytes(self.get::<2>(at)?)))
    }

    fn u32(self, at: usize) -> Option<usize> {
        usize::try_from(u32::from_le_bytes(self.get::<4>(at)?)).ok()
    }

    /// Where the unsigned offset at `at` points (the verifier adds with saturation; an
    /// overflow here is out of bounds either way).
    fn uoffset_target(self, at: usize) -> Option<usize> {
        at.checked_add(self.u32(at)?)
    }

    /// The table at `at`, its vtable checked as `Verifier::visit_table` checks it.
    fn table(self, at: usize) -> Option<Table> {
        let soffset = i32::from_le_bytes(self.get::<4>(at)?);
        let vtable = if soffset > 0 {
            at.checked_sub(usize::try_from(soffset.unsigned_abs()).ok()?)?
        } else {
            at.checked_add(usize::try_from(soffset.unsigned_abs()).ok()?)?
        };
        if vtable >= self.0.len() {
            return None;
        }
        let vtable_len = self.u16(vtable)?;
        let end = vtable.checked_add(vtable_len)?;
        if !end.is_multiple_of(2) || end > self.0.len() {
            return None;
        }
        Some(Table {
            at,
            vtable,
            vtable_len,
        })
    }

    /// A vector of 16-byte structs of two little-endian `i64`s at the offset at `at`
    /// (the verifier checks the vector's length and that its elements lie inside; the
    /// structs' alignment is 1).
    fn pairs(self, at: usize) -> Option<impl Iterator<Item = (i64, i64)> + 'a> {
        let vector = self.uoffset_target(at)?;
        let len = self.u32(vector)?;
        let start = vector.checked_add(4)?;
        let elements = self
            .0
            .get(start..start.checked_add(len.checked_mul(16)?)?)?;
        Some(elements.chunks_exact(16).map(|pair| {
            let (a, b) = pair.split_at(8);
            let word = |half: &[u8]| {
                let mut le = [0u8; 8];
                le.copy_from_slice(half);
                i64::from_le_bytes(le)
            };
            (word(a), word(b))
        }))
    }
}

impl Table {
    /// Where field `voffset` lies: absent, present at a position, or unreadable (its vtable
    /// entry out of bounds or misaligned).
    fn field(&self, bytes: &Bytes<'_>, voffset: usize) -> Field {
        if voffset >= self.vtable_len {
            return Field::Absent;
        }
        let Some(offset) = self
            .vtable
            .checked_add(voffset)
            .and_then(|entry| bytes.u16(entry))
        else {
            return Field::Unreadable;
        };
        match offset {
            0 => Field::Absent,
            offset => self
                .at
                .checked_add(offset)
                .map_or(Field::Unreadable, Field::At),
        }
    }

    /// Where a field this reader needs lies; `None` if absent or unreadable.
    fn required(&self, bytes: &Bytes<'_>, voffset: usize) -> Option<usize> {
        match self.field(bytes, voffset) {
            Field::At(at) => Some(at),
            Field::Absent | Field::Unreadable => None,
        }
    }

    /// Is a field this reader leaves to the verifier absent (and its vtable entry read)?
    fn absent(&self, bytes: &Bytes<'_>, voffset: usize) -> bool {
        matches!(self.field(bytes, voffset), Field::Absent)
    }

    /// An `i64` field (0 if absent, flatbuffers' default for these fields).
    fn i64_field(&self, bytes: &Bytes<'_>, voffset: usize) -> Option<i64> {
        match self.field(bytes, voffset) {
            Field::Absent => Some(0),
            Field::At(at) => Some(i64::from_le_bytes(bytes.get::<8>(at)?)),
            Field::Unreadable => None,
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(
        clippy::unwrap_used,
        clippy::expect_used,
        reason = "tests fail loudly on unexpected values"
    )]

    use std::sync::Arc;

    use arrow_array::{ArrayRef, Float64Array, Int64Array, RecordBatch};

    use super::BatchHeader;

    /// The metadata bytes of the second message (the batch) of a one-batch stream.
    fn batch_message() -> Vec<u8> {
        let batch = RecordBatch::try_from_iter([
            (
                "frame",
                Arc::new(Int64Array::from(vec![1, 2, 3])) as ArrayRef,
            ),
            (
                "x",
                Arc::new(Float64Array::from(vec![Some(0.5), None, Some(1.5)])),
            ),
        ])
        .unwrap();
        let stream = crate::ipc::tests::stream_of(&batch);
        let len = |at: usize| {
            usize::try_from(i32::from_le_bytes(stream[at..at + 4].try_into().unwrap())).unwrap()
        };
        // Continuation marker, length, metadata (the schema has no body).
        let second = 8 + len(4);
        stream[second + 8..second + 8 + len(second + 4)].to_vec()
    }

    /// What the verifier and arrow-ipc's accessors read, where the verifier accepts.
    fn verified(message: &[u8]) -> Option<BatchHeader> {
        let message = arrow_ipc::root_as_message(message).ok()?;
        BatchHeader::of_verified(message.bodyLength(), message.header_as_record_batch()?)
    }

    #[test]
    fn reads_what_arrow_writes_as_the_verifier_does() {
        let message = batch_message();
        let read = BatchHeader::read(&message).expect("arrow's own messages are read");
        assert_eq!(Some(read.clone()), verified(&message));
        assert_eq!(read.length, 3);
        assert_eq!(read.nodes.as_slice(), [(3, 0), (3, 1)]);
        assert_eq!(read.buffers.len(), 4);
    }

    /// Every one-byte change of a message, and every truncation: what this reader reads,
    /// the verifier accepts, and arrow-ipc reads the same header from it.
    #[test]
    fn reads_nothing_the_verifier_refuses() {
        let message = batch_message();
        let mut read = 0;
        for at in 0..message.len() {
            for byte in [0, 1, 2, 3, 4, 8, 0x7f, 0x80, 0xfe, 0xff, message[at] ^ 0x10] {
                let mut changed = message.clone();
                changed[at] = byte;
                if let Some(header) = BatchHeader::read(&changed) {
                    read += 1;
                    assert_eq!(
                        Some(header),
                        verified(&changed),
                        "byte {at} set to {byte:#x}"
                    );
                }
            }
        }
        for len in 0..message.len() {
            if let Some(header) = BatchHeader::read(&message[..len]) {
                assert_eq!(Some(header), verified(&message[..len]), "cut at {len}");
            }
        }
        // Most changes touch values (lengths, offsets), which the reader reads as they are.
        assert!(read > message.len(), "{read} changed messages read");
    }
}
