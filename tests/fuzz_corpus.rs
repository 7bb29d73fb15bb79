//! Replays the fuzz corpus (`fuzz/corpus/ipc_insert/`) and every crash ever found
//! (`tests/fuzz_crashes/`) through the fuzz target's own body, as an ordinary test.

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "the harness asserts with expect, like the fuzz target; a replay fails loudly"
)]

#[path = "../fuzz/harness/ipc_insert.rs"]
mod harness;

use std::path::Path;

fn replay(dir: &str) -> usize {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join(dir);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return 0;
    };
    let mut count = 0;
    for entry in entries {
        let path = entry.unwrap().path();
        if path.is_file() && path.extension().is_none_or(|e| e != "md") {
            let bytes = std::fs::read(&path).unwrap();
            harness::ipc_insert(&bytes);
            count += 1;
        }
    }
    count
}

#[test]
fn fuzz_corpus_replays_without_panics() {
    let count = replay("fuzz/corpus/ipc_insert");
    assert!(count >= 10, "the corpus holds seeds ({count} found)");
}

#[test]
fn fuzz_crashes_stay_fixed() {
    replay("tests/fuzz_crashes");
}

/// Decodes one file of `tests/fuzz_crashes/` with the library's IPC reader.
fn decode_crash(name: &str) -> Result<Vec<chunkstore::Chunk>, chunkstore::IoError> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz_crashes")
        .join(name);
    chunkstore::io::read_chunks_from_bytes(&std::fs::read(path).unwrap())
}

/// arrow-ipc panics on this input (a buffer offset past the message body); the library
/// must turn that into an error.
#[test]
fn regression_ipc_decoder_panic_is_an_error() {
    let result = decode_crash("ipc_buffer_offset_past_body");
    assert!(
        matches!(result, Err(chunkstore::IoError::DecoderPanicked { .. })),
        "{result:?}"
    );
}

/// arrow-ipc would allocate the body size this file's footer claims (far beyond the
/// file); the framing check must reject it first.
#[test]
fn regression_ipc_claimed_body_beyond_input_is_rejected_before_allocating() {
    let result = decode_crash("ipc_file_block_claims_huge_body");
    assert!(
        matches!(result, Err(chunkstore::IoError::MalformedFraming { .. })),
        "{result:?}"
    );
}
