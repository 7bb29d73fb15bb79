//! The `chunkstore` tool from outside, as a user meets it: answers that do not depend on
//! how a source is chunked, duplicated or encoded (`.rrd` or chunk files, lazy or not), one
//! line on stderr per error and exit code 2, never a panic, errors for unknown timelines,
//! reversed ranges and empty selections, `--skip-bad` to load what can be loaded, `print`, `convert`
//! (atomic, checked by reading back), and `--help` with an example on every command.
//!
//! By theme: `answers.rs` (queries), `errors.rs`, `outputs.rs` (`convert` and what every
//! output does), `dataframe.rs` (and `hive`), `sql.rs`, `dataset.rs`; the helpers that run
//! the tool are here.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests fail loudly on unexpected values"
)]

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Output;

mod answers;
#[path = "../common/mod.rs"]
mod common;
mod dataframe;
mod dataset;
mod errors;
mod outputs;
mod sql;

use common::ScratchDir;

const CHUNKS: &str = "testdata/rerun-0.41/a_robot/chunks";

fn recording_chunks() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(CHUNKS)
}

const RRD: &str = "testdata/rerun-0.41/a_robot/a_robot.rrd";

fn recording_rrd() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(RRD)
}

/// Runs the tool with these arguments.
fn run<S: AsRef<OsStr>>(args: &[S]) -> Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_chunkstore"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap()
}

/// Runs the tool, which must succeed; returns stdout and stderr.
fn ok<S: AsRef<OsStr>>(args: &[S]) -> (String, String) {
    let output = run(args);
    let stderr = String::from_utf8(output.stderr).unwrap();
    assert!(output.status.success(), "{stderr}");
    (String::from_utf8(output.stdout).unwrap(), stderr)
}

/// Runs the tool, which must fail with exit code 2 and exactly one line on stderr, without
/// the default panic hook's message (`thread '...' panicked at ...`); returns that line.
fn fails<S: AsRef<OsStr>>(args: &[S]) -> String {
    let output = run(args);
    let stderr = String::from_utf8_lossy(&output.stderr).into_owned();
    assert_eq!(output.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "one line on stderr: {stderr:?}");
    assert!(stderr.starts_with("error: "), "{stderr:?}");
    assert!(!stderr.contains("panicked at"), "{stderr:?}");
    stderr
}

/// A fresh, empty directory under the system's temporary directory, removed when dropped.
fn scratch_dir(name: &str) -> ScratchDir {
    ScratchDir::new(&format!("cli-{name}"))
}

/// The recording's chunk files, sorted.
fn chunk_files() -> Vec<PathBuf> {
    common::robot_chunk_files()
}

/// Runs the tool with `options` before `source` and `command` after it; returns its
/// standard output.
fn cli_on(source: &Path, options: &[&str], command: &[&str]) -> String {
    let mut args: Vec<&OsStr> = options.iter().map(OsStr::new).collect();
    args.push(source.as_os_str());
    args.extend(command.iter().map(OsStr::new));
    ok(&args).0
}

/// [`cli_on`] the recording's chunk files.
fn cli(options: &[&str], command: &[&str]) -> String {
    cli_on(&recording_chunks(), options, command)
}

fn concat(batches: &[arrow_array::RecordBatch]) -> arrow_array::RecordBatch {
    arrow_select::concat::concat_batches(&batches[0].schema(), batches).unwrap()
}

const IDENTITY: &str = "testdata/rerun-0.41/identity";

/// A recording Rerun 0.41's SDK wrote (see `testdata/rerun-0.41/identity/gen_identity.py`).
fn identity_file(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(IDENTITY)
        .join(name)
}

/// The recording store infos of an `.rrd` file written by us: (application id, recording
/// id) of each, and every chunk checked as Rerun checks it before loading.
fn written_identity(path: &Path) -> Vec<(String, String)> {
    let contents = chunkstore::rrd::read_rrd(
        arrow_buffer::Buffer::from_vec(std::fs::read(path).unwrap()),
        false,
    )
    .unwrap();
    contents
        .chunks
        .iter()
        .for_each(|(_, c)| common::assert_rerun_loads(c));
    let recording = chunkstore::rrd::StoreKind::Recording;
    assert!(
        contents.chunks.iter().all(|(store, _)| {
            store.kind == recording && contents.store_infos.iter().any(|i| &i.store_id == store)
        }),
        "every chunk under a store the file describes"
    );
    contents
        .store_infos
        .iter()
        .map(|i| {
            assert_eq!(i.store_id.kind, recording, "{i:?}");
            (
                i.store_id.application_id.to_string(),
                i.store_id.recording_id.to_string(),
            )
        })
        .collect()
}

/// A dataset directory of two segments: the robot recording, and the same chunks under
/// another recording id (written by `convert` from chunk files without a store info).
fn robot_dataset(name: &str) -> ScratchDir {
    let dir = scratch_dir(name);
    std::fs::copy(recording_rrd(), dir.join("one.rrd")).unwrap();
    let chunks = dir.join("chunks-without-info");
    std::fs::create_dir(&chunks).unwrap();
    for file in chunk_files() {
        std::fs::copy(&file, chunks.join(file.file_name().unwrap())).unwrap();
    }
    let two = dir.join("two.rrd");
    ok(&[
        chunks.as_os_str(),
        OsStr::new("convert"),
        two.as_os_str(),
        OsStr::new("--recording-id"),
        OsStr::new("second"),
    ]);
    std::fs::remove_dir_all(&chunks).unwrap();
    dir
}
