//! Outputs: `convert` round trips (`.rrd` and chunk directories, compacted or not, loaded
//! by Rerun), keeps the recording's identity, never overwrites its source, writes through
//! links and devices, and leaves nothing behind when it fails or is interrupted.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};

use crate::{
    cli, cli_on, common, fails, identity_file, ok, recording_chunks, recording_rrd, run,
    scratch_dir, written_identity,
};

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
