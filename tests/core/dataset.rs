//! Datasets (`chunkstore::dataset`, SEMANTICS.md section 15): a directory of `.rrd` files
//! queried as one table, each file a segment named by its recording id; the table is each
//! segment's own dataframe, one after another in id order, in the union of their columns.

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a test fails loudly"
)]

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_array::{Array, ArrayRef, Int64Array, RecordBatch, StringArray};
use arrow_select::concat::concat_batches;
use chunkstore::dataset::{Dataset, DatasetError, DatasetOptions, SEGMENT_ID_COLUMN};
use chunkstore::rrd::{RrdWriter, StoreId, StoreInfo, write_rrd_file};
use chunkstore::{Chunk, ChunkId, ChunkStore, DataframeQuery, LatestAtQuery, TimeInt, Timeline};

use crate::common::{ScratchDir, clear, scalars, static_scalar};

/// Writes `chunks` as recording `id` to `dir/name`, with a footer.
fn write(dir: &Path, name: &str, id: &str, chunks: Vec<Chunk>) -> PathBuf {
    let path = dir.join(name);
    let info = StoreInfo::new(StoreId::recording("app", id));
    write_rrd_file(&path, &info, chunks.into_iter().map(Arc::new), |_| {}).unwrap();
    path
}

/// Writes `chunks` as recording `id` without a footer (a stream cut before its end).
fn write_without_footer(dir: &Path, name: &str, id: &str, chunks: Vec<Chunk>) -> PathBuf {
    let mut bytes = Vec::new();
    {
        let info = StoreInfo::new(StoreId::recording("app", id));
        let mut writer = RrdWriter::with_store_info(&mut bytes, &info, true).unwrap();
        for chunk in chunks {
            writer.write_chunk(&Arc::new(chunk)).unwrap();
        }
    }
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

/// Four recordings of different shapes: entities and components only some share, Clears,
/// static data, one without the `frame` timeline's data (static only), one without a
/// footer.
fn episodes(dir: &Path) {
    write(
        dir,
        "first.rrd",
        "rec-b",
        vec![
            scalars(
                "/robot/arm",
                "angle",
                &[(1, 1, Some(vec![0.5])), (3, 2, Some(vec![1.5]))],
            ),
            scalars("/robot/leg", "angle", &[(2, 3, Some(vec![2.5]))]),
            static_scalar("/robot", "mass", 4, 70.0),
        ],
    );
    write(
        dir,
        "second.rrd",
        "rec-a",
        vec![
            scalars(
                "/robot/arm",
                "angle",
                &[(5, 10, Some(vec![9.0])), (2, 11, None)],
            ),
            scalars("/camera", "exposure", &[(4, 12, Some(vec![0.01]))]),
            clear("/robot", Some(6), 13, true),
        ],
    );
    write(
        dir,
        "static_only.rrd",
        "rec-s",
        vec![static_scalar("/robot", "mass", 20, 80.0)],
    );
    write_without_footer(
        dir,
        "cut.rrd",
        "rec-c",
        vec![scalars("/robot/arm", "angle", &[(7, 30, Some(vec![4.0]))])],
    );
    // Not segments: a subdirectory and a file of another kind.
    std::fs::create_dir_all(dir.join("nested")).unwrap();
    write(
        &dir.join("nested"),
        "deep.rrd",
        "rec-deep",
        vec![scalars("/x", "y", &[(1, 40, Some(vec![1.0]))])],
    );
    std::fs::write(dir.join("notes.txt"), "not a segment").unwrap();
}

fn store_of(path: &Path) -> ChunkStore {
    let options = chunkstore::recording::OpenOptions {
        lazy: false,
        ..Default::default()
    };
    chunkstore::recording::LoadedRecording::load(path, &options, &mut ())
        .unwrap()
        .store
}

/// Every batch of a table, as one.
fn read_all(table: impl arrow_array::RecordBatchReader) -> RecordBatch {
    let schema = table.schema();
    let batches: Vec<RecordBatch> = table.map(Result::unwrap).collect();
    concat_batches(&schema, &batches).unwrap()
}

/// The dataset's table is, segment by segment in id order, exactly that segment's own
/// dataframe: the same rows, each column's cells equal where the segment has the column
/// and null where it has not, its id in the first column.
#[test]
fn a_dataset_is_its_segments_dataframes_one_after_another() {
    let dir = ScratchDir::new("dataset-table");
    episodes(&dir);
    let dataset = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    let ids: Vec<&str> = dataset.segments().iter().map(|s| s.id.as_str()).collect();
    assert_eq!(
        ids,
        ["rec-a", "rec-b", "rec-c", "rec-s"],
        "sorted by recording id"
    );
    let cut = dataset.segment("rec-c").unwrap();
    assert!(!cut.from_footer && dataset.segment("rec-a").unwrap().from_footer);
    assert_eq!(cut.path, dir.join("cut.rrd"));
    assert!(dataset.segment("rec-s").unwrap().timelines.is_empty());
    assert_eq!(dataset.segment("rec-b").unwrap().num_rows, 4);

    for fill in [false, true] {
        let query = DataframeQuery::new("frame").with_fill_latest_at(fill);
        let stream = dataset.dataframe(&query).unwrap();
        assert_eq!(stream.num_segments(), 3, "rec-s has no data on frame");
        let schema = stream.schema();
        let names: Vec<&str> = schema.fields().iter().map(|f| f.name().as_str()).collect();
        assert_eq!(
            names,
            [
                SEGMENT_ID_COLUMN,
                "frame",
                "/camera:exposure",
                "/robot:Clear:is_recursive",
                "/robot:mass",
                "/robot/arm:angle",
                "/robot/leg:angle",
            ]
        );
        assert!(!schema.field(0).is_nullable());
        let table = read_all(stream);

        let mut at = 0;
        for (id, file) in [
            ("rec-a", "second.rrd"),
            ("rec-b", "first.rrd"),
            ("rec-c", "cut.rrd"),
        ] {
            let store = store_of(&dir.join(file));
            let own = read_all(store.dataframe(&query).unwrap());
            let rows = own.num_rows();
            assert!(rows > 0, "{id}");
            let part = table.slice(at, rows);
            let segment_ids = part
                .column(0)
                .as_any()
                .downcast_ref::<StringArray>()
                .unwrap();
            assert!(segment_ids.iter().all(|s| s == Some(id)), "{id}");
            for field in schema.fields().iter().skip(1) {
                let got = part.column_by_name(field.name()).unwrap();
                match own.column_by_name(field.name()) {
                    Some(expected) => assert_eq!(
                        got.to_data(),
                        expected.to_data(),
                        "{id} {} fill={fill}",
                        field.name()
                    ),
                    None => assert_eq!(got.null_count(), rows, "{id} {}", field.name()),
                }
            }
            at += rows;
        }
        assert_eq!(at, table.num_rows(), "no other rows");
    }
}

/// A projection keeps the segment id first and the table's order; a name the table lacks
/// is refused.
#[test]
fn a_dataset_projection_keeps_its_rows_and_names_what_is_missing() {
    let dir = ScratchDir::new("dataset-projection");
    episodes(&dir);
    let dataset = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    let full = dataset.dataframe(&DataframeQuery::new("frame")).unwrap();
    let full = read_all(full);
    let query = DataframeQuery::new("frame").with_columns(["/robot/leg:angle", "frame"]);
    let stream = dataset.dataframe(&query).unwrap();
    let schema = stream.schema();
    let names: Vec<&str> = schema.fields().iter().map(|f| f.name().as_str()).collect();
    assert_eq!(names, [SEGMENT_ID_COLUMN, "frame", "/robot/leg:angle"]);
    let projected = read_all(stream);
    assert_eq!(projected.num_rows(), full.num_rows());
    for name in names {
        assert_eq!(
            projected.column_by_name(name).unwrap().to_data(),
            full.column_by_name(name).unwrap().to_data(),
            "{name}"
        );
    }
    let error = dataset
        .dataframe(&DataframeQuery::new("frame").with_columns(["/nowhere:x"]))
        .unwrap_err();
    assert!(matches!(&error, DatasetError::UnknownColumn { name, .. } if name == "/nowhere:x"));
}

/// Bad datasets are errors naming what is wrong: no `.rrd` file, two files of one
/// recording, an index no segment has, a column of two types, a corrupt file (skipped
/// with a warning under `skip_bad`, the rest answering).
#[test]
fn bad_datasets_are_named_errors() {
    let dir = ScratchDir::new("dataset-bad");
    std::fs::write(dir.join("notes.txt"), "x").unwrap();
    let error = Dataset::open(&dir, &DatasetOptions::default()).unwrap_err();
    assert!(matches!(&error, DatasetError::NoRrdFiles { .. }), "{error}");
    assert!(error.to_string().contains("no .rrd file"), "{error}");

    let a = write(
        &dir,
        "a.rrd",
        "same",
        vec![scalars("/e", "x", &[(1, 1, Some(vec![1.0]))])],
    );
    let b = write(
        &dir,
        "b.rrd",
        "same",
        vec![scalars("/e", "x", &[(2, 2, Some(vec![2.0]))])],
    );
    let error = Dataset::open(&dir, &DatasetOptions::default()).unwrap_err();
    let text = error.to_string();
    assert!(
        matches!(&error, DatasetError::DuplicateRecording { id, .. } if id == "same"),
        "{error}"
    );
    assert!(text.contains(&*a.to_string_lossy()) && text.contains(&*b.to_string_lossy()));
    std::fs::remove_file(&b).unwrap();

    let dataset = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    let error = dataset.dataframe(&DataframeQuery::new("tick")).unwrap_err();
    assert!(
        matches!(&error, DatasetError::UnknownIndex(u) if u.name == "tick" && u.known == ["frame"]),
        "{error}"
    );

    // The same column as a list of booleans elsewhere.
    write(&dir, "c.rrd", "other", vec![clear("/e", Some(3), 3, false)]);
    let booleans = Chunk::try_new(
        ChunkId::new(),
        crate::common::path("/e"),
        vec![crate::common::rid(4)],
        vec![(
            Timeline::sequence("frame"),
            Arc::new(Int64Array::from(vec![4])) as ArrayRef,
        )],
        vec![("x".into(), crate::common::bool_list(&[Some(true)]))],
    )
    .unwrap();
    write(&dir, "d.rrd", "third", vec![booleans]);
    let dataset = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    let error = dataset
        .dataframe(&DataframeQuery::new("frame"))
        .unwrap_err();
    assert!(
        matches!(&error, DatasetError::ColumnTypeConflict { column, .. } if column == "/e:x"),
        "{error}"
    );
    std::fs::remove_file(dir.join("d.rrd")).unwrap();

    // A file cut inside its stream header, and one of garbage under the name.
    let bytes = std::fs::read(&a).unwrap();
    std::fs::write(dir.join("truncated.rrd"), &bytes[..5]).unwrap();
    let error = Dataset::open(&dir, &DatasetOptions::default()).unwrap_err();
    assert!(error.to_string().contains("truncated.rrd"), "{error}");
    let options = DatasetOptions {
        skip_bad: true,
        ..DatasetOptions::default()
    };
    let dataset = Dataset::open(&dir, &options).unwrap();
    let ids: Vec<&str> = dataset.segments().iter().map(|s| s.id.as_str()).collect();
    assert_eq!(ids, ["other", "same"]);
    let warnings = dataset.take_warnings();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(warnings[0].contains("truncated.rrd"), "{warnings:?}");
    let rows: usize = dataset
        .dataframe(&DataframeQuery::new("frame"))
        .unwrap()
        .map(|b| b.unwrap().num_rows())
        .sum();
    assert_eq!(rows, 2);

    // A file that vanishes once the dataset is open: the query names it.
    std::fs::remove_file(&a).unwrap();
    let dataset_options = DatasetOptions {
        memory_budget: 0,
        ..DatasetOptions::default()
    };
    let dir2 = ScratchDir::new("dataset-vanish");
    let kept = write(
        &dir2,
        "kept.rrd",
        "kept",
        vec![scalars("/e", "x", &[(1, 1, Some(vec![1.0]))])],
    );
    let gone = write(
        &dir2,
        "gone.rrd",
        "gone",
        vec![scalars("/e", "x", &[(1, 2, Some(vec![2.0]))])],
    );
    let dataset = Dataset::open(&dir2, &dataset_options).unwrap();
    std::fs::remove_file(&gone).unwrap();
    let error = dataset
        .dataframe(&DataframeQuery::new("frame"))
        .unwrap_err();
    assert!(error.to_string().contains("gone.rrd"), "{error}");
    assert!(kept.exists());
}

/// With a budget smaller than any segment, every use loads its segment again, and the
/// answers do not change.
#[test]
fn a_dataset_answers_alike_whatever_its_memory_budget() {
    let dir = ScratchDir::new("dataset-budget");
    episodes(&dir);
    let table = |budget| {
        let options = DatasetOptions {
            memory_budget: budget,
            threads: 1,
            ..DatasetOptions::default()
        };
        let dataset = Dataset::open(&dir, &options).unwrap();
        let stream = dataset.dataframe(&DataframeQuery::new("frame")).unwrap();
        read_all(stream)
    };
    assert_eq!(table(0), table(u64::MAX));
}

/// A segment opens as a recording for its own reads.
#[test]
fn a_segment_opens_as_a_recording() {
    let dir = ScratchDir::new("dataset-segment");
    episodes(&dir);
    let dataset = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    let mut recording = dataset.recording("rec-b").unwrap();
    let at = LatestAtQuery::new("frame", TimeInt::new(2).unwrap());
    let arm = chunkstore::EntityPath::parse("/robot/arm").unwrap();
    let cell = recording
        .reader()
        .latest_at(&at, &arm, "angle")
        .unwrap()
        .unwrap();
    assert!((crate::common::first_f64(&cell.cell()) - 0.5).abs() < 1e-12);
    let error = dataset.recording("rec-z").unwrap_err();
    assert!(
        matches!(&error, DatasetError::UnknownSegment { id, num_segments: 4 } if id == "rec-z"),
        "{error}"
    );
    assert_eq!(
        dataset
            .time_range("frame")
            .map(|r| (r.min().as_i64(), r.max().as_i64())),
        Some((1, 7))
    );
}
