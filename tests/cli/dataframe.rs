//! `dataframe` and `hive` over a recording: what the library answers, as Arrow IPC and
//! Parquet, and a partitioned Parquet dataset; every bad argument named on one line.

use std::ffi::OsStr;
use std::path::Path;

use crate::{CHUNKS, RRD, chunk_files, concat, fails, ok, recording_rrd, run, scratch_dir};

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
