//! The query tool (`examples/query.rs`) from outside, as a user meets it: answers that do
//! not depend on how a directory is chunked or duplicated, one line on stderr per error
//! and exit code 2, never a panic, warnings for queries that can only find static data,
//! and `--skip-bad` to load what can be loaded.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests fail loudly on unexpected values"
)]

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Output;

const CHUNKS: &str = "testdata/rerun-0.41/a_robot/chunks";

fn recording_chunks() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(CHUNKS)
}

/// Runs the tool with these arguments.
fn run<S: AsRef<OsStr>>(args: &[S]) -> Output {
    std::process::Command::new(env!("CARGO"))
        .args(["run", "--quiet", "--example", "query", "--"])
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

/// A fresh, empty directory under the system's temporary directory.
fn scratch_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("chunkstore-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The recording's chunk files, sorted.
fn chunk_files() -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(recording_chunks())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "arrow"))
        .collect();
    files.sort();
    files
}

/// Issue 12, item 1: a directory holding every chunk file twice, under two names, answers
/// exactly as the recording does, under every compaction option. (`range` used to print
/// every row twice with `--max-rows 2`.)
#[test]
fn duplicated_files_answer_like_the_recording_under_every_compaction_option() {
    let dir = scratch_dir("duplicates");
    for file in chunk_files() {
        let name = file.file_name().unwrap().to_string_lossy().into_owned();
        std::fs::copy(&file, dir.join(&name)).unwrap();
        std::fs::copy(&file, dir.join(format!("copy-of-{name}"))).unwrap();
    }
    let variants: [&[&str]; 5] = [
        &[],
        &["--max-rows", "2", "--max-rows-unsorted", "1"],
        &["--max-rows", "2", "--max-bytes", "4096", "--compact"],
        &["--compact"],
        &["--max-rows-unsorted", "3"],
    ];
    for command in [
        &["latest-at", "frame_id", "30"][..],
        &["range", "frame_id", "0", "59"],
        &["range", "log_time", "0", "9223372036854775807"],
    ] {
        let with = |dir: &Path, options: &[&str]| {
            let mut args: Vec<&OsStr> = options.iter().map(OsStr::new).collect();
            args.push(dir.as_os_str());
            args.extend(command.iter().map(OsStr::new));
            ok(&args).0
        };
        let expected = with(&recording_chunks(), &[]);
        assert!(expected.lines().count() > 10, "{command:?} answers");
        for options in variants {
            assert_eq!(with(&dir, options), expected, "{options:?} {command:?}");
        }
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// Issue 12, item 9: an argument that is not UTF-8 used to panic (exit code 101). `<DIR>`
/// may be any path; every other argument must be text.
#[test]
fn arguments_that_are_not_utf8_are_an_error_not_a_panic() {
    use std::os::unix::ffi::OsStrExt;
    let bad = OsStr::from_bytes(b"fr\xffme");
    let chunks = recording_chunks();
    for args in [
        vec![
            chunks.as_os_str(),
            OsStr::new("latest-at"),
            bad,
            OsStr::new("1"),
        ],
        vec![
            OsStr::new("--max-rows"),
            bad,
            chunks.as_os_str(),
            OsStr::new("stats"),
        ],
        vec![chunks.as_os_str(), bad],
    ] {
        let line = fails(&args);
        assert!(line.contains("is not valid UTF-8"), "{line}");
    }
    // A directory that does not exist, named by bytes that are not UTF-8: a plain error.
    let line = fails(&[bad, OsStr::new("stats")]);
    assert!(line.contains("No such file"), "{line}");
}

/// Issue 12, item 9: arrow-ipc panics on some malformed files; the library contains the
/// panic and reports an error, but the default panic hook still printed `thread 'main'
/// panicked at ...` before the error line.
#[test]
fn a_file_that_makes_arrow_panic_gives_one_line_on_stderr() {
    let dir = scratch_dir("arrow-panic");
    let crash = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz_crashes/ipc_insert/ipc_buffer_offset_past_body");
    std::fs::copy(crash, dir.join("bad.arrow")).unwrap();
    let line = fails(&[dir.as_os_str(), OsStr::new("stats")]);
    assert!(
        line.contains("bad.arrow") && line.contains("decoder panicked"),
        "{line}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

/// Issue 12, item 11: one bad file among good ones aborted the whole load. It still does
/// by default (naming the file and the option); with `--skip-bad`, each bad file gets one
/// warning line and the rest loads.
#[test]
fn skip_bad_reports_each_bad_file_and_loads_the_rest() {
    let dir = scratch_dir("skip-bad");
    for file in chunk_files() {
        std::fs::copy(&file, dir.join(file.file_name().unwrap())).unwrap();
    }
    std::fs::write(dir.join("0000-garbage.arrow"), b"not arrow at all").unwrap();
    let crash = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz_crashes/ipc_insert/ipc_buffer_offset_past_body");
    std::fs::copy(crash, dir.join("9999-arrow-panics.arrow")).unwrap();

    let line = fails(&[dir.as_os_str(), OsStr::new("stats")]);
    assert!(
        line.contains("0000-garbage.arrow") && line.contains("--skip-bad"),
        "{line}"
    );

    let command = ["latest-at", "frame_id", "30"];
    let mut args = vec![OsStr::new("--skip-bad"), dir.as_os_str()];
    args.extend(command.iter().map(OsStr::new));
    let (answers, warnings) = ok(&args);
    let warnings: Vec<&str> = warnings.lines().collect();
    assert_eq!(warnings.len(), 2, "{warnings:?}");
    assert!(warnings[0].starts_with("warning: skipped") && warnings[0].contains("0000-garbage"));
    assert!(warnings[1].contains("9999-arrow-panics") && !warnings[1].contains("panicked at"));
    let mut expected_args = vec![recording_chunks().into_os_string()];
    expected_args.extend(command.iter().map(Into::into));
    assert_eq!(answers, ok(&expected_args).0);

    // Nothing readable at all is an error even so.
    let empty = scratch_dir("skip-bad-only-bad");
    std::fs::write(empty.join("garbage.arrow"), b"nope").unwrap();
    let line = fails(&[
        OsStr::new("--skip-bad"),
        empty.as_os_str(),
        OsStr::new("stats"),
    ]);
    assert!(line.contains("could be read"), "{line}");
    std::fs::remove_dir_all(dir).unwrap();
    std::fs::remove_dir_all(empty).unwrap();
}

/// Issue 12, item 10: a timeline the data never uses, and a range whose start is after its
/// end, answer with static data only (SEMANTICS.md section 3) and exit 0, as before, but
/// now with one warning line naming the known timelines or the empty range.
#[test]
fn queries_that_can_only_find_static_data_warn_once() {
    let chunks = recording_chunks();
    let chunks = chunks.to_str().unwrap();
    let (typo, warning) = ok(&[chunks, "latest-at", "frame_idd", "30"]);
    let static_only: Vec<&str> = typo.lines().collect();
    assert!(!static_only.is_empty());
    assert!(
        static_only.iter().all(|l| l.contains("\"time\":null")),
        "{typo}"
    );
    assert_eq!(warning.lines().count(), 1, "{warning}");
    assert!(
        warning.starts_with("warning: ")
            && warning.contains("\"frame_idd\"")
            && warning.contains("\"frame_id\", \"log_time\", \"sim_time\""),
        "{warning}"
    );

    let (reversed, warning) = ok(&[chunks, "range", "frame_id", "40", "30"]);
    assert_eq!(reversed.lines().count(), static_only.len(), "{reversed}");
    assert_eq!(warning.lines().count(), 1, "{warning}");
    assert!(warning.contains("[40, 30] is empty"), "{warning}");

    let (_, quiet) = ok(&[chunks, "range", "frame_id", "30", "40"]);
    assert!(
        quiet.is_empty(),
        "a sensible query warns of nothing: {quiet}"
    );
}

/// Issue 12, item 10: `stats` lists what there is to query: each timeline with its type and
/// the times its data spans, and the entities.
#[test]
fn stats_lists_the_timelines_and_entities() {
    let (out, _) = ok(&[recording_chunks().to_str().unwrap(), "stats"]);
    let stats: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(
        stats["timelines"][0],
        serde_json::json!({"name": "frame_id", "type": "sequence", "min": 0, "max": 59})
    );
    assert_eq!(stats["timelines"][1]["type"], "timestamp_ns");
    assert_eq!(
        stats["timelines"][2],
        serde_json::json!({"name": "sim_time", "type": "duration_ns", "min": 0, "max": 5_900_000_000_i64})
    );
    let entities = stats["entities"].as_array().unwrap();
    assert_eq!(
        entities.len(),
        usize::try_from(stats["num_entities"].as_u64().unwrap()).unwrap()
    );
    assert!(entities.contains(&serde_json::json!("/world/robot/camera/rgb")));
}
