//! The body of the `ipc_schema_cache` fuzz target: an Arrow IPC stream (twice: the cache
//! keeps a layout from its second message on) and an edited copy of it, each decoded with
//! and without the cache of parsed schemas. The two decodes must agree exactly (equal
//! batches, schema metadata included, or both an error): the cache may reuse a schema only
//! where it proves the full decode gives the same one. The edits let the fuzzer change a
//! stream's bytes a few at a time after the cache kept its schema, which is where an
//! unsound cache would answer from stale bytes. The chunks decoded straight from the
//! stream (`read_stream_chunks_zero_copy`: from a cached schema, without a `RecordBatch`)
//! must be those made of the uncached batches, or fail alike.
//!
//! Input: a byte `n`, then `n % 8` edits of three bytes (a little-endian `u16` position,
//! taken modulo the stream's length, and the byte to write there), then the stream.

use arrow_array::RecordBatch;
use arrow_buffer::Buffer;
use chunkstore::Chunk;
use chunkstore::ipc::{
    IpcError, clear_schema_cache, read_stream_batches_zero_copy, read_stream_chunks_zero_copy,
    without_schema_cache,
};

/// Where to write which byte.
type Edit = (usize, u8);

/// Splits an input into its edits and its stream; `None` if it is too short for its edits.
pub fn parse(data: &[u8]) -> Option<(Vec<Edit>, &[u8])> {
    let (&count, rest) = data.split_first()?;
    let edits_len = usize::from(count % 8) * 3;
    let edits = rest.get(..edits_len)?;
    let stream = &rest[edits_len..];
    let edits = edits
        .chunks_exact(3)
        .map(|e| (usize::from(u16::from_le_bytes([e[0], e[1]])), e[2]))
        .collect();
    Some((edits, stream))
}

/// An input for this target: `stream` and the edits to make in its copy.
pub fn input(stream: &[u8], edits: &[(u16, u8)]) -> Vec<u8> {
    let count = u8::try_from(edits.len()).expect("at most 7 edits");
    assert!(count < 8, "at most 7 edits");
    let mut out = vec![count];
    for (at, byte) in edits {
        out.extend_from_slice(&at.to_le_bytes());
        out.push(*byte);
    }
    out.extend_from_slice(stream);
    out
}

/// Decodes `stream` with the cache, then without it, and checks that they agree, batches
/// and the chunks made of them: a cached schema's batches share its field list, through
/// which a chunk's layout is kept (`chunk/transport.rs`), where each uncached batch has a
/// list of its own.
fn decode_both_ways(stream: &[u8]) {
    let cached = read_stream_batches_zero_copy(Buffer::from(stream.to_vec()));
    let uncached =
        without_schema_cache(|| read_stream_batches_zero_copy(Buffer::from(stream.to_vec())));
    let direct = read_stream_chunks_zero_copy(&Buffer::from(stream.to_vec()));
    direct_chunks_agree(direct, uncached.as_deref());
    match (cached, uncached) {
        (Ok(cached), Ok(uncached)) => {
            assert_eq!(cached, uncached, "the cache changed a batch");
            for (cached, uncached) in cached.iter().zip(&uncached) {
                chunks_agree(cached, uncached);
            }
        }
        (Err(_), Err(_)) => {}
        (cached, uncached) => panic!(
            "with the cache {}, without it {}",
            cached.map_or_else(|e| e.to_string(), |b| format!("{} batches", b.len())),
            uncached.map_or_else(|e| e.to_string(), |b| format!("{} batches", b.len())),
        ),
    }
}

/// `a` and `b` are the same chunk: id, entity and every column (`what` says otherwise).
fn assert_same_chunk(a: &Chunk, b: &Chunk, what: &str) {
    assert_eq!(a.id(), b.id());
    assert_eq!(a.entity_path(), b.entity_path());
    assert_eq!(a.to_record_batch().ok(), b.to_record_batch().ok(), "{what}");
}

/// The chunks of two equal batches are equal, or fail alike.
fn chunks_agree(a: &RecordBatch, b: &RecordBatch) {
    match (Chunk::from_record_batch(a), Chunk::from_record_batch(b)) {
        (Ok(a), Ok(b)) => assert_same_chunk(&a, &b, "a kept layout changed a chunk"),
        (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string()),
        (a, b) => panic!(
            "one chunk decoded, the other did not: {:?} / {:?}",
            a.err(),
            b.err()
        ),
    }
}

/// The chunks decoded straight from a stream are those made of its uncached batches, or
/// the same error: the stream's, or the first bad chunk's.
fn direct_chunks_agree(
    direct: Result<Vec<Chunk>, IpcError>,
    batches: Result<&[RecordBatch], &IpcError>,
) {
    let from_batches = batches.map(|batches| {
        batches
            .iter()
            .enumerate()
            .map(|(batch, b)| Chunk::from_record_batch(b).map_err(|e| (batch, e)))
            .collect::<Result<Vec<Chunk>, _>>()
    });
    match (direct, from_batches) {
        (Ok(direct), Ok(Ok(made))) => {
            assert_eq!(direct.len(), made.len());
            for (a, b) in direct.iter().zip(&made) {
                assert_same_chunk(a, b, "a chunk decoded straight from the stream differs");
            }
        }
        (Err(IpcError::Chunk { batch, source }), Ok(Err((made_batch, made_error)))) => {
            assert_eq!(batch, made_batch);
            assert_eq!(source.to_string(), made_error.to_string());
        }
        (Err(IpcError::Chunk { .. }) | Ok(_), _) | (_, Ok(Err(_))) => {
            panic!("decoded straight from the stream or not, the chunks differ")
        }
        (Err(_), Err(_)) => {}
        (Err(e), Ok(Ok(_))) => panic!("straight from the stream: {e}; from batches: chunks"),
    }
}

/// The target's body.
pub fn ipc_schema_cache(data: &[u8]) {
    let Some((edits, stream)) = parse(data) else {
        return;
    };
    // Each input starts from an empty cache, so that a crash reproduces alone.
    clear_schema_cache();
    decode_both_ways(stream);
    decode_both_ways(stream);
    if let Some(edited) = edited(stream, &edits) {
        decode_both_ways(&edited);
    }
}

/// A copy of `stream` with `edits` made (positions modulo its length); `None` for an empty
/// stream, which no edit can touch.
pub fn edited(stream: &[u8], edits: &[Edit]) -> Option<Vec<u8>> {
    if stream.is_empty() {
        return None;
    }
    let mut edited = stream.to_vec();
    for &(at, byte) in edits {
        let at = at % edited.len();
        edited[at] = byte;
    }
    Some(edited)
}
