//! The `chunkstore` tool from outside, as a user meets it: answers that do not depend on
//! how a source is chunked, duplicated or encoded (`.rrd` or chunk files, lazy or not), one
//! line on stderr per error and exit code 2, never a panic, errors for unknown timelines,
//! reversed ranges and empty selections, `--skip-bad` to load what can be loaded, `print`, `convert`
//! (atomic, checked by reading back), and `--help` with an example on every command.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests fail loudly on unexpected values"
)]

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Output;

mod common;
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
}

/// Issue 12, item 9: an argument that is not UTF-8 used to panic (exit code 101). `<SOURCE>`
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
        // clap names the argument it could not take (lossily) or says it is not UTF-8.
        assert!(
            line.contains("invalid UTF-8") || line.contains("unexpected argument 'fr\u{fffd}me'"),
            "{line}"
        );
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
}

/// Issue 32, item 13 (which replaces issue 12's warnings): one rule everywhere. A
/// timeline the source does not have, a range whose start is after its end, and a
/// `--contents` filter that selects nothing are errors (exit 2, one line naming what the
/// source has), as `dataframe`, SQL and Python already said, never an answer of static
/// data only that a script takes for success.
#[test]
fn unknown_timelines_reversed_ranges_and_empty_selections_are_errors() {
    let chunks = recording_chunks();
    let chunks = chunks.to_str().unwrap();
    let rrd = recording_rrd();
    let rrd = rrd.to_str().unwrap();
    for source in [chunks, rrd] {
        for command in [
            &["latest-at", "FRAME_ID", "30"][..],
            &["range", "FRAME_ID", "30", "40"],
            &["dataframe", "FRAME_ID"],
        ] {
            let mut args = vec![source];
            args.extend(command);
            let line = fails(&args);
            assert!(
                line.contains("unknown timeline \"FRAME_ID\"")
                    && line.contains("frame_id, log_time, sim_time"),
                "{command:?}: {line}"
            );
        }
        for command in [
            &["range", "frame_id", "40", "30"][..],
            &["dataframe", "frame_id", "--range", "40", "30"],
        ] {
            let mut args = vec![source];
            args.extend(command);
            let line = fails(&args);
            assert!(
                line.contains("MIN is greater than MAX"),
                "{command:?}: {line}"
            );
        }
        let line = fails(&[source, "dataframe", "frame_id", "--contents", "/wrold/**"]);
        assert!(
            line.contains("matches no entity") && line.contains("/world/robot"),
            "{line}"
        );
        let (_, quiet) = ok(&[source, "range", "frame_id", "30", "40"]);
        assert!(
            quiet.is_empty(),
            "a sensible query warns of nothing: {quiet}"
        );
    }
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

#[test]
fn cli_answers_are_the_same_whatever_the_compaction_options() {
    let chunk_count = |options: &[&str]| {
        let stats: serde_json::Value = serde_json::from_str(&cli(options, &["stats"])).unwrap();
        stats["num_chunks"].as_u64().unwrap()
    };
    let variants: [&[&str]; 4] = [
        &[
            "--max-rows",
            "2",
            "--max-rows-unsorted",
            "1",
            "--max-bytes",
            "4096",
        ],
        &["--compact"],
        &["--max-rows", "7", "--max-bytes", "100000", "--compact"],
        &["--max-rows-unsorted", "3"],
    ];
    let plain_chunks = chunk_count(&[]);
    let mut counts = vec![plain_chunks];
    for command in [
        &["latest-at", "frame_id", "30"][..],
        &["latest-at", "sim_time", "1500000000"],
        &["range", "frame_id", "0", "59"],
        &["range", "log_time", "0", "9223372036854775807"],
    ] {
        let expected = cli(&[], command);
        assert!(expected.lines().count() > 10, "{command:?} answers");
        for options in variants {
            assert_eq!(cli(options, command), expected, "{options:?} {command:?}");
        }
    }
    for options in variants {
        counts.push(chunk_count(options));
    }
    // The options do change the store: splitting into tiny chunks, merging into few.
    assert!(counts[1] > plain_chunks * 3, "{counts:?}");
    assert!(counts[2] < plain_chunks, "{counts:?}");
}

#[test]
fn cli_rejects_bad_options() {
    for (options, message) in [
        (&["--max-rows", "0"][..], "max_rows must be at least 1"),
        (
            &["--max-bytes", "lots"],
            "invalid value 'lots' for '--max-bytes <N>'",
        ),
        (&["--max-rows"], "invalid value"), // it took the source as its value
        (&["--frobnicate", "1"], "unexpected argument '--frobnicate'"),
    ] {
        let mut args: Vec<&OsStr> = options.iter().map(OsStr::new).collect();
        let chunks = recording_chunks();
        args.push(chunks.as_os_str());
        args.push(OsStr::new("stats"));
        let line = fails(&args);
        assert!(line.contains(message), "{options:?}: {line}");
    }
}

#[test]
fn cli_answers_on_the_robot_recording() {
    let lines: Vec<serde_json::Value> = cli(&[], &["latest-at", "frame_id", "30"])
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let find = |entity: &str, component: &str| {
        lines
            .iter()
            .find(|l| l["entity"] == entity && l["component"] == component)
            .unwrap()
    };
    let cost = find("/metrics/planner/cost", "Scalars:scalars");
    assert_eq!(cost["time"], 30);
    assert_eq!(cost["value"], serde_json::json!([2.239_023_101_159_236]));
    assert_eq!(
        find("/world", "ViewCoordinates:xyz")["time"],
        serde_json::Value::Null
    );
    assert_eq!(
        find("/world", "ViewCoordinates:xyz")["value"],
        serde_json::json!([[3, 5, 1]])
    );
    let keys: Vec<(String, String)> = lines
        .iter()
        .map(|l| {
            (
                l["entity"].as_str().unwrap().to_owned(),
                l["component"].as_str().unwrap().to_owned(),
            )
        })
        .collect();
    assert!(
        keys.is_sorted(),
        "lines are ordered by entity then component"
    );
    assert_eq!(
        keys.len(),
        14,
        "every (entity, component) answers at frame 30"
    );
}

/// Issue 14: the `.rrd` Rerun wrote answers exactly as its chunk files do, lazily (through
/// the footer) or eagerly, on every timeline.
#[test]
fn the_rrd_answers_like_the_chunk_files_lazily_or_not() {
    let rrd = recording_rrd();
    for command in [
        &["latest-at", "frame_id", "30"][..],
        &["latest-at", "frame_id", "-5"],
        &["latest-at", "sim_time", "1500000000"],
        &["latest-at", "log_time", "9223372036854775807"],
        &["range", "frame_id", "0", "59"],
        &["range", "sim_time", "100", "2000000000"],
        &["range", "log_time", "0", "9223372036854775807"],
    ] {
        let expected = cli(&[], command);
        assert!(!expected.is_empty(), "{command:?}");
        assert_eq!(cli_on(&rrd, &[], command), expected, "lazy {command:?}");
        assert_eq!(
            cli_on(&rrd, &["--eager"], command),
            expected,
            "eager {command:?}"
        );
    }
    let stats = |source: &Path| -> serde_json::Value {
        serde_json::from_str(&cli_on(source, &[], &["stats"])).unwrap()
    };
    let (a, b) = (stats(&rrd), stats(&recording_chunks()));
    for key in [
        "num_chunks",
        "num_rows",
        "num_entities",
        "timelines",
        "entities",
    ] {
        assert_eq!(a[key], b[key], "{key}");
    }
}

/// Issue 14: `print` lists the chunks in file order, as text or JSON lines.
#[test]
fn print_lists_every_chunk_in_file_order() {
    let json = cli_on(&recording_rrd(), &[], &["print", "--json"]);
    let lines: Vec<serde_json::Value> = json
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 37);
    let first = &lines[0];
    assert_eq!(first["entity"], "/__properties");
    assert_eq!(first["static"], true);
    assert_eq!(first["chunk_id"], "chunk_18ea10afd776aa1f6deffa92d8abe82a");
    assert_eq!(
        lines
            .iter()
            .map(|l| l["rows"].as_u64().unwrap())
            .sum::<u64>(),
        261
    );
    let robot = &lines[1];
    assert_eq!(
        robot["timelines"][0],
        serde_json::json!({"name": "frame_id", "type": "sequence", "min": 0, "max": 17})
    );
    // The same listing from the chunk files, and as text.
    assert_eq!(cli(&[], &["print", "--json"]), json);
    let text = cli_on(&recording_rrd(), &[], &["print"]);
    assert_eq!(text.lines().count(), 37);
    assert!(
        text.lines()
            .nth(1)
            .unwrap()
            .contains("/world/robot rows=18 frame_id=[0, 17]"),
        "{text}"
    );
}

