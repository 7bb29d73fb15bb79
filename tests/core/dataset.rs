//! Datasets (`chunkstore::dataset`, SEMANTICS.md section 15): a directory of `.rrd` files
//! queried as one table, each file a segment named by its recording id; the table is each
//! segment's own dataframe, one after another in id order, in the union of their columns.

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a test fails loudly"
)]

use std::path::{Path, PathBuf};

use arrow_array::{Array, RecordBatch, StringArray};
use arrow_select::concat::concat_batches;
use chunkstore::SEGMENT_ID_COLUMN;
use chunkstore::dataset::{Dataset, DatasetError, DatasetOptions};
use chunkstore::{ChunkStore, DataframeQuery, LatestAtQuery, TimeInt};

use crate::common::{ScratchDir, clear, scalars, write_recording, write_without_footer};

/// Four recordings of different shapes: the three of `common::episodes` (entities and
/// components only some share, Clears, static data, one without the `frame` timeline's
/// data) and one without a footer.
fn episodes(dir: &Path) {
    crate::common::episodes(dir);
    write_without_footer(
        dir,
        "cut.rrd",
        "rec-c",
        vec![scalars("/robot/arm", "angle", &[(7, 30, Some(vec![4.0]))])],
    );
    // Not segments: a subdirectory and a file of another kind.
    std::fs::create_dir_all(dir.join("nested")).unwrap();
    write_recording(
        &dir.join("nested"),
        "deep.rrd",
        "rec-deep",
        vec![scalars("/x", "y", &[(1, 40, Some(vec![1.0]))])],
    );
    std::fs::write(dir.join("notes.txt"), "not a segment").unwrap();
}

fn store_of(path: &Path) -> ChunkStore {
    let options = chunkstore::recording::OpenOptions::default().with_lazy(false);
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
        let files = [
            ("rec-a", dir.join("second.rrd")),
            ("rec-b", dir.join("first.rrd")),
            ("rec-c", dir.join("cut.rrd")),
        ];
        assert_eq!(equals_own_tables(&table, &files, &query), 3);
    }
}

/// Checks that `table` is, segment after segment, each file's own dataframe of `query`
/// (the segment's columns equal, the others null); returns how many segments gave rows.
fn equals_own_tables(
    table: &RecordBatch,
    files: &[(&str, PathBuf)],
    query: &DataframeQuery,
) -> usize {
    let schema = table.schema();
    let mut at = 0;
    let mut with_rows = 0;
    for (id, file) in files {
        let store = store_of(file);
        let Ok(stream) = store.dataframe(query) else {
            continue; // no data on the index: no rows
        };
        let own = read_all(stream);
        let rows = own.num_rows();
        with_rows += usize::from(rows > 0);
        let part = table.slice(at, rows);
        let segment_ids = part
            .column(0)
            .as_any()
            .downcast_ref::<StringArray>()
            .unwrap();
        assert!(segment_ids.iter().all(|s| s == Some(*id)), "{id}");
        for field in own.schema().fields() {
            assert!(
                schema.field_with_name(field.name()).is_ok(),
                "{id} {}",
                field.name()
            );
        }
        for field in schema.fields().iter().skip(1) {
            let got = part.column_by_name(field.name()).unwrap();
            match own.column_by_name(field.name()) {
                Some(expected) => assert_eq!(
                    got.to_data(),
                    expected.to_data(),
                    "{id} {} {query:?}",
                    field.name()
                ),
                None => assert_eq!(got.null_count(), rows, "{id} {}", field.name()),
            }
        }
        at += rows;
    }
    assert_eq!(at, table.num_rows(), "no other rows");
    with_rows
}

