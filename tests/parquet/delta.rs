//! Delta Lake tables (`Dataset::write_delta`): the Hive copy's files in Delta's types,
//! a log that names every file once, appends as single commits, and two writers racing
//! for one version: one wins, the other commits after it or, adding a segment the winner
//! added, fails and leaves nothing behind.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use arrow_schema::DataType;
use chunkstore::dataset::{Dataset, DatasetError, DatasetOptions};
use chunkstore::parquet::delta::{DeltaError, LocalTable};
use chunkstore::parquet::{HiveLayout, unescape_partition_value};
use serde_json::Value;

use super::common::{self, ScratchDir};
use super::read_back;

#[path = "../common/hooked_table.rs"]
mod hooked_table;
use hooked_table::Hooked;

fn by_entity() -> HiveLayout {
    HiveLayout::ByEntity {
        timeline: Some("frame".into()),
    }
}

fn unordered() -> HiveLayout {
    HiveLayout::ByEntity { timeline: None }
}

/// The episodes' files (`common::episodes`): `first.rrd` (rec-b), `second.rrd` (rec-a),
/// `static_only.rrd` (rec-s).
fn episode_files(scratch: &ScratchDir) -> PathBuf {
    let source = scratch.join("episodes");
    if !source.exists() {
        std::fs::create_dir(&source).unwrap();
        common::episodes(&source);
    }
    source
}

/// The dataset of some of the episodes' files.
fn dataset_of(scratch: &ScratchDir, names: &[&str]) -> Dataset {
    let dir = episode_files(scratch);
    let files: Vec<PathBuf> = names.iter().map(|n| dir.join(n)).collect();
    Dataset::open_files(&files, &DatasetOptions::default()).unwrap()
}