/// Issue 14: `convert` writes an `.rrd` or a directory that read back to the same answers,
/// with or without compaction; it never writes over its source or into a non-empty
/// directory, and leaves nothing behind when it fails.
#[test]
fn convert_round_trips_and_is_careful_with_files() {
    let dir = scratch_dir("convert");
    let rrd = recording_rrd();
    let copy = dir.join("copy.rrd");
    let compacted = dir.join("compacted.rrd");
    let as_dir = dir.join("chunks");
    let back = dir.join("back.rrd");
    ok(&[rrd.as_os_str(), OsStr::new("convert"), copy.as_os_str()]);
    ok(&[
        OsStr::new("--compact"),
        rrd.as_os_str(),
        OsStr::new("convert"),
        compacted.as_os_str(),
    ]);
    ok(&[rrd.as_os_str(), OsStr::new("convert"), as_dir.as_os_str()]);
    ok(&[as_dir.as_os_str(), OsStr::new("convert"), back.as_os_str()]);
    // Without --compact, the chunks are the file's, in order.
    let listing = cli_on(&rrd, &[], &["print", "--json"]);
    assert_eq!(cli_on(&copy, &[], &["print", "--json"]), listing);
    assert_eq!(cli_on(&as_dir, &[], &["print", "--json"]), listing);
    assert_eq!(cli_on(&back, &[], &["print", "--json"]), listing);
    let compacted_chunks = cli_on(&compacted, &[], &["print"]).lines().count();
    assert!(compacted_chunks < 37, "{compacted_chunks}");
    // Every answer is the same (chunk ids aside, for the compacted file).
    let without_chunk_ids = |text: String| -> Vec<serde_json::Value> {
        text.lines()
            .map(|l| {
                let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
                v.as_object_mut().unwrap().remove("chunk_id");
                v
            })
            .collect()
    };
    for command in [
        &["latest-at", "frame_id", "30"][..],
        &["range", "sim_time", "0", "9000000000"],
    ] {
        let expected = cli_on(&rrd, &[], command);
        for source in [&copy, &as_dir, &back] {
            assert_eq!(
                cli_on(source, &[], command),
                expected,
                "{source:?} {command:?}"
            );
        }
        assert_eq!(
            without_chunk_ids(cli_on(&compacted, &[], command)),
            without_chunk_ids(expected)
        );
    }
    // The store info of an .rrd source is kept; chunk files get the given ids.
    let info = std::fs::read(&copy).unwrap();
    assert!(info.windows(25).any(|w| w == b"rerun_example_robot_scene"));

    // Never over the source, never into a non-empty directory.
    let line = fails(&[copy.as_os_str(), OsStr::new("convert"), copy.as_os_str()]);
    assert!(line.contains("overwrite the source"), "{line}");
    let line = fails(&[rrd.as_os_str(), OsStr::new("convert"), as_dir.as_os_str()]);
    assert!(line.contains("not empty"), "{line}");
    // A failed write leaves nothing: not the target, not a temporary file.
    let nowhere = dir.join("missing/out.rrd");
    fails(&[rrd.as_os_str(), OsStr::new("convert"), nowhere.as_os_str()]);
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["back.rrd", "chunks", "compacted.rrd", "copy.rrd"]);
}

/// A source holding one chunk twice (a chunk file copied under another name) converts to
/// an `.rrd` holding it once, which reads back: a recording lists each chunk id once.
#[test]
fn convert_writes_a_chunk_the_source_holds_twice_once() {
    let dir = scratch_dir("convert-twice");
    let source = dir.join("chunks");
    std::fs::create_dir_all(&source).unwrap();
    let mut files: Vec<PathBuf> = std::fs::read_dir(recording_chunks())
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    for file in &files {
        std::fs::copy(file, source.join(file.file_name().unwrap())).unwrap();
    }
    std::fs::copy(&files[0], source.join("zz_again.arrow")).unwrap();
    let out = dir.join("out.rrd");
    ok(&[source.as_os_str(), OsStr::new("convert"), out.as_os_str()]);
    let listing = cli_on(&out, &[], &["print", "--json"]);
    assert_eq!(
        listing,
        cli(&[], &["print", "--json"]),
        "each chunk once, in order"
    );
}

/// Issue 14: a damaged `.rrd` is one line naming the byte offset; `--skip-bad` loads what
/// comes before the damage and says what it skipped.
#[test]
fn a_damaged_rrd_is_one_line_and_skip_bad_keeps_the_rest() {
    let dir = scratch_dir("damaged");
    let bytes = std::fs::read(recording_rrd()).unwrap();
    let truncated = dir.join("truncated.rrd");
    std::fs::write(&truncated, &bytes[..150_000]).unwrap();
    for command in [&["stats"][..], &["latest-at", "frame_id", "30"], &["print"]] {
        let mut args = vec![truncated.as_os_str()];
        args.extend(command.iter().map(OsStr::new));
        let line = fails(&args);
        assert!(
            line.contains("at byte") && line.contains("truncated"),
            "{line}"
        );
    }
    let (out, warnings) = ok(&[
        OsStr::new("--skip-bad"),
        truncated.as_os_str(),
        OsStr::new("stats"),
    ]);
    let stats: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(stats["num_rows"].as_u64().unwrap() > 50, "{stats}");
    assert_eq!(warnings.lines().count(), 1, "{warnings}");
    assert!(warnings.contains("stopped reading"), "{warnings}");

    let not_rrd = dir.join("notes.txt");
    std::fs::write(&not_rrd, b"hello").unwrap();
    let line = fails(&[not_rrd.as_os_str(), OsStr::new("stats")]);
    assert!(line.contains("neither an .rrd"), "{line}");
    let mut old = bytes.clone();
    old[..4].copy_from_slice(b"RRF1");
    let old_file = dir.join("old.rrd");
    std::fs::write(&old_file, &old).unwrap();
    let line = fails(&[old_file.as_os_str(), OsStr::new("stats")]);
    assert!(line.contains("before Rerun 0.23"), "{line}");
    // A file from a newer Rerun is read, with one warning.
    let mut newer = bytes.clone();
    newer[5] = 99;
    let newer_file = dir.join("newer.rrd");
    std::fs::write(&newer_file, &newer).unwrap();
    for command in [&["stats"][..], &["latest-at", "frame_id", "30"], &["print"]] {
        let mut args = vec![newer_file.as_os_str()];
        args.extend(command.iter().map(OsStr::new));
        let (_, warning) = ok(&args);
        assert_eq!(warning.lines().count(), 1, "{warning}");
        assert!(warning.contains("Rerun 0.99.0, newer"), "{warning}");
    }
}

/// Issue 14: `--help` on the tool and on every command exits 0 and shows an example.
#[test]
fn every_command_has_help_with_an_example() {
    let output = run(&["--help"]);
    assert!(output.status.success());
    let text = String::from_utf8(output.stdout).unwrap();
    assert!(
        text.contains("Examples:") && text.contains("latest-at"),
        "{text}"
    );
    for command in [
        "latest-at",
        "range",
        "stats",
        "print",
        "convert",
        "dataframe",
    ] {
        let output = run(&[RRD, command, "--help"]);
        assert!(output.status.success(), "{command}");
        let text = String::from_utf8(output.stdout).unwrap();
        assert!(text.contains("Example"), "{command}: {text}");
    }
}

/// The table the library gives for `query` on the robot recording, as one batch.
fn library_table(query: &chunkstore::DataframeQuery) -> arrow_array::RecordBatch {
    let mut store = chunkstore::ChunkStore::new();
    for file in chunk_files() {
        for chunk in chunkstore::ipc::read_chunks_from_path(&file).unwrap() {
            store.insert(chunk).unwrap();
        }
    }
    let stream = store.dataframe(query).unwrap();
    let schema = stream.schema();
    let batches: Vec<_> = stream.map(Result::unwrap).collect();
    arrow_select::concat::concat_batches(&schema, &batches).unwrap()
}