/// A query over a range or some entities decodes, through each footer, only the chunks it
/// needs, and answers exactly as each whole segment would: with and without fill, ranges
/// before, inside, across and after the data.
#[test]
fn a_dataset_query_reads_only_what_it_needs_and_answers_alike() {
    let dir = ScratchDir::new("dataset-pruned");
    episodes(&dir);
    // Where a filled cell comes from a chunk before the range that is not its column's
    // first: `/a` in three chunks, `/b`'s rows later.
    write_recording(
        &dir,
        "fill.rrd",
        "rec-f",
        vec![
            scalars(
                "/a",
                "x",
                &[(0, 50, Some(vec![0.0])), (1, 51, Some(vec![1.0]))],
            ),
            scalars(
                "/a",
                "x",
                &[(2, 52, Some(vec![2.0])), (3, 53, Some(vec![3.0]))],
            ),
            scalars(
                "/a",
                "x",
                &[(4, 54, Some(vec![4.0])), (5, 55, Some(vec![5.0]))],
            ),
            scalars(
                "/b",
                "y",
                &[(8, 56, Some(vec![8.0])), (9, 57, Some(vec![9.0]))],
            ),
        ],
    );
    let files = [
        ("rec-a", dir.join("second.rrd")),
        ("rec-b", dir.join("first.rrd")),
        ("rec-c", dir.join("cut.rrd")),
        ("rec-f", dir.join("fill.rrd")),
    ];
    let range = |lo: i64, hi: i64| {
        chunkstore::TimeRange::new(TimeInt::new(lo).unwrap(), TimeInt::new(hi).unwrap())
    };
    for (lo, hi) in [
        (-5, 0),
        (2, 2),
        (2, 4),
        (3, 6),
        (6, 6),
        (7, 7),
        (8, 9),
        (8, 100),
    ] {
        for fill in [false, true] {
            for contents in [None, Some("/robot/**"), Some("/camera")] {
                let mut query = DataframeQuery::new("frame")
                    .with_range(range(lo, hi))
                    .with_fill_latest_at(fill);
                if let Some(contents) = contents {
                    query = query
                        .with_contents(chunkstore::EntityPathFilter::parse([contents]).unwrap());
                }
                for memory_budget in [0, DatasetOptions::default().memory_budget] {
                    let options = DatasetOptions::default().with_memory_budget(memory_budget);
                    let dataset = Dataset::open(&dir, &options).unwrap();
                    let table = read_all(dataset.dataframe(&query).unwrap());
                    equals_own_tables(&table, &files, &query);
                }
            }
        }
    }

    // The robot recording Rerun's SDK wrote, as a dataset of one: a tenth of its frames
    // decodes a fraction of its chunks, and answers as the whole recording.
    let robot = crate::common::robot_recording().join("a_robot.rrd");
    let robot_files = [("a0000000-0000-4000-8000-00000000000a", robot.clone())];
    for fill in [false, true] {
        let query = DataframeQuery::new("frame_id")
            .with_range(range(20, 25))
            .with_fill_latest_at(fill);
        let dataset = Dataset::open(&robot, &DatasetOptions::default()).unwrap();
        let table = read_all(dataset.dataframe(&query).unwrap());
        assert_eq!(equals_own_tables(&table, &robot_files, &query), 1);
        let read = dataset.read_stats();
        let total = dataset.segments()[0].num_chunks;
        assert!(read.chunks_decoded < total, "{read:?} of {total}");
        assert!(
            read.bytes_read < dataset.segments()[0].file_bytes,
            "{read:?}"
        );
    }
}

