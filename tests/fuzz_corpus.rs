//! Replays the fuzz corpus (`fuzz/corpus/ipc_insert/`) and every crash ever found
//! (`tests/fuzz_crashes/`) through the fuzz target's own body, as an ordinary test.

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "the harness asserts with expect, like the fuzz target; a replay fails loudly"
)]

#[path = "../fuzz/harness/ipc_insert.rs"]
mod harness;

use std::path::{Path, PathBuf};

use chunkstore::IoError;

/// The files of a directory of the repository (but its `README.md`), sorted. A directory
/// that cannot be read fails the test: a replay of nothing proves nothing.
fn files_in(dir: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join(dir);
    let entries = std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    let mut files: Vec<PathBuf> = entries
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.is_file() && path.extension().is_none_or(|e| e != "md"))
        .collect();
    files.sort();
    files
}

#[test]
fn fuzz_corpus_replays_without_panics() {
    let files = files_in("fuzz/corpus/ipc_insert");
    assert!(
        files.len() >= 10,
        "the corpus holds seeds ({} found)",
        files.len()
    );
    for file in files {
        harness::ipc_insert(&std::fs::read(file).unwrap());
    }
}

/// What decoding each crash must give now, with the root cause in
/// `tests/fuzz_crashes/README.md`. A crash file without an entry here fails the test.
const CRASH_OUTCOMES: &[(&str, fn(&Result<Vec<chunkstore::Chunk>, IoError>) -> bool)] = &[
    // arrow-ipc panics on this input (a buffer offset past the message body); the library
    // must turn that into an error.
    ("ipc_buffer_offset_past_body", |r| {
        matches!(r, Err(IoError::DecoderPanicked { .. }))
    }),
    // arrow-ipc would allocate the body size this file's footer claims (far beyond the
    // file); the framing check must reject it first.
    ("ipc_file_block_claims_huge_body", |r| {
        matches!(r, Err(IoError::MalformedFraming { .. }))
    }),
];

/// Issue 12, item 12: this test used to pass when its directory was missing (the replay
/// returned 0 on a read error) and asserted nothing of each file's outcome.
#[test]
fn fuzz_crashes_stay_fixed() {
    let files = files_in("tests/fuzz_crashes");
    assert_eq!(
        files.len(),
        CRASH_OUTCOMES.len(),
        "one expected outcome per crash file: {files:?}"
    );
    for file in files {
        let name = file.file_name().unwrap().to_str().unwrap();
        let Some((_, expected)) = CRASH_OUTCOMES.iter().find(|(n, _)| *n == name) else {
            panic!("{name}: no expected outcome in CRASH_OUTCOMES");
        };
        let bytes = std::fs::read(&file).unwrap();
        let outcome = chunkstore::io::read_chunks_from_bytes(&bytes);
        assert!(expected(&outcome), "{name}: {outcome:?}");
        // And the whole fuzz target's body stays quiet on it.
        harness::ipc_insert(&bytes);
    }
}
