//! Datasets (a directory of `.rrd` files): `stats`, `dataframe`, `sql`, `hive`, the
//! index cache and `--segment`, and what a dataset cannot do, each in one line.

use std::ffi::OsStr;
use std::path::Path;

use crate::{common, fails, ok, recording_rrd, robot_dataset, scratch_dir};

/// The batches of an Arrow IPC file, as one batch.
fn read_arrow_file(path: &Path) -> arrow_array::RecordBatch {
    let reader =
        arrow_ipc::reader::FileReader::try_new(std::fs::File::open(path).unwrap(), None).unwrap();
    let schema = reader.schema();
    let batches: Vec<_> = reader.map(Result::unwrap).collect();
    arrow_select::concat::concat_batches(&schema, &batches).unwrap()
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

/// Issue 71: `hive --delta` makes a Delta table (a partition per segment, then per
/// entity), `--append` adds a recording as one more segment in the next commit and refuses
/// it the second time, a recording of chunk files is refused, and `--append` needs
/// `--delta`: each refusal one line.
#[test]
fn hive_delta_makes_a_table_and_appends_a_recording_as_a_segment() {
    let dir = robot_dataset("dataset-delta");
    let out = scratch_dir("dataset-delta-out");
    let table = out.join("table");
    let one = dir.join("one.rrd");
    let two = dir.join("two.rrd");
    let (_, said) = ok(&[
        one.as_os_str(),
        OsStr::new("hive"),
        table.as_os_str(),
        OsStr::new("--delta"),
    ]);
    assert!(
        said.contains("committed version 0 of") && said.contains("of 1 segments"),
        "{said}"
    );
    let append = [
        two.as_os_str(),
        OsStr::new("hive"),
        table.as_os_str(),
        OsStr::new("--delta"),
        OsStr::new("--append"),
    ];
    let (_, said) = ok(&append);
    assert!(said.contains("committed version 1 of"), "{said}");
    assert!(table.join("_delta_log/00000000000000000001.json").is_file());
    assert!(table.join("segment=second").is_dir());
    let again = fails(&append);
    assert!(
        again.contains("segment \"second\" is in the table already"),
        "{again}"
    );
    let chunks = fails(&[
        common::robot_recording().join("chunks").as_os_str(),
        OsStr::new("hive"),
        out.join("chunks").as_os_str(),
        OsStr::new("--delta"),
    ]);
    assert!(chunks.contains("convert"), "{chunks}");
    assert!(
        !chunks.contains("  "),
        "one line, one space between words: {chunks}"
    );
    let no_delta = fails(&[
        one.as_os_str(),
        OsStr::new("hive"),
        table.as_os_str(),
        OsStr::new("--append"),
    ]);
    assert!(no_delta.contains("--delta"), "{no_delta}");
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