/// Segments of one shape (by their footers) after the first thread's are not read to plan
/// the table: each segment of a range query is read once, for the chunk its rows need,
/// and the table is each segment's own.
#[test]
fn segments_of_one_shape_are_read_once_each() {
    let dir = ScratchDir::new("dataset-one-shape");
    let mut files = Vec::new();
    let ids: Vec<String> = (0..5).map(|n| format!("run-{n}")).collect();
    for (n, id) in (0..5u8).zip(&ids) {
        let early = scalars("/e", "x", &[(1, 1, Some(vec![f64::from(n)]))]);
        let late = scalars("/e", "x", &[(10, 2, Some(vec![10.0 + f64::from(n)]))]);
        let file = write_recording(&dir, &format!("{id}.rrd"), id, vec![early, late]);
        files.push((id.as_str(), file));
    }
    let one_thread = DatasetOptions::default().with_threads(1);
    let dataset = Dataset::open(&dir, &one_thread).unwrap();
    let late = chunkstore::TimeRange::new(TimeInt::new(10).unwrap(), TimeInt::new(10).unwrap());
    let query = DataframeQuery::new("frame").with_range(late);
    let table = read_all(dataset.dataframe(&query).unwrap());
    assert_eq!(equals_own_tables(&table, &files, &query), 5);
    let read = dataset.read_stats();
    // The first segment's planning read is kept for its rows; the others are read for
    // their rows alone: one chunk each.
    assert_eq!(read.segment_reads, 5, "{read:?}");
    assert!(read.chunks_decoded <= 6, "{read:?}");

    // A segment of that shape whose column has another type is not read to plan the
    // table either: the conflict is the error of the rows' pass when it reaches it,
    // naming the column and the segment.
    let booleans = crate::common::boolean("/e", "x", 10, 3, true);
    write_recording(&dir, "run-9.rrd", "run-9", vec![booleans]);
    let dataset = Dataset::open(&dir, &one_thread).unwrap();
    let rows: Result<Vec<_>, _> = dataset.dataframe(&query).unwrap().collect();
    let error = rows.unwrap_err().to_string();
    assert!(
        error.contains("\"/e:x\"") && error.contains("\"run-9\""),
        "{error}"
    );
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

    let a = write_recording(
        &dir,
        "a.rrd",
        "same",
        vec![scalars("/e", "x", &[(1, 1, Some(vec![1.0]))])],
    );
    let b = write_recording(
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
    write_recording(&dir, "c.rrd", "other", vec![clear("/e", Some(3), 3, false)]);
    let booleans = crate::common::boolean("/e", "x", 4, 4, true);
    write_recording(&dir, "d.rrd", "third", vec![booleans]);
    // Each segment read to plan the table (as many threads as segments, each keeping its
    // read for the rows): the conflict is planning's error.
    let dataset = Dataset::open(&dir, &DatasetOptions::default().with_threads(8)).unwrap();
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
    let options = DatasetOptions::default().with_skip_bad(true);
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
    let dataset_options = DatasetOptions::default().with_memory_budget(0);
    let dir2 = ScratchDir::new("dataset-vanish");
    let kept = write_recording(
        &dir2,
        "kept.rrd",
        "kept",
        vec![scalars("/e", "x", &[(1, 1, Some(vec![1.0]))])],
    );
    let gone = write_recording(
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
        let options = DatasetOptions::default()
            .with_memory_budget(budget)
            .with_threads(1);
        let dataset = Dataset::open(&dir, &options).unwrap();
        let stream = dataset.dataframe(&DataframeQuery::new("frame")).unwrap();
        read_all(stream)
    };
    assert_eq!(table(0), table(u64::MAX));
}

/// Segments are planned on the dataset's threads and loaded ahead of the reader on them,
/// and read in order: on 1, 2 and 5 threads, with planning's reads kept or not, the table
/// is the same, and a stream dropped before its end leaves the next one whole.
#[test]
fn a_dataset_streams_alike_on_any_number_of_threads() {
    let dir = ScratchDir::new("dataset-threads");
    episodes(&dir);
    for n in 0..6 {
        let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..40u8)
            .map(|t| {
                (
                    i64::from(t),
                    100 + u128::from(t),
                    Some(vec![f64::from(n) * 100.0 + f64::from(t)]),
                )
            })
            .collect();
        write_recording(
            &dir,
            &format!("more-{n}.rrd"),
            &format!("rec-m{n}"),
            vec![scalars("/robot/arm", "angle", &rows)],
        );
    }
    let table = |threads, budget| {
        let options = DatasetOptions::default()
            .with_memory_budget(budget)
            .with_threads(threads);
        let dataset = Dataset::open(&dir, &options).unwrap();
        let query = DataframeQuery::new("frame").with_fill_latest_at(true);
        let mut early = dataset.dataframe(&query).unwrap();
        assert!(early.next().unwrap().unwrap().num_rows() > 0);
        drop(early);
        let mut stream = dataset.dataframe(&query).unwrap();
        assert_eq!(stream.num_segments(), 9);
        let schema = stream.schema();
        let batches: Vec<RecordBatch> = stream.by_ref().map(Result::unwrap).collect();
        // What planning read is kept for the rows only for the segments they start with,
        // one per thread, however large the budget: the others are read as they stream
        // (but for the footerless one, which the cache keeps whole if it may).
        let streamed_from_files = dataset
            .segments()
            .iter()
            .filter(|segment| segment.time_type("frame").is_some())
            .skip(if budget == 0 { 0 } else { threads })
            .filter(|segment| budget == 0 || segment.from_footer)
            .count();
        assert_eq!(
            stream.read_stats().segment_reads,
            streamed_from_files as u64,
            "{threads} threads, budget {budget}"
        );
        let read = concat_batches(&schema, &batches).unwrap();
        (read, dataset.take_warnings())
    };
    let (one, warnings) = table(1, u64::MAX);
    // The one warning: the fixture's subdirectory, named and not read.
    assert!(
        warnings.len() == 1 && warnings[0].contains("1 subdirectories hold .rrd files"),
        "{warnings:?}"
    );
    assert!(one.num_rows() > 6 * 40, "{one:?}");
    for threads in [1, 2, 5] {
        for budget in [0, u64::MAX] {
            assert_eq!(
                table(threads, budget),
                (one.clone(), warnings.clone()),
                "{threads} threads, budget {budget}"
            );
        }
    }
}