fn concat(batches: &[arrow_array::RecordBatch]) -> arrow_array::RecordBatch {
    arrow_select::concat::concat_batches(&batches[0].schema(), batches).unwrap()
}

#[test]
fn dataframe_writes_what_the_library_answers_as_ipc_and_parquet() {
    use chunkstore::{DataframeQuery, EntityPathFilter, TimeInt, TimeRange};
    let t = |v| TimeInt::new(v).unwrap();
    let dir = scratch_dir("dataframe");
    let cases: [(&[&str], DataframeQuery); 4] = [
        (&["frame_id"], DataframeQuery::new("frame_id")),
        (
            &["sim_time", "--fill-latest-at", "--range", "0", "1000000000"],
            DataframeQuery::new("sim_time")
                .with_fill_latest_at(true)
                .with_range(TimeRange::new(t(0), t(1_000_000_000))),
        ),
        (
            &["frame_id", "--index-values", "-5,30,30,99"],
            DataframeQuery::new("frame_id").with_index_values([t(-5), t(30), t(30), t(99)]),
        ),
        (
            &[
                "frame_id",
                "--contents",
                "/world/**",
                "--contents",
                "-/world/map/**",
            ],
            DataframeQuery::new("frame_id")
                .with_contents(EntityPathFilter::parse(["/world/**", "-/world/map/**"]).unwrap()),
        ),
    ];
    for (source, name) in [(RRD, "rrd"), (CHUNKS, "chunks")] {
        for (i, (args, query)) in cases.iter().enumerate() {
            let expected = library_table(query);
            assert!(expected.num_columns() > 3);
            // An IPC file.
            let arrow = dir.join(format!("{name}-{i}.arrow"));
            let mut command = vec![source, "dataframe"];
            command.extend_from_slice(args);
            let out = arrow.to_str().unwrap();
            ok(&[command.clone(), vec!["--out", out]].concat());
            let bytes = std::fs::read(&arrow).unwrap();
            assert!(bytes.starts_with(b"ARROW1"), "an IPC file");
            assert_eq!(
                concat(&chunkstore::ipc::read_batches(&bytes).unwrap()),
                expected
            );
            // Parquet.
            let parquet = dir.join(format!("{name}-{i}.parquet"));
            ok(&[command.clone(), vec!["--out", parquet.to_str().unwrap()]].concat());
            let file = std::fs::File::open(&parquet).unwrap();
            let reader =
                parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file)
                    .unwrap()
                    .build()
                    .unwrap();
            let batches: Vec<_> = reader.map(Result::unwrap).collect();
            assert_eq!(concat(&batches), expected);
            // An IPC stream on stdout.
            let output = run(&command);
            assert!(output.status.success());
            assert!(
                !output.stdout.starts_with(b"ARROW1"),
                "a stream, not a file"
            );
            assert_eq!(
                concat(&chunkstore::ipc::read_batches(&output.stdout).unwrap()),
                expected
            );
        }
    }
}

#[test]
fn dataframe_names_every_bad_argument_and_input_on_one_line() {
    let dir = scratch_dir("dataframe-bad");
    let truncated = dir.join("truncated.rrd");
    std::fs::write(&truncated, &std::fs::read(recording_rrd()).unwrap()[..1000]).unwrap();
    let truncated = truncated.to_str().unwrap();
    let out = dir.join("never.parquet");
    let out = out.to_str().unwrap();
    for (args, expected) in [
        (vec![RRD, "dataframe", "nope"], "unknown timeline \"nope\""),
        (
            vec![RRD, "dataframe", "frame_id", "--range", "5", "3"],
            "MIN is greater than MAX",
        ),
        (
            vec![RRD, "dataframe", "frame_id", "--range", "a", "3"],
            "is not a time",
        ),
        (
            vec![RRD, "dataframe", "frame_id", "--range", "1"],
            "2 values required",
        ),
        (
            vec![RRD, "dataframe", "frame_id", "--index-values", "1,x"],
            "\"x\" is not a time",
        ),
        (
            vec![
                RRD,
                "dataframe",
                "frame_id",
                "--index-values",
                "-9223372036854775808",
            ],
            "reserved",
        ),
        (
            vec![RRD, "dataframe", "frame_id", "--contents", "/a/**/b"],
            "`**` may only end a path",
        ),
        (
            vec![RRD, "dataframe", "frame_id", "--contents", "/a//b"],
            "empty part",
        ),
        (
            vec!["/nonexistent", "dataframe", "frame_id"],
            "No such file",
        ),
        (
            vec![truncated, "dataframe", "frame_id", "--out", out],
            "truncated",
        ),
        (vec![RRD, "dataframe"], "required"),
    ] {
        let line = fails(&args);
        assert!(line.contains(expected), "{args:?}: {line}");
    }
    assert!(!Path::new(out).exists(), "nothing is written on an error");
    // The output may not overwrite the source.
    let copy = dir.join("copy.arrow");
    std::fs::copy(chunk_files()[0].clone(), &copy).unwrap();
    let copy = copy.to_str().unwrap();
    assert!(
        fails(&[copy, "dataframe", "frame_id", "--out", copy]).contains("overwrite the source")
    );
}

/// `sql` over the robot recording: a table, JSON lines, files; bad SQL is one line and
/// exit code 2.
#[cfg(feature = "datafusion")]
#[test]
fn sql_answers_as_a_table_as_json_lines_and_as_files() {
    let rrd = recording_rrd();
    let (table, _) = ok(&[
        rrd.as_os_str(),
        OsStr::new("sql"),
        OsStr::new(
            r#"SELECT frame_id, "/metrics/planner/cost:Scalars:scalars" AS cost FROM frame_id WHERE frame_id BETWEEN 10 AND 12"#,
        ),
    ]);
    assert!(table.contains("| frame_id | cost"), "{table}");
    assert_eq!(
        table.lines().filter(|l| l.starts_with("| 1")).count(),
        3,
        "{table}"
    );

    // The range is built in parts side by side; the rows still come in index order, a
    // filter DataFusion applies itself included (no ORDER BY asked).
    let (json, _) = ok(&[
        rrd.as_os_str(),
        OsStr::new("sql"),
        OsStr::new("SELECT frame_id FROM frame_id WHERE frame_id + 0 >= 0"),
        OsStr::new("--json"),
    ]);
    let frames: Vec<i64> = json
        .lines()
        .map(|l| {
            serde_json::from_str::<serde_json::Value>(l).unwrap()["frame_id"]
                .as_i64()
                .unwrap()
        })
        .collect();
    assert!(frames.len() > 10, "{json}");
    assert!(frames.windows(2).all(|w| w[0] < w[1]), "{frames:?}");
    // That order is kept by design, not by luck of scheduling: no round-robin spreads the
    // scan's batches over partitions for the filter.
    let (plan, _) = ok(&[
        rrd.as_os_str(),
        OsStr::new("sql"),
        OsStr::new("EXPLAIN SELECT frame_id FROM frame_id WHERE frame_id + 0 >= 0"),
    ]);
    assert!(plan.contains("built side by side"), "{plan}");
    assert!(!plan.contains("RepartitionExec"), "{plan}");

    let (json, _) = ok(&[
        rrd.as_os_str(),
        OsStr::new("sql"),
        OsStr::new(
            "SELECT entity_path, count(*) AS n FROM chunks WHERE entity_path LIKE '/world/%' GROUP BY entity_path ORDER BY entity_path",
        ),
        OsStr::new("--json"),
    ]);
    let rows: Vec<serde_json::Value> = json
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(rows.len(), 4, "{json}");
    assert_eq!(rows[1]["entity_path"], "/world/robot");
    assert_eq!(rows[1]["n"], 60);

    let dir = scratch_dir("sql-out");
    for name in ["answer.parquet", "answer.arrow"] {
        let out = dir.join(name);
        ok(&[
            rrd.as_os_str(),
            OsStr::new("sql"),
            OsStr::new("SELECT * FROM latest_at('frame_id', 30)"),
            OsStr::new("--out"),
            out.as_os_str(),
        ]);
        assert!(std::fs::metadata(&out).unwrap().len() > 0, "{name}");
    }
    let reader = std::fs::File::open(dir.join("answer.arrow")).unwrap();
    let batches: Vec<_> = arrow_ipc::reader::FileReader::try_new(reader, None)
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(
        batches
            .iter()
            .map(arrow_array::RecordBatch::num_rows)
            .sum::<usize>(),
        1
    );

    for bad in [
        "SELEC 1",
        "SELECT nope FROM frame_id",
        "SELECT * FROM latest_at('nope', 1)",
    ] {
        let line = fails(&[rrd.as_os_str(), OsStr::new("sql"), OsStr::new(bad)]);
        assert!(line.len() > 10, "{bad}: {line}");
    }
}

