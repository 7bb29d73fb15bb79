//! Errors: one line on stderr and exit code 2 for every bad argument and input (never a
//! panic), each naming the problem and the option that gets past it (`--skip-bad`), and
//! `--help` with an example on every command.

use std::ffi::OsStr;
use std::path::Path;

use crate::{RRD, chunk_files, fails, ok, recording_chunks, recording_rrd, run, scratch_dir};

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