/// A segment that vanishes once its dataframe is planned (with no budget, planning keeps
/// nothing) is named where its rows would be, the segments before it answered; with
/// `skip_bad` it is skipped with one warning and the rest answers; on one thread or
/// several.
#[test]
fn a_segment_that_vanishes_while_streaming_is_named_or_skipped() {
    for threads in [1, 2, 4] {
        for skip_bad in [false, true] {
            let dir = ScratchDir::new("dataset-vanish-streaming");
            let mut files = Vec::new();
            for n in 0..4u8 {
                files.push(write_recording(
                    &dir,
                    &format!("s{n}.rrd"),
                    &format!("rec-{n}"),
                    vec![scalars(
                        "/e",
                        "x",
                        &[(i64::from(n), u128::from(n), Some(vec![f64::from(n)]))],
                    )],
                ));
            }
            let options = DatasetOptions::default()
                .with_memory_budget(0)
                .with_threads(threads)
                .with_skip_bad(skip_bad);
            let dataset = Dataset::open(&dir, &options).unwrap();
            let stream = dataset.dataframe(&DataframeQuery::new("frame")).unwrap();
            std::fs::remove_file(&files[2]).unwrap();
            let results: Vec<_> = stream.collect();
            let context = format!("{threads} threads, skip_bad {skip_bad}");
            let rows = |results: &[Result<RecordBatch, _>]| -> Vec<String> {
                results
                    .iter()
                    .filter_map(|r| r.as_ref().ok())
                    .flat_map(|b| {
                        let ids = b.column(0).as_any().downcast_ref::<StringArray>().unwrap();
                        (0..b.num_rows())
                            .map(|i| ids.value(i).to_owned())
                            .collect::<Vec<_>>()
                    })
                    .collect()
            };
            assert_eq!(rows(&results), ["rec-0", "rec-1", "rec-3"], "{context}");
            let errors: Vec<String> = results
                .iter()
                .filter_map(|r| r.as_ref().err().map(ToString::to_string))
                .collect();
            let warnings = dataset.take_warnings();
            if skip_bad {
                assert!(errors.is_empty(), "{context}: {errors:?}");
                assert_eq!(warnings.len(), 1, "{context}: {warnings:?}");
                assert!(
                    warnings[0].contains("rec-2") && warnings[0].contains("s2.rrd"),
                    "{warnings:?}"
                );
            } else {
                assert_eq!(errors.len(), 1, "{context}: {errors:?}");
                assert!(errors[0].contains("s2.rrd"), "{context}: {errors:?}");
                assert!(warnings.is_empty(), "{context}: {warnings:?}");
                let at = results.iter().position(Result::is_err).unwrap();
                assert_eq!(
                    rows(&results[..at]),
                    ["rec-0", "rec-1"],
                    "{context}: in order"
                );
            }
        }
    }
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

mod pruning_model {
    use std::sync::atomic::{AtomicUsize, Ordering};

    use proptest::prelude::*;

    use super::{equals_own_tables, read_all};
    use crate::common::{
        ScratchDir, clear, scalars, static_scalar, write_recording, write_without_footer,
    };
    use chunkstore::dataset::{Dataset, DatasetOptions};
    use chunkstore::{DataframeQuery, EntityPathFilter, TimeInt, TimeRange};

    const ENTITIES: [&str; 3] = ["/e", "/e/child", "/f"];
    const COMPONENTS: [&str; 2] = ["x", "y"];

    static CASE: AtomicUsize = AtomicUsize::new(0);

    proptest! {
        #![proptest_config(ProptestConfig { cases: 256, failure_persistence: crate::common::seed_file("core/dataset.txt"), ..ProptestConfig::default() })]

        /// A segment read through its footer for a query (only the chunks it needs) answers
        /// as the whole segment does, whatever the chunks (any order, nulls, static data,
        /// Clears flat and recursive), the range, the fill and the contents.
        #[test]
        fn a_pruned_segment_answers_as_the_whole_one(
            // Chunks: entity, component, its rows' times (the first row's cell null if asked).
            specs in prop::collection::vec(
                (0..3usize, 0..2usize, prop::collection::vec(0i32..30, 1..4), any::<bool>()),
                1..10,
            ),
            clears in prop::collection::vec((0..3usize, 0i64..30, any::<bool>()), 0..3),
            statics in prop::collection::vec((0..3usize, 0..2usize), 0..2),
            lo in -2i64..30,
            len in 0i64..12,
            fill in any::<bool>(),
            contents in 0..3usize,
        ) {
            let case = CASE.fetch_add(1, Ordering::Relaxed);
            let dir = ScratchDir::new(&format!("dataset-model-{case}"));
            // The chunks, built alike for each file (a chunk is not `Clone`).
            let build = || {
                let mut row = 1000u128;
                let mut next_row = || {
                    row += 1;
                    row
                };
                let mut chunks = Vec::new();
                for (entity, component, times, null_first) in &specs {
                    let rows: Vec<(i64, u128, Option<Vec<f64>>)> = times
                        .iter()
                        .enumerate()
                        .map(|(i, &t)| {
                            let cell = (i > 0 || !null_first).then(|| vec![f64::from(t)]);
                            (i64::from(t), next_row(), cell)
                        })
                        .collect();
                    chunks.push(scalars(ENTITIES[*entity], COMPONENTS[*component], &rows));
                }
                for &(entity, time, recursive) in &clears {
                    chunks.push(clear(ENTITIES[entity], Some(time), next_row(), recursive));
                }
                for &(entity, component) in &statics {
                    chunks.push(static_scalar(ENTITIES[entity], COMPONENTS[component], next_row(), -1.0));
                }
                chunks
            };
            // The same chunks without a footer, read through an index cache.
            let cut_dir = dir.join("cut");
            std::fs::create_dir(&cut_dir).unwrap();
            let cut = write_without_footer(&cut_dir, "segment.rrd", "model", build());
            let file = write_recording(&dir, "segment.rrd", "model", build());
            let mut query = DataframeQuery::new("frame")
                .with_range(TimeRange::new(
                    TimeInt::new(lo).unwrap(),
                    TimeInt::new(lo + len).unwrap(),
                ))
                .with_fill_latest_at(fill);
            if let Some(rule) = [None, Some("/e/**"), Some("/f")][contents] {
                query = query.with_contents(EntityPathFilter::parse([rule]).unwrap());
            }
            // A budget of nothing: planning reads the columns' chunks alone, the rows'
            // pass the rest.
            for memory_budget in [0, DatasetOptions::default().memory_budget] {
                let options = DatasetOptions::default().with_memory_budget(memory_budget);
                let dataset = Dataset::open(&file, &options).unwrap();
                let table = read_all(dataset.dataframe(&query).unwrap());
                equals_own_tables(&table, &[("model", file.clone())], &query);
            }
            // Scanned into the cache on the first open, read through it on the second;
            // with no budget, neither keeps the segment, so both read it in part.
            for _ in 0..2 {
                let options = DatasetOptions::default().with_memory_budget(0).with_index_cache(dir.join("index"));
                let dataset = Dataset::open(&cut, &options).unwrap();
                prop_assert!(dataset.segments()[0].index_file.is_some());
                let table = read_all(dataset.dataframe(&query).unwrap());
                equals_own_tables(&table, &[("model", file.clone())], &query);
            }
        }
    }
}

/// Issue 36: with an index cache, a file without a footer is scanned once and its index
/// kept in the cache directory (nothing is written beside the data); the next open reads
/// the index instead of the file, a range reads the file in part through it, and every
/// answer is the one without the cache. A file that changes is scanned again.
#[test]
#[allow(
    clippy::too_many_lines,
    reason = "one file's life in the cache, step by step"
)]
fn a_footerless_segment_is_indexed_once_in_the_index_cache() {
    let dir = ScratchDir::new("dataset-index-cache");
    let data = dir.join("data");
    std::fs::create_dir(&data).unwrap();
    let cut = write_without_footer(
        &data,
        "cut.rrd",
        "rec-c",
        vec![
            scalars("/robot/arm", "angle", &[(1, 1, Some(vec![1.0]))]),
            scalars("/robot/arm", "angle", &[(2, 6, Some(vec![1.0]))]),
            scalars("/robot/arm", "angle", &[(3, 7, Some(vec![1.0]))]),
            scalars("/robot/arm", "angle", &[(4, 8, Some(vec![1.0]))]),
            scalars("/robot/arm", "angle", &[(50, 2, Some(vec![2.0]))]),
            scalars("/robot/leg", "angle", &[(60, 3, Some(vec![3.0]))]),
            crate::common::static_scalar("/robot", "mass", 4, 70.0),
        ],
    );
    write_recording(
        &data,
        "full.rrd",
        "rec-f",
        vec![scalars("/robot/arm", "angle", &[(5, 10, Some(vec![9.0]))])],
    );
    let listing = |dir: &Path| {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .map(|entries| {
                entries
                    .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                    .collect()
            })
            .unwrap_or_default();
        names.sort();
        names
    };
    let before = listing(&data);
    let cache = dir.join("cache");
    // Every chunk as written, so that counts of chunks read mean what they say.
    let options = DatasetOptions::default()
        .with_index_cache(cache.clone())
        .with_config(chunkstore::StoreConfig::COMPACTION_OFF);
    let plain = Dataset::open(&data, &DatasetOptions::default()).unwrap();
    assert!(plain.segment("rec-c").unwrap().index_file.is_none());
    let range = chunkstore::TimeRange::new(TimeInt::new(40).unwrap(), TimeInt::new(55).unwrap());
    let queries = [
        DataframeQuery::new("frame"),
        DataframeQuery::new("frame").with_range(range),
        DataframeQuery::new("frame")
            .with_range(range)
            .with_fill_latest_at(true),
    ];

    let scanned = Dataset::open(&data, &options).unwrap();
    let segment = scanned.segment("rec-c").unwrap();
    assert!(!segment.from_footer);
    let index = segment.index_file.clone().expect("indexed");
    assert!(index.starts_with(&cache), "{}", index.display());
    assert_eq!(listing(&cache).len(), 1, "{:?}", listing(&cache));
    assert!(listing(&cache)[0].ends_with(".rrd-index"));
    assert_eq!(listing(&data), before, "nothing is written beside the data");
    assert!(scanned.segment("rec-f").unwrap().index_file.is_none());

    // The next open reads the index: the same segment, and every answer alike; a range
    // decodes only the chunks it needs.
    let indexed = Dataset::open(&data, &options).unwrap();
    let again = indexed.segment("rec-c").unwrap();
    assert_eq!(again.index_file.as_ref(), Some(&index));
    assert_eq!(
        (
            &again.entities,
            &again.timelines,
            again.num_rows,
            again.num_chunks
        ),
        (
            &segment.entities,
            &segment.timelines,
            segment.num_rows,
            segment.num_chunks
        )
    );
    assert_eq!(listing(&cache).len(), 1);
    for query in &queries {
        let expected = read_all(plain.dataframe(query).unwrap());
        for dataset in [&scanned, &indexed] {
            let table = read_all(dataset.dataframe(query).unwrap());
            assert_eq!(table.schema(), expected.schema(), "{query:?}");
            crate::common::assert_same_cells(&table, &expected, &format!("{query:?}"));
        }
    }
    let fresh = Dataset::open(&data, &options).unwrap();
    let read_before = fresh.read_stats();
    let _ = read_all(fresh.dataframe(&queries[1]).unwrap());
    let read = fresh.read_stats();
    // Of rec-c's seven chunks, at most the one at frame 50 (rows), the static one, and one
    // of each (entity, component, timeline) for the columns; and rec-f's one chunk.
    let decoded = read.chunks_decoded - read_before.chunks_decoded;
    assert!(decoded <= 5, "{read:?}");
    assert!(read.bytes_read - read_before.bytes_read < std::fs::metadata(&cut).unwrap().len() * 2);

    // A file that changes (here, rewritten with other chunks) is scanned again, into a
    // new index.
    write_without_footer(
        &data,
        "cut.rrd",
        "rec-c",
        vec![
            scalars("/robot/arm", "angle", &[(1, 1, Some(vec![1.0]))]),
            scalars("/robot/arm", "angle", &[(70, 5, Some(vec![5.0]))]),
        ],
    );
    let changed = Dataset::open(&data, &options).unwrap();
    let segment = changed.segment("rec-c").unwrap();
    assert_ne!(segment.index_file.as_ref(), Some(&index));
    assert_eq!(listing(&cache).len(), 2);
    assert_eq!(
        segment.time_range("frame").map(|r| r.max().as_i64()),
        Some(70)
    );
    let rows = read_all(changed.dataframe(&queries[0]).unwrap()).num_rows();
    let plain_rows = read_all(
        Dataset::open(&data, &DatasetOptions::default())
            .unwrap()
            .dataframe(&queries[0])
            .unwrap(),
    )
    .num_rows();
    assert_eq!(rows, plain_rows);

    // An index that does not read (here, cut short) is written again by a new scan.
    let current = segment.index_file.clone().unwrap();
    let whole = std::fs::read(&current).unwrap();
    std::fs::write(&current, &whole[..whole.len() / 2]).unwrap();
    let rescanned = Dataset::open(&data, &options).unwrap();
    assert_eq!(
        rescanned.segment("rec-c").unwrap().index_file.as_ref(),
        Some(&current)
    );
    assert_eq!(std::fs::read(&current).unwrap().len(), whole.len());
    assert_eq!(
        read_all(rescanned.dataframe(&queries[0]).unwrap()).num_rows(),
        plain_rows
    );
}