/// Built without `datafusion` (CI builds `cli` alone to run this): `sql` over a recording
/// and over a dataset exits 2 saying how to build it.
#[cfg(not(feature = "datafusion"))]
#[test]
fn sql_without_the_datafusion_feature_says_how_to_build_it() {
    let dataset = robot_dataset("sql-without-datafusion");
    for source in [recording_rrd(), dataset.to_path_buf()] {
        let line = fails(&[
            source.as_os_str(),
            OsStr::new("sql"),
            OsStr::new("SELECT 1"),
        ]);
        assert!(line.contains("--features cli,datafusion"), "{line}");
    }
}

/// `hive` writes a partitioned dataset, by entity or by time bucket, and refuses an
/// existing directory.
#[test]
fn hive_writes_a_partitioned_dataset() {
    let rrd = recording_rrd();
    let dir = scratch_dir("hive");
    let by_entity = dir.join("by_entity");
    let (_, stderr) = ok(&[
        rrd.as_os_str(),
        OsStr::new("hive"),
        by_entity.as_os_str(),
        OsStr::new("--index"),
        OsStr::new("frame_id"),
    ]);
    assert!(stderr.contains("wrote 261 rows in 8 files"), "{stderr}");
    assert!(
        by_entity
            .join("entity=%2Fworld%2Frobot/part-0.parquet")
            .is_file()
    );

    let by_bucket = dir.join("by_bucket");
    let (_, stderr) = ok(&[
        rrd.as_os_str(),
        OsStr::new("hive"),
        by_bucket.as_os_str(),
        OsStr::new("--index"),
        OsStr::new("frame_id"),
        OsStr::new("--bucket"),
        OsStr::new("25"),
    ]);
    assert!(stderr.contains("in 3 files"), "{stderr}");
    for k in 0..3 {
        assert!(
            by_bucket
                .join(format!("frame_id_bucket={k}/part-0.parquet"))
                .is_file()
        );
    }
    let line = fails(&[rrd.as_os_str(), OsStr::new("hive"), by_bucket.as_os_str()]);
    assert!(line.contains("already exists"), "{line}");
    let line = fails(&[
        rrd.as_os_str(),
        OsStr::new("hive"),
        dir.join("x").as_os_str(),
        OsStr::new("--index"),
        OsStr::new("nope"),
    ]);
    assert!(line.contains("unknown timeline"), "{line}");
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

/// Issue 32, items 1 and 4: `RecordingStream.save(path, default_blueprint=…)` writes the
/// blueprint's store first. `convert` (plain and `--compact`) used to write the recording's
/// chunks under the blueprint's store id, which chunkstore and Rerun then read as no
/// recording at all; and a directory kept no store info, so `.rrd → directory → .rrd`
/// lost the application and recording ids.
#[test]
fn convert_keeps_the_recording_s_identity_not_the_blueprint_s() {
    let dir = scratch_dir("identity");
    let source = identity_file("blueprint_first.rrd");
    let expected = vec![(
        "chunkstore_identity".to_owned(),
        "blueprint-first-rec".to_owned(),
    )];
    let answers = cli_on(&source, &[], &["latest-at", "frame", "4"]);
    assert!(answers.contains("/plot/a"), "{answers}");
    for (options, name) in [(&[][..], "plain.rrd"), (&["--compact"][..], "compact.rrd")] {
        let out = dir.join(name);
        let mut args: Vec<&OsStr> = options.iter().map(OsStr::new).collect();
        args.extend([source.as_os_str(), OsStr::new("convert"), out.as_os_str()]);
        let (_, stderr) = ok(&args);
        assert!(stderr.contains("left out its blueprint"), "{stderr}");
        assert_eq!(written_identity(&out), expected, "{name}");
        assert_eq!(cli_on(&out, &[], &["latest-at", "frame", "4"]), answers);
        assert_eq!(
            cli_on(&out, &["--eager"], &["latest-at", "frame", "4"]),
            answers
        );
    }
    // Through a directory of chunk files and back: the ids survive.
    let as_dir = dir.join("chunks");
    let back = dir.join("back.rrd");
    ok(&[
        source.as_os_str(),
        OsStr::new("convert"),
        as_dir.as_os_str(),
    ]);
    assert!(as_dir.join(chunkstore::rrd::STORE_INFO_FILE).is_file());
    ok(&[as_dir.as_os_str(), OsStr::new("convert"), back.as_os_str()]);
    assert_eq!(written_identity(&back), expected);
    assert_eq!(cli_on(&back, &[], &["latest-at", "frame", "4"]), answers);
    // A directory names its recording: asking for another is an error naming it.
    let line = fails(&[
        OsStr::new("--recording"),
        OsStr::new("other"),
        as_dir.as_os_str(),
        OsStr::new("stats"),
    ]);
    assert!(line.contains("\"blueprint-first-rec\""), "{line}");
}

/// Issue 32, item 2: rows logged at frames 2, 1, 3 compact into a chunk in time order,
/// whose row ids are then out of order; Rerun 0.41 refuses such a chunk. `--compact`
/// output is sorted by row id, and answers as the source does.
#[test]
fn compacted_output_of_out_of_order_rows_loads_in_rerun() {
    let dir = scratch_dir("out-of-order");
    let source = identity_file("out_of_order.rrd");
    let out = dir.join("compact.rrd");
    ok(&[
        OsStr::new("--compact"),
        source.as_os_str(),
        OsStr::new("convert"),
        out.as_os_str(),
    ]);
    assert_eq!(
        written_identity(&out),
        [(
            "chunkstore_identity".to_owned(),
            "out-of-order-rec".to_owned()
        )]
    );
    let as_dir = dir.join("chunks");
    ok(&[
        OsStr::new("--compact"),
        source.as_os_str(),
        OsStr::new("convert"),
        as_dir.as_os_str(),
    ]);
    for file in chunkstore::ipc::chunk_files(&as_dir).unwrap() {
        for chunk in chunkstore::ipc::read_chunks_from_path(&file).unwrap() {
            common::assert_rerun_loads(&chunk);
        }
    }
    let range = ["range", "frame", "0", "9"];
    let expected = cli_on(&source, &[], &range);
    assert_eq!(expected.matches("/plot/a").count(), 3, "{expected}");
    let strip = |text: String| -> Vec<serde_json::Value> {
        text.lines()
            .map(|l| {
                let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
                v.as_object_mut().unwrap().remove("chunk_id");
                v
            })
            .collect()
    };
    assert_eq!(strip(cli_on(&out, &[], &range)), strip(expected.clone()));
    assert_eq!(strip(cli_on(&as_dir, &[], &range)), strip(expected));
}

/// Issue 32, item 3: two recordings in one file (`cat a.rrd b.rrd`) are kept apart. Lazy
/// queries used to fail on the second stream's footer; `--eager`, `stats` and `convert`
/// merged both recordings into one store. Now every command names both recordings and
/// asks for `--recording ID`, and with it answers exactly as that recording's own file.
#[test]
fn a_file_of_two_recordings_is_never_merged() {
    let dir = scratch_dir("two-recordings");
    let a = identity_file("blueprint_first.rrd");
    let b = identity_file("out_of_order.rrd");
    let both = dir.join("both.rrd");
    let mut bytes = std::fs::read(&a).unwrap();
    bytes.extend(std::fs::read(&b).unwrap());
    std::fs::write(&both, bytes).unwrap();

    for (options, command) in [
        (&[][..], &["latest-at", "frame", "2"][..]),
        (&["--eager"], &["latest-at", "frame", "2"]),
        (&[], &["range", "frame", "0", "9"]),
        (&[], &["stats"]),
        (&[], &["dataframe", "frame"]),
    ] {
        let mut args: Vec<&OsStr> = options.iter().map(OsStr::new).collect();
        args.push(both.as_os_str());
        args.extend(command.iter().map(OsStr::new));
        let line = fails(&args);
        assert!(
            line.contains("\"blueprint-first-rec\", \"out-of-order-rec\"")
                && line.contains("--recording"),
            "{command:?}: {line}"
        );
    }
    let out = dir.join("b.rrd");
    fails(&[both.as_os_str(), OsStr::new("convert"), out.as_os_str()]);
    assert!(!out.exists());

    for (file, id) in [(&a, "blueprint-first-rec"), (&b, "out-of-order-rec")] {
        let chosen = ["--recording", id];
        for command in [
            &["latest-at", "frame", "2"][..],
            &["range", "frame", "0", "9"],
        ] {
            let expected = cli_on(file, &[], command);
            assert!(!expected.is_empty());
            assert_eq!(
                cli_on(&both, &chosen, command),
                expected,
                "{id} {command:?}"
            );
            let eager = ["--recording", id, "--eager"];
            assert_eq!(cli_on(&both, &eager, command), expected, "{id} {command:?}");
        }
        assert_eq!(
            cli_on(&both, &chosen, &["stats"]),
            cli_on(file, &[], &["stats"])
        );
        let out = dir.join(format!("{id}.rrd"));
        let mut args: Vec<&OsStr> = chosen.iter().map(OsStr::new).collect();
        args.extend([both.as_os_str(), OsStr::new("convert"), out.as_os_str()]);
        ok(&args);
        assert_eq!(
            written_identity(&out),
            [("chunkstore_identity".to_owned(), id.to_owned())]
        );
    }
    let line = fails(&[
        OsStr::new("--recording"),
        OsStr::new("nope"),
        both.as_os_str(),
        OsStr::new("latest-at"),
        OsStr::new("frame"),
        OsStr::new("2"),
    ]);
    assert!(line.contains("no recording \"nope\""), "{line}");
    // The same recording twice (`cat a.rrd a.rrd`) is one recording, not two.
    let twice = dir.join("twice.rrd");
    let mut bytes = std::fs::read(&b).unwrap();
    bytes.extend(std::fs::read(&b).unwrap());
    std::fs::write(&twice, bytes).unwrap();
    assert_eq!(
        cli_on(&twice, &[], &["range", "frame", "0", "9"]),
        cli_on(&b, &[], &["range", "frame", "0", "9"])
    );
}

/// Issue 32, item 6: outputs never replace what they should write through: a symbolic
/// link stays a link (its target gets the file), `/dev/stdout` (a pipe here) gets the
/// bytes, a device node stays a device node.
#[cfg(unix)]
#[test]
fn outputs_write_through_links_and_devices() {
    use std::os::unix::fs::FileTypeExt as _;
    let dir = scratch_dir("write-through");
    let rrd = recording_rrd();
    for (command, file) in [
        (&["dataframe", "frame_id", "--out"][..], "table.parquet"),
        (&["dataframe", "frame_id", "--out"], "table.arrow"),
        (&["convert"], "copy.rrd"),
    ] {
        let target = dir.join(format!("target-{file}"));
        let link = dir.join(file);
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let mut args: Vec<&OsStr> = vec![rrd.as_os_str()];
        args.extend(command.iter().map(OsStr::new));
        args.push(link.as_os_str());
        ok(&args);
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink(),
            "{file}: the link was replaced"
        );
        assert!(std::fs::metadata(&target).unwrap().len() > 0, "{file}");
    }
    // `--out /dev/stdout`: the Arrow IPC file on the pipe the test reads.
    let output = run(&[
        rrd.as_os_str(),
        OsStr::new("dataframe"),
        OsStr::new("frame_id"),
        OsStr::new("--out"),
        OsStr::new("/dev/stdout"),
    ]);
    assert!(output.status.success(), "{output:?}");
    assert!(
        output.stdout.starts_with(b"ARROW1"),
        "{:?}",
        &output.stdout[..8]
    );
    assert_eq!(
        chunkstore::ipc::read_batches(&output.stdout)
            .unwrap()
            .iter()
            .map(arrow_array::RecordBatch::num_rows)
            .sum::<usize>(),
        60
    );
    let dataframe_to = |out: &'static str| {
        [
            rrd.as_os_str(),
            OsStr::new("dataframe"),
            OsStr::new("frame_id"),
            OsStr::new("--out"),
            OsStr::new(out),
        ]
    };
    ok(&dataframe_to("/dev/null"));
    assert!(
        std::fs::metadata("/dev/null")
            .unwrap()
            .file_type()
            .is_char_device()
    );
    if Path::new("/dev/full").exists() {
        let line = fails(&dataframe_to("/dev/full"));
        assert!(line.contains("/dev/full"), "{line}");
        assert!(
            std::fs::metadata("/dev/full")
                .unwrap()
                .file_type()
                .is_char_device()
        );
    }
}

