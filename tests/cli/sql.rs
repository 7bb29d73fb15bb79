//! `sql` over a recording: a table, JSON lines, files; bad SQL in one line; a build
//! without DataFusion says how to get it.

use std::ffi::OsStr;

/// `sql` over the robot recording: a table, JSON lines, files; bad SQL is one line and
/// exit code 2.
#[cfg(feature = "datafusion")]
#[test]
fn sql_answers_as_a_table_as_json_lines_and_as_files() {
    use crate::{fails, ok, recording_rrd, scratch_dir};

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
    use crate::{fails, recording_rrd, robot_dataset};

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