/// A second file of a recording is skipped with a warning under `skip_bad`; a link to a
/// file of the dataset is the same file, read once; subdirectories holding `.rrd` files
/// are named, not read.
#[test]
fn duplicates_links_and_subdirectories_are_said_and_skipped() {
    let dir = ScratchDir::new("dataset-duplicates");
    write_recording(
        &dir,
        "a.rrd",
        "same",
        vec![scalars("/e", "x", &[(1, 1, Some(vec![1.0]))])],
    );
    write_recording(
        &dir,
        "b.rrd",
        "same",
        vec![scalars("/e", "x", &[(2, 2, Some(vec![2.0]))])],
    );
    let skip = DatasetOptions::default().with_skip_bad(true);
    let dataset = Dataset::open(&dir, &skip).unwrap();
    assert_eq!(dataset.segments().len(), 1);
    let warnings = dataset.take_warnings();
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("b.rrd") && w.contains("a.rrd")),
        "{warnings:?}"
    );
    std::fs::remove_file(dir.join("b.rrd")).unwrap();

    std::os::unix::fs::symlink(dir.join("a.rrd"), dir.join("c.rrd")).unwrap();
    std::fs::create_dir(dir.join("more")).unwrap();
    write_recording(
        &dir.join("more"),
        "d.rrd",
        "deeper",
        vec![scalars("/e", "x", &[(3, 3, Some(vec![3.0]))])],
    );
    let dataset = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    assert_eq!(dataset.segments().len(), 1);
    let warnings = dataset.take_warnings();
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("c.rrd") && w.contains("the same file")),
        "{warnings:?}"
    );
    assert!(
        warnings.iter().any(|w| w.contains("1 subdirectories")),
        "{warnings:?}"
    );
}
