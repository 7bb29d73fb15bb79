//! Replays every fuzz target's corpus (`fuzz/corpus/<target>/`) and every crash ever found
//! (`tests/fuzz_crashes/`) through the fuzz targets' own bodies, as ordinary tests.

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "the harness asserts with expect, like the fuzz target; a replay fails loudly"
)]

use crate::harness;

use std::path::{Path, PathBuf};

use chunkstore::ipc::IpcError;

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

/// Replays one target's corpus through its body; the corpus must hold seeds.
fn replay_corpus(target: &str, body: fn(&[u8])) {
    let files = files_in(&format!("fuzz/corpus/{target}"));
    assert!(
        files.len() >= 10,
        "{target}'s corpus holds seeds ({} found)",
        files.len()
    );
    for file in files {
        body(&std::fs::read(file).unwrap());
    }
}

#[test]
fn ipc_insert_corpus_replays_without_panics() {
    replay_corpus("ipc_insert", harness::ipc_insert::ipc_insert);
}

#[test]
fn chunk_build_corpus_replays_without_panics() {
    replay_corpus("chunk_build", harness::chunk_build::chunk_build);
}

#[test]
fn entity_path_corpus_replays_without_panics() {
    replay_corpus("entity_path", harness::entity_path::entity_path);
}

#[test]
fn rrd_decode_corpus_replays_without_panics() {
    replay_corpus("rrd_decode", harness::rrd_decode::rrd_decode);
}

#[test]
fn log_msg_corpus_replays_without_panics() {
    replay_corpus("log_msg", harness::log_msg::log_msg);
}

#[test]
fn ipc_schema_cache_corpus_replays_without_panics() {
    replay_corpus(
        "ipc_schema_cache",
        harness::ipc_schema_cache::ipc_schema_cache,
    );
}

/// The own batch decoder's target starts from `ipc_schema_cache`'s seeds (the same input
/// form) and keeps what its own runs add.
#[test]
fn ipc_batch_decoder_corpus_replays_without_panics() {
    replay_corpus(
        "ipc_batch_decoder",
        harness::ipc_batch_decoder::ipc_batch_decoder,
    );
}

/// Writes the seeds of `ipc_schema_cache`: every chunk of the robot recording Rerun 0.41
/// wrote, as the IPC stream of its payload, each with edits that turn its chunk id into
/// another (the case the cache answers), into another length's worth of garbage, or that
/// touch bytes outside the metadata values (which must miss).
#[test]
#[ignore = "writes fuzz/corpus/ipc_schema_cache: run once with --ignored"]
fn write_ipc_schema_cache_seeds() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus/ipc_schema_cache");
    std::fs::create_dir_all(&dir).unwrap();
    for (i, chunk) in crate::common::robot_chunks().iter().enumerate() {
        let batch = chunk.to_record_batch().unwrap();
        let mut stream = Vec::new();
        let mut writer =
            arrow_ipc::writer::StreamWriter::try_new(&mut stream, &batch.schema()).unwrap();
        writer.write(&batch).unwrap();
        writer.finish().unwrap();
        drop(writer);
        let id = chunk.id().to_string();
        let at = stream
            .windows(id.len())
            .position(|w| w == id.as_bytes())
            .map(|at| u16::try_from(at).unwrap());
        let edits: Vec<(u16, u8)> = match (i % 4, at) {
            (0, Some(at)) => vec![(at, b'f'), (at + 5, b'0'), (at + 31, b'a')],
            (1, Some(at)) => vec![(at + 2, 0xff)],
            (2, _) => vec![(u16::try_from(i * 7).unwrap(), 0x41)],
            _ => vec![],
        };
        let input = harness::ipc_schema_cache::input(&stream, &edits);
        std::fs::write(dir.join(format!("robot_chunk_{i:03}")), input).unwrap();
    }
}

#[cfg(feature = "cli")]
#[test]
fn cli_args_corpus_replays_without_panics() {
    replay_corpus("cli_args", harness::cli_args::cli_args);
}

/// The seeds are a real table's log (written by `hive --delta`) and edits of it that the
/// append must refuse (a checkpoint, a newer protocol, another partitioning, a segment it
/// adds, a column of another type, a gap in versions, no `metaData`, broken JSON) or take
/// (a second commit with a remove, a column of the write's type, files that are not
/// commits).
#[cfg(feature = "parquet")]
#[test]
fn delta_log_corpus_replays_without_panics() {
    replay_corpus("delta_log", harness::delta_log::delta_log);
}

/// What each crash must give now (the root causes are in `tests/fuzz_crashes/README.md`).
enum Expected {
    /// Decoding the bytes as Arrow IPC gives an error this accepts.
    Decoding(fn(&Result<Vec<chunkstore::Chunk>, IpcError>) -> bool),
    /// The target's harness runs to its end: every one of its checks holds.
    HarnessPasses,
}