/// The table's log entries in order, each as its actions.
fn log(table: &Path) -> Vec<Vec<Value>> {
    let mut names: Vec<_> = std::fs::read_dir(table.join("_delta_log"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    names
        .iter()
        .enumerate()
        .map(|(version, name)| {
            assert_eq!(
                *name,
                format!("{version:020}.json"),
                "no other file in the log"
            );
            std::fs::read_to_string(table.join("_delta_log").join(name))
                .unwrap()
                .lines()
                .map(|line| serde_json::from_str(line).unwrap())
                .collect()
        })
        .collect()
}

/// The live files of the table (its log's adds) and each's `add`.
fn added(table: &Path) -> BTreeMap<String, Value> {
    log(table)
        .into_iter()
        .flatten()
        .filter_map(|action| action.get("add").cloned())
        .map(|add| (add["path"].as_str().unwrap().to_owned(), add))
        .collect()
}

/// Every Parquet file under `dir` (relative, `/`-separated).
fn parquet_files(dir: &Path) -> Vec<String> {
    fn walk(root: &Path, dir: &Path, out: &mut Vec<String>) {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(root, &path, out);
            } else if path.extension().is_some_and(|e| e == "parquet") {
                let relative = path.strip_prefix(root).unwrap();
                let parts: Vec<_> = relative.iter().map(|p| p.to_str().unwrap()).collect();
                out.push(parts.join("/"));
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}

/// What the table's last `metaData` says: its columns by name with their Delta types, and
/// its partition columns.
fn schema(table: &Path) -> (BTreeMap<String, Value>, Vec<String>) {
    let metadata = log(table)
        .into_iter()
        .flatten()
        .filter_map(|a| a.get("metaData").cloned())
        .next_back()
        .unwrap();
    let schema: Value = serde_json::from_str(metadata["schemaString"].as_str().unwrap()).unwrap();
    let columns = schema["fields"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| (f["name"].as_str().unwrap().to_owned(), f["type"].clone()))
        .collect();
    let partitions = metadata["partitionColumns"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p.as_str().unwrap().to_owned())
        .collect();
    (columns, partitions)
}

/// A new table is the Hive copy's files with a log: one `add` per file, its path the
/// file's (escaped once more, as a URI path), its partition values the directories'
/// decoded, its size and row count the file's.
#[test]
fn a_new_table_is_one_commit_naming_every_file() {
    let scratch = ScratchDir::new("delta-new");
    let dataset = dataset_of(&scratch, &["first.rrd", "second.rrd", "static_only.rrd"]);
    let dir = scratch.join("table");
    let commit = dataset
        .write_delta(&LocalTable::new(&dir), &by_entity(), false, &|_, _| {})
        .unwrap();
    assert_eq!(commit.version, 0);
    assert_eq!(commit.segments, ["rec-a", "rec-b", "rec-s"]);
    let entries = log(&dir);
    assert_eq!(entries.len(), 1);
    let actions = &entries[0];
    assert!(actions[0].get("commitInfo").is_some());
    assert_eq!(actions[1]["protocol"]["minReaderVersion"], 1);
    assert_eq!(actions[1]["protocol"]["minWriterVersion"], 2);
    let (columns, partitions) = schema(&dir);
    assert_eq!(partitions, ["segment", "entity"]);
    assert_eq!(columns["segment"], "string");
    assert_eq!(columns["entity"], "string");
    assert_eq!(columns["rerun_segment_id"], "string");
    assert_eq!(
        columns["row_id"], "binary",
        "a fixed-size binary id is binary"
    );
    assert_eq!(columns["frame"], "long");

    let adds = added(&dir);
    let files = parquet_files(&dir);
    assert_eq!(adds.len(), files.len(), "every file is in the log, once");
    assert_eq!(adds.len(), commit.files.len());
    let mut rows = 0;
    for (path, add) in &adds {
        let on_disk = unescape_partition_value(path);
        assert!(files.contains(&on_disk), "{path}: its file is {on_disk}");
        let file = dir.join(&on_disk);
        let (batch, _) = read_back(&file);
        assert_eq!(add["size"], std::fs::metadata(&file).unwrap().len());
        let stats: Value = serde_json::from_str(add["stats"].as_str().unwrap()).unwrap();
        assert_eq!(stats["numRecords"], batch.num_rows());
        // The index's exact range and nulls, for readers to skip files by.
        let frames = batch.column_by_name("frame").unwrap();
        let frames = frames
            .as_any()
            .downcast_ref::<arrow_array::Int64Array>()
            .unwrap();
        assert_eq!(
            stats["nullCount"]["frame"],
            arrow_array::Array::null_count(frames),
            "{path}"
        );
        let present: Vec<i64> = frames.iter().flatten().collect();
        if let (Some(low), Some(high)) = (present.iter().min(), present.iter().max()) {
            assert_eq!(stats["minValues"]["frame"], *low, "{path}");
            assert_eq!(stats["maxValues"]["frame"], *high, "{path}");
        } else {
            assert!(stats["minValues"].get("frame").is_none(), "{path}");
        }
        assert!(
            stats["minValues"].get("entity_path").is_none(),
            "text is not taken"
        );
        rows += batch.num_rows() as u64;
        let values = add["partitionValues"].as_object().unwrap();
        let directories: Vec<(&str, String)> = on_disk
            .split('/')
            .filter_map(|d| d.split_once('='))
            .map(|(k, v)| (k, unescape_partition_value(v)))
            .collect();
        assert_eq!(values.len(), 2);
        for (key, value) in directories {
            assert_eq!(values[key], value.as_str(), "{path}");
        }
        assert_eq!(
            super::strings(&batch, "rerun_segment_id")[0],
            values["segment"].as_str().unwrap()
        );
        assert!(
            super::strings(&batch, "entity_path")
                .iter()
                .all(|e| e == values["entity"].as_str().unwrap()),
            "{path}: a file holds its entity's rows"
        );
    }
    assert_eq!(rows, commit.rows());
    // No staging directory is left beside the table.
    let beside: Vec<_> = std::fs::read_dir(scratch.join("."))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.contains("partial"))
        .collect();
    assert!(beside.is_empty(), "{beside:?}");

    // A second new table in the same place is refused, and changes nothing.
    let error = dataset
        .write_delta(&LocalTable::new(&dir), &by_entity(), false, &|_, _| {})
        .unwrap_err();
    assert!(
        matches!(error, DatasetError::Delta(DeltaError::Exists { .. })),
        "{error}"
    );
    assert_eq!(parquet_files(&dir), files);
}

/// Whether a file's column type is one a Delta type reads as it is.
fn delta_only(data_type: &DataType) -> bool {
    match data_type {
        DataType::UInt8
        | DataType::UInt16
        | DataType::UInt32
        | DataType::UInt64
        | DataType::FixedSizeList(..)
        | DataType::FixedSizeBinary(_)
        | DataType::Timestamp(..)
        | DataType::Duration(_) => false,
        DataType::List(item) => delta_only(item.data_type()),
        DataType::Struct(fields) => fields.iter().all(|f| delta_only(f.data_type())),
        _ => true,
    }
}

/// A table of Rerun's own recording: its files hold only types Delta has (no unsigned
/// integers, fixed-size lists, timestamps or durations), every row of its chunk table.
#[test]
fn a_table_of_real_data_holds_delta_types_only() {
    let scratch = ScratchDir::new("delta-real");
    let dataset = Dataset::open_files(
        &[common::robot_recording().join("a_robot.rrd")],
        &DatasetOptions::default(),
    )
    .unwrap();
    let dir = scratch.join("table");
    let layout = HiveLayout::ByTimeBucket {
        timeline: "log_time".into(),
        width: 1_000_000_000,
        query: None,
    };
    let commit = dataset
        .write_delta(&LocalTable::new(&dir), &layout, false, &|_, _| {})
        .unwrap();
    let expected = super::collect(
        dataset
            .dataframe(&chunkstore::DataframeQuery::new("log_time"))
            .unwrap(),
    );
    assert_eq!(commit.rows(), expected.num_rows() as u64);
    let (columns, partitions) = schema(&dir);
    assert_eq!(partitions, ["segment", "log_time_bucket"]);
    assert_eq!(columns["log_time_bucket"], "long");
    assert_eq!(columns["log_time"], "long", "nanoseconds as they are");
    assert_eq!(columns["sim_time"], "long");
    let image = &columns["/world/robot/camera/rgb:Image:buffer"];
    assert_eq!(image["elementType"]["elementType"], "short", "u8 -> short");
    let mut times = Vec::new();
    for (file, _) in &commit.files {
        let (batch, _) = read_back(&dir.join(file));
        for field in batch.schema().fields() {
            assert!(delta_only(field.data_type()), "{file}: {field}");
        }
        let log_time = batch.column_by_name("log_time").unwrap();
        let log_time = log_time
            .as_any()
            .downcast_ref::<arrow_array::Int64Array>()
            .unwrap();
        times.extend(log_time.iter().map(Option::unwrap));
    }
    // The index keeps every nanosecond.
    let theirs = arrow_cast::cast(
        expected.column_by_name("log_time").unwrap(),
        &DataType::Int64,
    )
    .unwrap();
    let theirs = theirs
        .as_any()
        .downcast_ref::<arrow_array::Int64Array>()
        .unwrap();
    assert_eq!(times, theirs.values().to_vec());
}

/// An append is one commit adding the segments' files, and a `metaData` with the wider
/// schema when they bring columns; a segment the table holds is refused, as are another
/// partitioning and a place without a table. A refused append leaves no file behind.
#[test]
fn an_append_adds_segments_in_one_commit_and_refuses_what_does_not_fit() {
    let scratch = ScratchDir::new("delta-append");
    let dir = scratch.join("table");
    let table = LocalTable::new(&dir);
    dataset_of(&scratch, &["first.rrd"])
        .write_delta(&table, &by_entity(), false, &|_, _| {})
        .unwrap();
    let (before, _) = schema(&dir);
    assert!(!before.contains_key("/camera:exposure") && !before.contains_key("exposure"));

    let more = dataset_of(&scratch, &["second.rrd", "static_only.rrd"]);
    let commit = more
        .write_delta(&table, &by_entity(), true, &|_, _| {})
        .unwrap();
    assert_eq!(commit.version, 1);
    assert_eq!(commit.segments, ["rec-a", "rec-s"]);
    assert_eq!(commit.retries, 0);
    let entries = log(&dir);
    assert!(entries[1].iter().all(|a| a.get("protocol").is_none()));
    let (after, _) = schema(&dir);
    assert!(
        after.len() > before.len(),
        "rec-a's Clear columns widen the schema"
    );
    for (name, delta_type) in &before {
        assert_eq!(&after[name], delta_type, "{name} keeps its type");
    }
    let files = parquet_files(&dir);
    assert_eq!(added(&dir).len(), files.len());

    // The same segment again: refused before anything is written.
    let again = dataset_of(&scratch, &["second.rrd"]);
    let error = again
        .write_delta(&table, &by_entity(), true, &|_, _| {})
        .unwrap_err();
    assert!(
        matches!(&error, DatasetError::Delta(DeltaError::SegmentExists { segment }) if segment == "rec-a"),
        "{error}"
    );
    // Another partitioning.
    let layout = HiveLayout::ByTimeBucket {
        timeline: "frame".into(),
        width: 10,
        query: None,
    };
    let error = again
        .write_delta(&table, &layout, true, &|_, _| {})
        .unwrap_err();
    assert!(
        matches!(&error, DatasetError::Delta(DeltaError::Partitions { .. })),
        "{error}"
    );
    // No table there.
    let error = again
        .write_delta(
            &LocalTable::new(scratch.join("none")),
            &by_entity(),
            true,
            &|_, _| {},
        )
        .unwrap_err();
    assert!(
        matches!(&error, DatasetError::Delta(DeltaError::NotATable { .. })),
        "{error}"
    );
    assert_eq!(log(&dir).len(), 2);
    assert_eq!(parquet_files(&dir), files);

    // A log chunkstore cannot follow: a checkpoint, a newer protocol, a broken entry.
    let next = "_delta_log/00000000000000000002.json";
    for (file, text, unsupported) in [
        ("_delta_log/_last_checkpoint", "{\"version\":1}", true),
        (
            next,
            "{\"protocol\":{\"minReaderVersion\":3,\"minWriterVersion\":7}}\n",
            true,
        ),
        (next, "{\"add\": \n", false),
    ] {
        std::fs::write(dir.join(file), text).unwrap();
        let error = again
            .write_delta(&table, &by_entity(), true, &|_, _| {})
            .unwrap_err();
        let expected = match &error {
            DatasetError::Delta(DeltaError::UnsupportedTable { .. }) => unsupported,
            DatasetError::Delta(DeltaError::BadLog { .. }) => !unsupported,
            _ => false,
        };
        assert!(expected, "{file}: {error}");
        std::fs::remove_file(dir.join(file)).unwrap();
    }
    assert_eq!(parquet_files(&dir), files, "no refused write left a file");

    // A log with commits but no `metaData` describes no table.
    let bare = scratch.join("bare");
    std::fs::create_dir_all(bare.join("_delta_log")).unwrap();
    std::fs::write(
        bare.join("_delta_log/00000000000000000000.json"),
        "{\"commitInfo\":{}}\n",
    )
    .unwrap();
    let error = again
        .write_delta(&LocalTable::new(&bare), &by_entity(), true, &|_, _| {})
        .unwrap_err();
    assert!(
        matches!(&error, DatasetError::Delta(DeltaError::BadLog { reason, .. }) if reason.contains("no metaData")),
        "{error}"
    );
    assert!(parquet_files(&bare).is_empty());
}

/// Two writers commit at once: with different segments both land, one after the other
/// (the loser read the winner's commit and took the next version); with the same
/// segment exactly one lands, and the other's files are gone.
#[test]
fn two_writers_racing_never_both_win_a_version_or_a_segment() {
    let scratch = ScratchDir::new("delta-race");
    for same_segment in [false, true] {
        let dir = scratch.join(format!("table-{same_segment}"));
        dataset_of(&scratch, &["static_only.rrd"])
            .write_delta(&LocalTable::new(&dir), &unordered(), false, &|_, _| {})
            .unwrap();
        let racing = Hooked::racing(LocalTable::new(&dir), 2);
        let sources = if same_segment {
            [["second.rrd"], ["second.rrd"]]
        } else {
            [["first.rrd"], ["second.rrd"]]
        };
        let datasets: Vec<Dataset> = sources.iter().map(|s| dataset_of(&scratch, s)).collect();
        let results: Vec<_> = std::thread::scope(|scope| {
            let handles: Vec<_> = datasets
                .iter()
                .map(|d| scope.spawn(|| d.write_delta(&racing, &unordered(), true, &|_, _| {})))
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let context = format!("same segment: {same_segment}");
        let won: Vec<_> = results.iter().filter_map(|r| r.as_ref().ok()).collect();
        if same_segment {
            assert_eq!(won.len(), 1, "{context}");
            assert_eq!(won[0].version, 1, "{context}");
            let lost = results.iter().find_map(|r| r.as_ref().err()).unwrap();
            assert!(
                matches!(lost, DatasetError::Delta(DeltaError::SegmentExists { .. })),
                "{context}: {lost}"
            );
        } else {
            assert_eq!(won.len(), 2, "{context}: {results:?}");
            let mut versions: Vec<u64> = won.iter().map(|c| c.version).collect();
            versions.sort_unstable();
            assert_eq!(versions, [1, 2], "{context}");
            assert_eq!(won.iter().map(|c| c.retries).sum::<usize>(), 1, "{context}");
        }
        let adds = added(&dir);
        let files = parquet_files(&dir);
        assert_eq!(
            adds.len(),
            files.len(),
            "{context}: no file outside the log"
        );
        let segments: std::collections::BTreeSet<String> = adds
            .values()
            .map(|a| a["partitionValues"]["segment"].as_str().unwrap().to_owned())
            .collect();
        let expected: &[&str] = if same_segment {
            &["rec-a", "rec-s"]
        } else {
            &["rec-a", "rec-b", "rec-s"]
        };
        assert_eq!(
            segments.iter().map(String::as_str).collect::<Vec<_>>(),
            expected
        );
    }
}

/// A write places each segment's files once they are written: on one thread, the staging
/// directory never holds more than the segment being placed, whatever the table's size.
#[test]
fn a_write_stages_one_segment_at_a_time() {
    let scratch = ScratchDir::new("delta-staging");
    let dir = episode_files(&scratch);
    let files: Vec<PathBuf> = ["first.rrd", "second.rrd", "static_only.rrd"]
        .iter()
        .map(|n| dir.join(n))
        .collect();
    let dataset = Dataset::open_files(&files, &DatasetOptions::default().with_threads(1)).unwrap();
    // At every file placed, how many staged files wait.
    let waiting = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let seen = std::sync::Arc::clone(&waiting);
    let watching = Hooked {
        table: LocalTable::new(scratch.join("table")),
        before_commit: Box::new(|| {}),
        before_place: Box::new(move |staged: &Path| {
            let root = staged
                .ancestors()
                .find(|a| {
                    a.file_name()
                        .is_some_and(|n| n.to_string_lossy().contains(".partial-"))
                })
                .unwrap();
            seen.lock().unwrap().push(parquet_files(root).len());
        }),
    };
    let commit = dataset
        .write_delta(&watching, &unordered(), false, &|_, _| {})
        .unwrap();
    let waiting = waiting.lock().unwrap().clone();
    assert_eq!(waiting.len(), commit.files.len());
    // rec-a has 3 entities, rec-b 3, rec-s 1: never all 7 staged at once.
    let most = dataset
        .segments()
        .iter()
        .map(|s| {
            commit
                .files
                .iter()
                .filter(|(f, _)| f.contains(&format!("segment={}/", s.id)))
                .count()
        })
        .max()
        .unwrap();
    assert!(
        waiting.iter().all(|&n| n <= most),
        "{waiting:?}, a segment has at most {most}"
    );
    assert!(commit.files.len() > most);
}
