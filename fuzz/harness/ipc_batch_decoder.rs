//! The body of the `ipc_batch_decoder` fuzz target: an Arrow IPC stream and an edited copy
//! of it, each decoded with the library's own batch decoder and with arrow-ipc's alone
//! (`without_own_batch_decoder`). The two must agree exactly: equal batches, or the same
//! kind of error; except where arrow-ipc panics (contained, a bug of its own, e.g. an
//! alignment assertion on a hostile buffer), where the own decoder may answer. The own decoder hands whatever it does not build to arrow-ipc, so a difference
//! means it built a batch arrow-ipc refuses, or built one differently.
//!
//! Input: as `ipc_schema_cache`'s (a byte `n`, then `n % 8` edits of three bytes, then the
//! stream), so that its corpus seeds this one.

use arrow_buffer::Buffer;
use chunkstore::ipc::{IpcError, read_stream_batches_zero_copy, without_own_batch_decoder};

/// Decodes `stream` both ways and checks that they agree.
fn decode_both_ways(stream: &[u8]) {
    let own = read_stream_batches_zero_copy(Buffer::from(stream.to_vec()));
    let reference =
        without_own_batch_decoder(|| read_stream_batches_zero_copy(Buffer::from(stream.to_vec())));
    match (own, reference) {
        (Ok(own), Ok(reference)) => {
            assert_eq!(own, reference, "the own decoder built another batch");
        }
        // arrow-ipc panicked (a bug of its own, contained): the own decoder may have built
        // that batch (with arrow's checked constructors) and gone on; it did not panic.
        (_, Err(IpcError::DecoderPanicked { .. })) => {}
        // The same kind of error (its text can differ: it may print a metadata map, whose
        // order is a hash map's).
        (Err(own), Err(reference)) => assert_eq!(
            std::mem::discriminant(&own),
            std::mem::discriminant(&reference),
            "{own} / {reference}"
        ),
        (own, reference) => panic!(
            "with the own decoder {}, with arrow-ipc alone {}",
            own.map_or_else(|e| e.to_string(), |b| format!("{} batches", b.len())),
            reference.map_or_else(|e| e.to_string(), |b| format!("{} batches", b.len())),
        ),
    }
}

/// The target's body.
pub fn ipc_batch_decoder(data: &[u8]) {
    use super::ipc_schema_cache::{edited, parse};
    let Some((edits, stream)) = parse(data) else {
        return;
    };
    decode_both_ways(stream);
    if let Some(edited) = edited(stream, &edits) {
        decode_both_ways(&edited);
    }
}