/// Every crash file, by target and name. A crash file without an entry fails the test.
const CRASHES: &[(&str, &str, Expected)] = &[
    // arrow-ipc panics on this input (a buffer offset past the message body); the library
    // must turn that into an error.
    (
        "ipc_insert",
        "ipc_buffer_offset_past_body",
        Expected::Decoding(|r| matches!(r, Err(IpcError::DecoderPanicked { .. }))),
    ),
    // arrow-ipc would allocate the body size this file's footer claims (far beyond the
    // file); the framing check must reject it first.
    (
        "ipc_insert",
        "ipc_file_block_claims_huge_body",
        Expected::Decoding(|r| matches!(r, Err(IpcError::MalformedFraming { .. }))),
    ),
    // A list of empty structs spanning 202 million values in 856 bytes: a merge's
    // interleave took 3.2 GB of indices. Refused when the chunk is built.
    (
        "ipc_insert",
        "list_of_empty_structs_spans_millions",
        Expected::Decoding(|r| {
            matches!(
                r,
                Err(IpcError::Chunk {
                    source: chunkstore::ChunkError::UnbackedValues { .. },
                    ..
                })
            )
        }),
    ),
    // A split on insert built a slice that the unbacked-values guard refused, though the
    // chunk it came from was accepted (see the README).
    (
        "ipc_insert",
        "slice_of_unbacked_like_values_refused",
        Expected::HarnessPasses,
    ),
    // A refused first chunk of an unknown recording left the recording open, empty (see
    // the README).
    (
        "log_msg",
        "refused_first_chunk_opened_its_recording",
        Expected::HarnessPasses,
    ),
    // compact() changed which components an entity listed (see the README).
    (
        "chunk_build",
        "component_type_outlived_its_chunks",
        Expected::HarnessPasses,
    ),
    // The schema cache answered a message whose metadata value, in an entry without a
    // key, was not UTF-8; the verifier refuses such a message (see the README).
    (
        "ipc_schema_cache",
        "value_without_key_not_utf8",
        Expected::HarnessPasses,
    ),
    (
        "ipc_batch_decoder",
        "errors_print_a_hash_map",
        Expected::HarnessPasses,
    ),
    (
        "ipc_batch_decoder",
        "arrow_ipc_panics_where_ours_builds",
        Expected::HarnessPasses,
    ),
    (
        "ipc_batch_decoder",
        "struct_child_longer_than_its_struct",
        Expected::HarnessPasses,
    ),
    (
        "rrd_decode",
        "run_error_text_differs",
        Expected::HarnessPasses,
    ),
];

/// Issue 12, item 12: this test used to pass when its directory was missing (the replay
/// returned 0 on a read error) and asserted nothing of each file's outcome.
#[test]
fn fuzz_crashes_stay_fixed() {
    let mut num_files = 0;
    for (target, body) in [
        ("ipc_insert", harness::ipc_insert::ipc_insert as fn(&[u8])),
        ("chunk_build", harness::chunk_build::chunk_build),
        ("log_msg", harness::log_msg::log_msg),
        (
            "ipc_schema_cache",
            harness::ipc_schema_cache::ipc_schema_cache,
        ),
        (
            "ipc_batch_decoder",
            harness::ipc_batch_decoder::ipc_batch_decoder,
        ),
        ("rrd_decode", harness::rrd_decode::rrd_decode),
    ] {
        for file in files_in(&format!("tests/fuzz_crashes/{target}")) {
            num_files += 1;
            let name = file.file_name().unwrap().to_str().unwrap();
            let Some((_, _, expected)) =
                CRASHES.iter().find(|(t, n, _)| *t == target && *n == name)
            else {
                panic!("{target}/{name}: no expected outcome in CRASHES");
            };
            let bytes = std::fs::read(&file).unwrap();
            if let Expected::Decoding(accepts) = expected {
                let outcome = chunkstore::ipc::read_chunks_from_bytes(&bytes);
                assert!(accepts(&outcome), "{target}/{name}: {outcome:?}");
            }
            // The whole harness stays quiet on it (it panics on any broken check).
            body(&bytes);
        }
    }
    assert_eq!(num_files, CRASHES.len(), "every listed crash has its file");
}

#[test]
fn damaged_log_corpus_replays_without_panics() {
    replay_corpus("damaged_log", harness::damaged_log::damaged_log);
}

/// The `damaged_log` target's checks at every byte of two scripted logs (one appended to
/// a closed file), for each kind of damage: a cut or zeroed tail keeps every whole
/// message before it; a changed byte is refused or loses only its own message.
#[test]
fn a_damaged_log_loses_at_most_the_damaged_message_at_every_offset() {
    for (flags, choices) in [
        (5u8, &[0u8, 1, 2, 7, 0, 13][..]),
        (8 | 3, &[4, 15, 6, 9][..]),
    ] {
        let scripted = harness::damaged_log::ScriptedLog::new(flags, choices);
        for at in 0..scripted.log.len() {
            for (op, value) in [(0, 0), (1, 0), (2, 0x80), (2, 0x01), (3, 0), (3, 0xff)] {
                scripted.check_damage(at, op, value);
            }
        }
    }
}