/// Issue 32, item 8: SIGTERM (and SIGINT) in the middle of a write leaves no temporary
/// file or directory behind, and no output; `hive` refuses a missing parent directory as
/// every other output does.
#[cfg(unix)]
#[test]
fn an_interrupted_write_leaves_no_debris() {
    let dir = scratch_dir("interrupted");
    // 20,000 one-row chunks: `convert` to a directory writes and syncs a file each, long
    // enough to be interrupted.
    let source = dir.join("many.rrd");
    let info = chunkstore::rrd::StoreInfo::new(chunkstore::rrd::StoreId::recording("app", "many"));
    let chunks = (0u16..20_000).map(|i| {
        std::sync::Arc::new(common::scalar(
            "/e",
            "x",
            i64::from(i),
            1 + u128::from(i),
            0.5,
        ))
    });
    chunkstore::rrd::write_rrd_file(&source, &info, chunks, |_| {}).unwrap();
    let outputs = dir.join("outputs");
    std::fs::create_dir(&outputs).unwrap();
    for signal in ["-TERM", "-INT"] {
        let out = outputs.join("chunks");
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_chunkstore"))
            .args([source.as_os_str(), OsStr::new("convert"), out.as_os_str()])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // Wait until the temporary directory holds a file, then interrupt.
        let started = std::time::Instant::now();
        loop {
            let busy = std::fs::read_dir(&outputs).unwrap().any(|e| {
                let path = e.unwrap().path();
                path.is_dir() && std::fs::read_dir(&path).unwrap().next().is_some()
            });
            if busy {
                break;
            }
            assert!(
                child.try_wait().unwrap().is_none(),
                "finished before it could be interrupted"
            );
            assert!(
                started.elapsed().as_secs() < 60,
                "no temporary directory appeared"
            );
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        let status = std::process::Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .unwrap();
        assert!(status.success());
        let output = child.wait_with_output().unwrap();
        assert_eq!(output.status.code(), Some(130), "{signal}: {output:?}");
        let left: Vec<_> = std::fs::read_dir(&outputs)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        assert!(left.is_empty(), "{signal}: debris {left:?}");
    }
    let line = fails(&[
        recording_rrd().as_os_str(),
        OsStr::new("hive"),
        dir.join("missing/parent/h").as_os_str(),
    ]);
    assert!(line.contains("does not exist"), "{line}");
    assert!(!dir.join("missing").exists());
}

/// Issue 32, item 16: errors that read well: no about-line for a missing SOURCE, no "at
/// byte 0" and no path named twice for an output that cannot be created, no "not Arrow
/// IPC" for a full disk, a negative count named as one, and global options under their
/// own heading in every command's help.
#[test]
fn errors_read_well() {
    let line = fails::<&str>(&[]);
    assert!(line.contains("a SOURCE and a COMMAND are needed"), "{line}");
    let rrd = recording_rrd();
    let rrd = rrd.to_str().unwrap();
    for command in [
        &["convert", "/nonexistent/x.rrd"][..],
        &["dataframe", "frame_id", "--out", "/nonexistent/x.parquet"],
        &["dataframe", "frame_id", "--out", "/nonexistent/x.arrow"],
        &["sql", "SELECT 1", "--out", "/nonexistent/x.parquet"],
        &["hive", "/nonexistent/x"],
    ] {
        let mut args = vec![rrd];
        args.extend(command);
        let line = fails(&args);
        assert!(!line.contains("at byte"), "{line}");
        assert_eq!(line.matches("/nonexistent/x").count(), 1, "{line}");
    }
    if Path::new("/dev/full").exists() {
        let line = fails(&[rrd, "dataframe", "frame_id", "--out", "/dev/full"]);
        assert!(
            !line.contains("not Arrow IPC") && line.contains("No space left"),
            "{line}"
        );
    }
    let line = fails(&["--max-rows", "-1", rrd, "stats"]);
    assert!(line.contains("-1 is negative"), "{line}");
    let (help, _) = ok(&[rrd, "latest-at", "--help"]);
    let global = help
        .find("Global options")
        .expect("a heading for global options");
    assert!(help[global..].contains("--max-rows") && !help[..global].contains("--max-rows"));
}

/// Issue 32, item 14: times as a person writes them: an RFC 3339 timestamp on a timestamp
/// timeline, a number with a unit on a duration timeline, in `latest-at`, `range`,
/// `dataframe` and SQL's `latest_at`, each answering as the same time in nanoseconds; a
/// form the timeline's type does not take is named with that type.
#[test]
fn human_times_answer_as_their_nanoseconds() {
    let rrd = recording_rrd();
    let rrd = rrd.to_str().unwrap();
    let chunks = recording_chunks();
    let chunks = chunks.to_str().unwrap();
    // The robot's log_time at frame 30 is 2026-11-21T12:55:49.5...Z; sim_time is 0.1 s a frame.
    for source in [rrd, chunks] {
        let same = |human: &[&str], integer: &[&str]| {
            let answer = cli_on(Path::new(source), &[], human);
            assert!(!answer.is_empty(), "{human:?}");
            assert_eq!(answer, cli_on(Path::new(source), &[], integer), "{human:?}");
        };
        same(
            &["latest-at", "log_time", "2026-11-21T12:55:49.5Z"],
            &["latest-at", "log_time", "1795265749500000000"],
        );
        same(
            &["latest-at", "log_time", "2026-11-21 13:55:49.5+01:00"],
            &["latest-at", "log_time", "1795265749500000000"],
        );
        same(
            &["latest-at", "sim_time", "1.5s"],
            &["latest-at", "sim_time", "1500000000"],
        );
        same(
            &["range", "sim_time", "1s", "2500ms"],
            &["range", "sim_time", "1000000000", "2500000000"],
        );
        let line = fails(&[source, "latest-at", "frame_id", "1.5s"]);
        assert!(line.contains("not a time of a sequence timeline"), "{line}");
        let line = fails(&[source, "range", "sim_time", "2s", "1s"]);
        assert!(line.contains("MIN is greater than MAX"), "{line}");
        let line = fails(&[source, "latest-at", "log_time", "2026-02-30T00:00:00Z"]);
        assert!(line.contains("is not a time"), "{line}");
    }
    let table = |args: &[&str]| {
        let output = run(args);
        assert!(output.status.success(), "{args:?}");
        output.stdout
    };
    assert_eq!(
        table(&[rrd, "dataframe", "sim_time", "--range", "1s", "2s"]),
        table(&[
            rrd,
            "dataframe",
            "sim_time",
            "--range",
            "1000000000",
            "2000000000"
        ])
    );
    assert_eq!(
        table(&[
            rrd,
            "dataframe",
            "log_time",
            "--index-values",
            "2026-11-21T12:55:49Z,2026-11-21T12:55:50Z"
        ]),
        table(&[
            rrd,
            "dataframe",
            "log_time",
            "--index-values",
            "1795265749000000000,1795265750000000000"
        ])
    );
    #[cfg(feature = "datafusion")]
    {
        let count = |time: &str| {
            let query = format!(
                "SELECT \"/world/robot:Transform3D:translation\" AS t FROM latest_at('sim_time', {time})"
            );
            cli_on(Path::new(rrd), &[], &["sql", &query, "--json"])
        };
        assert_eq!(count("'1.5s'"), count("1500000000"));
        assert!(count("'1.5s'").contains("\"t\""));
    }
}

/// Issue 32, item 15: quick looks. `--contents` and `--component` narrow `latest-at` and
/// `range` to the lines the whole answer has for them (a selection of nothing is an
/// error), and `-` reads the source from standard input.
#[test]
fn selections_and_standard_input() {
    let rrd = recording_rrd();
    let rrd = rrd.to_str().unwrap();
    let all = cli_on(Path::new(rrd), &[], &["latest-at", "frame_id", "30"]);
    let only = cli_on(
        Path::new(rrd),
        &[],
        &[
            "latest-at",
            "frame_id",
            "30",
            "--contents",
            "/world/**",
            "--contents",
            "-/world/map/**",
            "--component",
            "Transform3D:translation",
            "--component",
            "Image:buffer",
        ],
    );
    let expected: Vec<&str> = all
        .lines()
        .filter(|l| l.contains("\"entity\":\"/world") && !l.contains("\"entity\":\"/world/map"))
        .filter(|l| {
            l.contains("\"component\":\"Transform3D:translation\"")
                || l.contains("\"component\":\"Image:buffer\"")
        })
        .collect();
    assert!(!expected.is_empty());
    assert_eq!(only.lines().collect::<Vec<_>>(), expected);
    let ranged = cli_on(
        Path::new(rrd),
        &[],
        &["range", "frame_id", "0", "9", "--contents", "/metrics/**"],
    );
    assert_eq!(ranged.lines().count(), 10, "{ranged}");
    let line = fails(&[rrd, "range", "frame_id", "0", "9", "--component", "Nope"]);
    assert!(line.contains("selects no"), "{line}");

    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_chunkstore"))
        .args(["-", "latest-at", "frame_id", "30"])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let bytes = std::fs::read(rrd).unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let writer = std::thread::spawn(move || {
        use std::io::Write as _;
        stdin.write_all(&bytes).unwrap();
    });
    let output = child.wait_with_output().unwrap();
    writer.join().unwrap();
    assert!(output.status.success());
    assert_eq!(String::from_utf8(output.stdout).unwrap(), all);
}

/// The batches of an Arrow IPC file, as one batch.
fn read_arrow_file(path: &Path) -> arrow_array::RecordBatch {
    let reader =
        arrow_ipc::reader::FileReader::try_new(std::fs::File::open(path).unwrap(), None).unwrap();
    let schema = reader.schema();
    let batches: Vec<_> = reader.map(Result::unwrap).collect();
    arrow_select::concat::concat_batches(&schema, &batches).unwrap()
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

/// Issue 36: a directory of `.rrd` files is a dataset. `stats` lists its segments from
/// their footers; `dataframe` is each segment's own table in turn, under the segment id;
/// `latest-at --segment` reads one segment as its file would.
#[test]
fn a_directory_of_rrd_files_is_a_dataset() {
    let dir = robot_dataset("dataset");
    let (stats, _) = ok(&[dir.as_os_str(), OsStr::new("stats")]);
    let stats: serde_json::Value = serde_json::from_str(&stats).unwrap();
    let ids: Vec<&str> = stats["segments"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["id"].as_str().unwrap())
        .collect();
    let robot_id = "a0000000-0000-4000-8000-00000000000a";
    assert_eq!(ids, [robot_id, "second"]);
    assert_eq!(stats["num_segments"], 2);
    let (one, _) = ok(&[dir.join("one.rrd").as_os_str(), OsStr::new("stats")]);
    let one: serde_json::Value = serde_json::from_str(&one).unwrap();
    assert_eq!(stats["segments"][0]["num_rows"], one["num_rows"]);
    assert_eq!(stats["timelines"], one["timelines"]);

    let out = dir.join("table.arrow");
    ok(&[
        dir.as_os_str(),
        OsStr::new("dataframe"),
        OsStr::new("frame_id"),
        OsStr::new("--fill-latest-at"),
        OsStr::new("--out"),
        out.as_os_str(),
    ]);
    let table = read_arrow_file(&out);
    let own_out = dir.join("own.arrow");
    std::fs::remove_file(&out).unwrap();
    ok(&[
        dir.join("one.rrd").as_os_str(),
        OsStr::new("dataframe"),
        OsStr::new("frame_id"),
        OsStr::new("--fill-latest-at"),
        OsStr::new("--out"),
        own_out.as_os_str(),
    ]);
    let own = read_arrow_file(&own_out);
    std::fs::remove_file(&own_out).unwrap();
    assert_eq!(table.num_rows(), 2 * own.num_rows());
    assert_eq!(table.schema().field(0).name(), "rerun_segment_id");
    assert_eq!(
        table.num_columns(),
        own.num_columns() + 1,
        "the same columns, and the segment's"
    );
    let segments = table
        .column(0)
        .as_any()
        .downcast_ref::<arrow_array::StringArray>()
        .unwrap();
    for (half, id) in [(0, robot_id), (1, "second")] {
        let part = table.slice(half * own.num_rows(), own.num_rows());
        assert!(
            (half * own.num_rows()..(half + 1) * own.num_rows())
                .all(|row| segments.value(row) == id)
        );
        for field in own.schema().fields() {
            assert_eq!(
                part.column_by_name(field.name()).unwrap().to_data(),
                own.column_by_name(field.name()).unwrap().to_data(),
                "{id} {}",
                field.name()
            );
        }
    }

    let latest = |source: &Path, segment: Option<&str>| {
        let mut args: Vec<&OsStr> = Vec::new();
        if let Some(segment) = segment {
            args.extend([OsStr::new("--segment"), OsStr::new(segment)]);
        }
        args.extend([
            source.as_os_str(),
            OsStr::new("latest-at"),
            OsStr::new("frame_id"),
            OsStr::new("30"),
        ]);
        ok(&args).0
    };
    let answer = latest(&dir, Some("second"));
    assert!(!answer.is_empty());
    assert_eq!(answer, latest(&dir.join("two.rrd"), None));
}

/// Issue 36: `sql` over a dataset: each timeline table holds every segment's rows under its
/// id (as `dataframe` gives them), filters on the segment id prune whole files (`EXPLAIN`
/// says how many), and the output may not overwrite a segment.
#[cfg(feature = "datafusion")]
#[test]
fn sql_answers_over_a_dataset() {
    let dir = robot_dataset("dataset-sql");
    let (own, _) = ok(&[
        dir.join("one.rrd").as_os_str(),
        OsStr::new("sql"),
        OsStr::new("SELECT count(*) AS n FROM frame_id"),
        OsStr::new("--json"),
    ]);
    let own: serde_json::Value = serde_json::from_str(own.trim()).unwrap();
    let (counts, _) = ok(&[
        dir.as_os_str(),
        OsStr::new("sql"),
        OsStr::new("SELECT rerun_segment_id, count(*) AS n FROM frame_id GROUP BY 1 ORDER BY 1"),
        OsStr::new("--json"),
    ]);
    let rows: Vec<serde_json::Value> = counts
        .lines()
        .map(|line| serde_json::from_str(line).unwrap())
        .collect();
    assert_eq!(rows.len(), 2, "{counts}");
    assert_eq!(
        rows[0]["rerun_segment_id"],
        "a0000000-0000-4000-8000-00000000000a"
    );
    assert_eq!(rows[1]["rerun_segment_id"], "second");
    assert!(rows.iter().all(|row| row["n"] == own["n"]), "{counts}");

    let (plan, _) = ok(&[
        dir.as_os_str(),
        OsStr::new("sql"),
        OsStr::new("EXPLAIN SELECT count(*) FROM frame_id WHERE rerun_segment_id = 'second'"),
        OsStr::new("--full"),
    ]);
    assert!(
        plan.contains("segments=1 of 2 (pruned: 1 by rerun_segment_id)"),
        "{plan}"
    );
    let clobber = fails(&[
        dir.as_os_str(),
        OsStr::new("sql"),
        OsStr::new("SELECT 1"),
        OsStr::new("--out"),
        dir.join("two.rrd").as_os_str(),
    ]);
    assert!(clobber.contains("would overwrite segment"), "{clobber}");
    let latest = fails(&[
        dir.as_os_str(),
        OsStr::new("sql"),
        OsStr::new("SELECT * FROM latest_at('frame_id', 3)"),
    ]);
    assert!(latest.contains("--segment ID"), "{latest}");
}

/// Issue 36: `hive` of a dataset writes a partition per segment (and in it per bucket or
/// entity), says what it wrote, and refuses an existing directory or an unknown timeline
/// in one line, before reading anything.
#[test]
fn hive_of_a_dataset_writes_a_partition_per_segment() {
    let dir = robot_dataset("dataset-hive");
    let out = scratch_dir("dataset-hive-out");
    let by_bucket = out.join("by_bucket");
    let (_, said) = ok(&[
        dir.as_os_str(),
        OsStr::new("hive"),
        by_bucket.as_os_str(),
        OsStr::new("--index"),
        OsStr::new("frame_id"),
        OsStr::new("--bucket"),
        OsStr::new("100"),
    ]);
    assert!(said.contains("of 2 segments under"), "{said}");
    let mut segments: Vec<String> = std::fs::read_dir(&by_bucket)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    segments.sort();
    assert_eq!(
        segments,
        vec![
            "segment=a0000000-0000-4000-8000-00000000000a".to_owned(),
            "segment=second".to_owned()
        ]
    );
    // Each segment holds the rows its own file's dataframe has.
    let (own, _) = ok(&[
        dir.join("two.rrd").as_os_str(),
        OsStr::new("sql"),
        OsStr::new("SELECT count(*) AS n FROM frame_id"),
        OsStr::new("--json"),
    ]);
    let own: serde_json::Value = serde_json::from_str(own.trim()).unwrap();
    let rows: u64 = std::fs::read_dir(by_bucket.join("segment=second"))
        .unwrap()
        .map(|bucket| {
            let file = std::fs::File::open(bucket.unwrap().path().join("part-0.parquet")).unwrap();
            let reader = parquet::file::reader::SerializedFileReader::new(file).unwrap();
            let rows = parquet::file::reader::FileReader::metadata(&reader)
                .file_metadata()
                .num_rows();
            u64::try_from(rows).unwrap()
        })
        .sum();
    assert_eq!(serde_json::json!(rows), own["n"]);

    let by_entity = out.join("by_entity");
    let (_, said) = ok(&[dir.as_os_str(), OsStr::new("hive"), by_entity.as_os_str()]);
    assert!(said.contains("of 2 segments"), "{said}");
    assert!(by_entity.join("segment=second").is_dir());
    let entity = std::fs::read_dir(by_entity.join("segment=second"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap();
    assert!(
        entity
            .file_name()
            .to_string_lossy()
            .starts_with("entity=%2F"),
        "{:?}",
        entity.file_name()
    );

    let again = fails(&[dir.as_os_str(), OsStr::new("hive"), by_entity.as_os_str()]);
    assert!(again.contains("already exists"), "{again}");
    let unknown = fails(&[
        dir.as_os_str(),
        OsStr::new("hive"),
        out.join("unknown").as_os_str(),
        OsStr::new("--index"),
        OsStr::new("tick"),
        OsStr::new("--bucket"),
        OsStr::new("10"),
    ]);
    assert!(
        unknown.contains("no segment has the index") && unknown.contains("frame_id"),
        "{unknown}"
    );
    assert!(!out.join("unknown").exists());
}

/// Issue 36: `--index-cache DIR` keeps the index of a dataset's file without a footer in
/// DIR (`stats` then says where), never beside the data; the next run answers alike from
/// it. Given with one recording, it is refused in one line.
#[test]
fn index_cache_keeps_the_index_of_a_footerless_segment() {
    let dir = robot_dataset("dataset-index-cache");
    let chunks: Vec<chunkstore::Chunk> = common::robot_chunks();
    common::write_without_footer(&dir, "cut.rrd", "cut", chunks);
    // The guard is kept to the end: dropped at once, it would delete the directory before
    // the cache recreated it, and nothing would delete that.
    let cache_root = scratch_dir("dataset-index-cache-dir");
    let cache = cache_root.join("index");
    let listing = |dir: &Path| std::fs::read_dir(dir).map_or(0, Iterator::count);
    let files = listing(&dir);
    let stats = |extra: &[&OsStr]| {
        let args: Vec<&OsStr> = [
            OsStr::new("--index-cache"),
            cache.as_os_str(),
            dir.as_os_str(),
        ]
        .into_iter()
        .chain(extra.iter().copied())
        .collect();
        let (out, _) = ok(&args);
        out
    };
    let first = stats(&[OsStr::new("stats")]);
    let first: serde_json::Value = serde_json::from_str(first.trim()).unwrap();
    let cut = first["segments"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["id"] == "cut")
        .unwrap()
        .clone();
    assert_eq!(cut["from_footer"], false);
    let index = cut["index_file"].as_str().unwrap().to_owned();
    assert!(Path::new(&index).starts_with(&cache), "{index}");
    assert_eq!(listing(&cache), 1);
    assert_eq!(listing(&dir), files, "nothing beside the data");
    let counts = "SELECT rerun_segment_id, count(*) AS n FROM frame_id GROUP BY 1 ORDER BY 1";
    let cached = stats(&[OsStr::new("sql"), OsStr::new(counts), OsStr::new("--json")]);
    let (plain, _) = ok(&[
        dir.as_os_str(),
        OsStr::new("sql"),
        OsStr::new(counts),
        OsStr::new("--json"),
    ]);
    assert_eq!(cached, plain);
    assert_eq!(cached.lines().count(), 3, "{cached}");
    assert_eq!(listing(&cache), 1);

    let one = fails(&[
        OsStr::new("--index-cache"),
        cache.as_os_str(),
        recording_rrd().as_os_str(),
        OsStr::new("stats"),
    ]);
    assert!(one.contains("is not a dataset"), "{one}");
}

/// Issue 36: what a dataset does not do, or is not asked right, is one line on stderr;
/// a corrupt segment is named, and `--skip-bad` skips it with one warning.
#[test]
fn a_dataset_names_what_it_cannot_do() {
    let dir = robot_dataset("dataset-errors");
    let missing = fails(&[
        dir.as_os_str(),
        OsStr::new("latest-at"),
        OsStr::new("frame_id"),
        OsStr::new("3"),
    ]);
    assert!(
        missing.contains("--segment ID") && missing.contains("second"),
        "{missing}"
    );
    let unknown = fails(&[
        OsStr::new("--segment"),
        OsStr::new("third"),
        dir.as_os_str(),
        OsStr::new("range"),
        OsStr::new("frame_id"),
        OsStr::new("0"),
        OsStr::new("9"),
    ]);
    assert!(unknown.contains("no segment \"third\""), "{unknown}");
    let not_a_dataset = fails(&[
        OsStr::new("--segment"),
        OsStr::new("second"),
        recording_rrd().as_os_str(),
        OsStr::new("stats"),
    ]);
    assert!(
        not_a_dataset.contains("is not a dataset"),
        "{not_a_dataset}"
    );
    let index = fails(&[dir.as_os_str(), OsStr::new("dataframe"), OsStr::new("tick")]);
    assert!(
        index.contains("no segment has the index") && index.contains("frame_id"),
        "{index}"
    );
    let recording = fails(&[
        OsStr::new("--recording"),
        OsStr::new("second"),
        dir.as_os_str(),
        OsStr::new("stats"),
    ]);
    assert!(recording.contains("--segment ID"), "{recording}");
    let print = fails(&[dir.as_os_str(), OsStr::new("print")]);
    assert!(print.contains("not this command yet"), "{print}");
    let reversed = fails(&[
        dir.as_os_str(),
        OsStr::new("dataframe"),
        OsStr::new("frame_id"),
        OsStr::new("--range"),
        OsStr::new("9"),
        OsStr::new("3"),
    ]);
    assert!(reversed.contains("MIN is greater than MAX"), "{reversed}");
    let clobber = fails(&[
        dir.as_os_str(),
        OsStr::new("dataframe"),
        OsStr::new("frame_id"),
        OsStr::new("--out"),
        dir.join("two.rrd").as_os_str(),
    ]);
    assert!(clobber.contains("would overwrite segment"), "{clobber}");
    assert!(dir.join("two.rrd").exists());

    // A corrupt segment is named; --skip-bad skips it with a warning and answers.
    std::fs::write(dir.join("broken.rrd"), b"RRF2garbage").unwrap();
    let broken = fails(&[dir.as_os_str(), OsStr::new("stats")]);
    assert!(
        broken.contains("broken.rrd") && broken.contains("--skip-bad"),
        "{broken}"
    );
    let (stats, warnings) = ok(&[
        OsStr::new("--skip-bad"),
        dir.as_os_str(),
        OsStr::new("stats"),
    ]);
    assert!(warnings.contains("broken.rrd"), "{warnings}");
    assert_eq!(warnings.lines().count(), 1, "{warnings}");
    let stats: serde_json::Value = serde_json::from_str(&stats).unwrap();
    assert_eq!(stats["num_segments"], 2);
    // A command on one segment says of the other files one line, not one per file.
    std::fs::write(dir.join("broken2.rrd"), b"RRF2garbage").unwrap();
    let (_, warnings) = ok(&[
        OsStr::new("--skip-bad"),
        OsStr::new("--segment"),
        OsStr::new("second"),
        dir.as_os_str(),
        OsStr::new("latest-at"),
        OsStr::new("frame_id"),
        OsStr::new("3"),
    ]);
    assert_eq!(warnings.lines().count(), 1, "{warnings}");
    assert!(
        warnings.contains("2 warnings about other files"),
        "{warnings}"
    );
}

/// A directory with neither kind of file says what it looked for.
#[test]
fn a_directory_without_recordings_names_both_kinds() {
    let dir = scratch_dir("empty-dataset");
    std::fs::write(dir.join("readme.txt"), "nothing here").unwrap();
    let error = fails(&[dir.as_os_str(), OsStr::new("stats")]);
    assert!(error.contains("no .rrd files"), "{error}");
}

/// A recording of static data alone has no timeline, and static data answers on every
/// timeline (SEMANTICS.md section 3): `latest-at`, `range`, `dataframe` and SQL's
/// `latest_at` answer on any name, where a store with timelines still names a typo.
#[test]
fn a_recording_of_static_data_alone_answers_on_any_timeline() {
    let dir = scratch_dir("static-only");
    let source = common::write_recording(
        &dir,
        "static.rrd",
        "static",
        vec![common::static_scalar("/config", "gain", 1, 2.5)],
    );
    let (out, _) = ok(&[
        source.as_os_str(),
        "latest-at".as_ref(),
        "frame".as_ref(),
        "0".as_ref(),
    ]);
    assert!(out.contains("2.5"), "{out}");
    let (out, _) = ok(&[
        source.as_os_str(),
        "latest-at".as_ref(),
        "log_time".as_ref(),
        "2026-11-21T12:55:49Z".as_ref(),
    ]);
    assert!(out.contains("2.5"), "{out}");
    let (out, _) = ok(&[
        source.as_os_str(),
        "range".as_ref(),
        "frame".as_ref(),
        "0".as_ref(),
        "10".as_ref(),
    ]);
    assert!(out.contains("2.5"), "{out}");
    let table = run(&[source.as_os_str(), "dataframe".as_ref(), "frame".as_ref()]);
    assert!(
        table.status.success(),
        "{}",
        String::from_utf8_lossy(&table.stderr)
    );
    if cfg!(feature = "datafusion") {
        let (out, _) = ok(&[
            source.as_os_str(),
            "sql".as_ref(),
            "SELECT * FROM latest_at('frame', 3)".as_ref(),
        ]);
        assert!(out.contains("2.5"), "{out}");
    }
    // A typo on a recording with timelines is still an error naming them.
    let line = fails(&[RRD, "latest-at", "FRAME_ID", "0"]);
    assert!(line.contains("unknown timeline \"FRAME_ID\""), "{line}");
}

/// A missing argument is named; an empty file says it is empty.
#[test]
fn a_missing_argument_is_named_and_an_empty_file_says_so() {
    let line = fails(&[RRD, "latest-at", "frame_id"]);
    assert!(line.contains("<TIME>"), "{line}");
    let dir = scratch_dir("empty-file");
    let empty = dir.join("empty.rrd");
    std::fs::write(&empty, b"").unwrap();
    let line = fails(&[empty.as_os_str(), "stats".as_ref()]);
    assert!(line.contains("the file is empty"), "{line}");
}
