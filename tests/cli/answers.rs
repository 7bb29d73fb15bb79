//! Answers: `latest-at`, `range`, `stats` and `print` on the robot recording, the same
//! whatever the source's chunking, duplication or encoding (`.rrd` or chunk files, lazy or
//! not, standard input), with times as a person writes them and selections that must
//! select something; two recordings in one file never merged.

use std::ffi::OsStr;
use std::path::Path;

use crate::{
    RRD, chunk_files, cli, cli_on, common, fails, identity_file, ok, recording_chunks,
    recording_rrd, run, scratch_dir, written_identity,
};

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
