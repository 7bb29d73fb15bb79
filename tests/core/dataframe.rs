//! Dataframe views (SEMANTICS.md section 9), rule by rule, on small stores whose tables
//! are written out by hand.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::cast_sign_loss,
    clippy::cast_precision_loss,
    reason = "tests fail loudly on unexpected values; test values are small non-negative integers"
)]

use crate::common;

use std::sync::Arc;

use arrow_array::cast::AsArray;
use arrow_array::types::Float64Type;
use arrow_array::{Array, ArrayRef, Int64Array, RecordBatch};
use chunkstore::{
    Chunk, ChunkId, ChunkStore, DataframeError, DataframeQuery, EntityPathFilter, StoreConfig,
    TimeRange, Timeline,
};
use common::{clear, f64_list, path, rid, scalar, scalars, static_scalar, t};

/// A table as text: one line per row, `index | cell | cell ...` with cells as `null`,
/// `[]`, `[1]`, `[1,2]` (floats as integers) or `[true]` for Clears.
fn render(store: &ChunkStore, query: &DataframeQuery) -> (Vec<String>, Vec<String>) {
    let stream = store.dataframe(query).unwrap();
    let schema = stream.schema();
    let names = schema.fields().iter().map(|f| f.name().clone()).collect();
    let index = schema.index_of(query.index()).unwrap();
    let data_start = schema
        .fields()
        .iter()
        .position(|f| f.name().contains(':'))
        .unwrap_or(schema.fields().len());
    let mut lines = Vec::new();
    for batch in stream {
        let batch = batch.unwrap();
        if let Some(rows) = query.batch_rows() {
            assert!(batch.num_rows() <= rows);
        }
        let index = batch
            .column(index)
            .as_primitive::<arrow_array::types::Int64Type>();
        for row in 0..batch.num_rows() {
            let mut line = index.value(row).to_string();
            for column in &batch.columns()[data_start..] {
                line.push_str(" | ");
                line.push_str(&cell_text(column, row));
            }
            lines.push(line);
        }
    }
    (names, lines)
}

fn cell_text(column: &ArrayRef, row: usize) -> String {
    let list = column.as_list::<i32>();
    if list.is_null(row) {
        return "null".to_owned();
    }
    let cell = list.value(row);
    let items: Vec<String> = if let Some(floats) = cell.as_primitive_opt::<Float64Type>() {
        floats.values().iter().map(|v| format!("{v}")).collect()
    } else {
        cell.as_boolean()
            .iter()
            .map(|b| b.unwrap().to_string())
            .collect()
    };
    format!("[{}]", items.join(","))
}

fn store_of(chunks: impl IntoIterator<Item = Chunk>) -> ChunkStore {
    let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).unwrap();
    for chunk in chunks {
        store.insert(chunk).unwrap();
    }
    store
}

fn frame() -> DataframeQuery {
    DataframeQuery::new("frame")
}

fn lines(rows: &[&str]) -> Vec<String> {
    rows.iter().map(|r| (*r).to_owned()).collect()
}

#[test]
fn columns_are_ordered_by_path_parts_then_component() {
    let store = store_of([
        scalar("/tree/a", "y", 1, 1, 1.0),
        scalar("/tree", "z", 1, 2, 2.0),
        scalar("/tree", "b", 1, 3, 3.0),
        scalar("/tree-b", "x", 1, 4, 4.0),
        scalar("/tree/a/deep", "x", 1, 5, 5.0),
    ]);
    let (names, rows) = render(&store, &frame());
    // `/tree` and its subtree come before `/tree-b`: parts compare one by one.
    assert_eq!(
        names,
        [
            "frame",
            "/tree:b",
            "/tree:z",
            "/tree/a:y",
            "/tree/a/deep:x",
            "/tree-b:x"
        ]
    );
    assert_eq!(rows, lines(&["1 | [3] | [2] | [1] | [5] | [4]"]));
}

#[test]
fn sparse_rows_keep_the_greatest_row_id_per_time_whatever_the_order() {
    // Out of order across and inside chunks, two rows at time 2 (row ids 7 and 9).
    let store = store_of([
        scalars(
            "/a",
            "x",
            &[
                (3, 5, Some(vec![30.0])),
                (2, 9, Some(vec![29.0])),
                (1, 4, Some(vec![10.0])),
            ],
        ),
        scalars("/a", "x", &[(2, 7, Some(vec![20.0])), (5, 8, None)]),
        scalar("/b", "x", 4, 6, 40.0),
    ]);
    let (names, rows) = render(&store, &frame());
    assert_eq!(names, ["frame", "/a:x", "/b:x"]);
    // Time 5 holds only a null cell: no row.
    assert_eq!(
        rows,
        lines(&[
            "1 | [10] | null",
            "2 | [29] | null",
            "3 | [30] | null",
            "4 | null | [40]"
        ])
    );
}

#[test]
fn fill_latest_at_fills_nulls_from_before_the_range_too() {
    let store = store_of([
        scalar("/a", "x", 1, 1, 1.0),
        scalar("/b", "x", 2, 2, 2.0),
        scalar("/a", "x", 3, 3, 3.0),
        scalar("/b", "x", 5, 4, 5.0),
    ]);
    let query = frame().with_fill_latest_at(true);
    assert_eq!(
        render(&store, &query).1,
        lines(&[
            "1 | [1] | null",
            "2 | [1] | [2]",
            "3 | [3] | [2]",
            "5 | [3] | [5]"
        ])
    );
    let query = query.with_range(TimeRange::new(t(3), t(10)));
    assert_eq!(
        render(&store, &query).1,
        lines(&["3 | [3] | [2]", "5 | [3] | [5]"])
    );
}

#[test]
fn ranges_are_inclusive_and_an_empty_one_has_no_rows() {
    let store = store_of([scalars(
        "/a",
        "x",
        &[
            (1, 1, Some(vec![1.0])),
            (2, 2, Some(vec![2.0])),
            (3, 3, Some(vec![3.0])),
        ],
    )]);
    let range = |lo, hi| render(&store, &frame().with_range(TimeRange::new(t(lo), t(hi)))).1;
    assert_eq!(range(2, 3), lines(&["2 | [2]", "3 | [3]"]));
    assert_eq!(range(2, 2), lines(&["2 | [2]"]));
    assert!(range(3, 2).is_empty(), "min > max: an empty range");
    assert!(range(10, 20).is_empty());
    // The schema is there even without rows.
    assert_eq!(
        render(&store, &frame().with_range(TimeRange::new(t(10), t(20)))).0,
        ["frame", "/a:x"]
    );
}

#[test]
fn static_data_shows_on_every_row_and_adds_none() {
    let store = store_of([
        scalar("/a", "x", 1, 1, 1.0),
        scalar("/a", "x", 3, 3, 3.0),
        static_scalar("/s", "x", 2, 7.0),
        static_scalar("/s", "x", 5, 8.0), // the later static write wins
        scalar("/s", "x", 2, 9, 99.0),    // shadowed by static data: no row of its own
    ]);
    let (names, rows) = render(&store, &frame());
    assert_eq!(names, ["frame", "/a:x", "/s:x"]);
    assert_eq!(rows, lines(&["1 | [1] | [8]", "3 | [3] | [8]"]));
    let stream = store.dataframe(&frame()).unwrap();
    let schema = stream.schema();
    let field = schema.field_with_name("/s:x").unwrap();
    assert_eq!(
        field.metadata().get("rerun:is_static").map(String::as_str),
        Some("true")
    );
    assert_eq!(
        field
            .metadata()
            .get("rerun:entity_path")
            .map(String::as_str),
        Some("/s")
    );
    assert_eq!(
        field.metadata().get("rerun:component").map(String::as_str),
        Some("x")
    );
    assert!(
        schema
            .field_with_name("/a:x")
            .unwrap()
            .metadata()
            .get("rerun:is_static")
            .is_none()
    );
}

#[test]
fn sampling_gives_one_row_per_value_before_between_and_after() {
    let store = store_of([
        scalar("/a", "x", 10, 1, 1.0),
        scalar("/a", "x", 20, 2, 2.0),
        static_scalar("/s", "y", 3, 5.0),
    ]);
    for fill in [false, true] {
        let query = frame()
            .with_index_values([t(5), t(10), t(15), t(25), t(15), t(-3)])
            .with_fill_latest_at(fill)
            .with_range(TimeRange::new(t(11), t(12))); // sampling ignores the range
        assert_eq!(
            render(&store, &query).1,
            lines(&[
                "5 | null | [5]",
                "10 | [1] | [5]",
                "15 | [1] | [5]",
                "25 | [2] | [5]",
                "15 | [1] | [5]",
                "-3 | null | [5]",
            ])
        );
    }
    assert!(render(&store, &frame().with_index_values([])).1.is_empty());
}

#[test]
fn a_component_on_one_timeline_only_is_null_on_the_other() {
    let two_timelines = Chunk::try_new(
        ChunkId::new(),
        path("/a"),
        vec![rid(1), rid(2)],
        vec![
            (
                Timeline::sequence("frame"),
                Arc::new(Int64Array::from(vec![1, 2])) as ArrayRef,
            ),
            (
                Timeline::sequence("other"),
                Arc::new(Int64Array::from(vec![100, 200])) as ArrayRef,
            ),
        ],
        vec![("x".into(), f64_list(&[Some(vec![1.0]), Some(vec![2.0])]))],
    )
    .unwrap();
    let frame_only = scalar("/b", "y", 2, 3, 9.0);
    let store = store_of([two_timelines, frame_only]);
    let (names, rows) = render(&store, &DataframeQuery::new("other"));
    // `/b:y` has data (on `frame` only): a column, never a row of its own on `other`.
    assert_eq!(names, ["frame", "other", "/a:x", "/b:y"]);
    assert_eq!(rows, lines(&["100 | [1] | null", "200 | [2] | null"]));
    // The other index column shows the rows' own times there.
    let batch = one_batch(&store, &DataframeQuery::new("other"));
    let frame_values = batch
        .column(0)
        .as_primitive::<arrow_array::types::Int64Type>();
    assert_eq!(frame_values.values().to_vec(), [1, 2]);
    // On `frame`, `/b:y` has its row; `other` is null where no cell of the row has it.
    let batch = one_batch(&store, &frame());
    let other = batch
        .column(1)
        .as_primitive::<arrow_array::types::Int64Type>();
    assert_eq!(other.iter().collect::<Vec<_>>(), [Some(100), Some(200)]);
}

fn one_batch(store: &ChunkStore, query: &DataframeQuery) -> RecordBatch {
    let stream = store.dataframe(query).unwrap();
    let schema = stream.schema();
    let batches: Vec<RecordBatch> = stream.map(Result::unwrap).collect();
    arrow_select::concat::concat_batches(&schema, &batches).unwrap()
}

/// SEMANTICS.md section 9 (settled by issue 32, item 9): an empty list marks a Clear at
/// its own time; everything a Clear hides elsewhere (a filled or sampled cell, before any
/// data too) is null, the answer latest-at gives: none.
#[test]
fn a_flat_clear_shows_as_an_empty_list_and_is_not_filled_back() {
    let store = store_of([
        scalar("/a", "x", 1, 1, 1.0),
        clear("/a", Some(3), 2, false),
        scalar("/a", "x", 5, 3, 5.0),
        scalar("/b", "x", 4, 4, 4.0),
    ]);
    let (names, rows) = render(&store, &frame());
    assert_eq!(names, ["frame", "/a:Clear:is_recursive", "/a:x", "/b:x"]);
    assert_eq!(
        rows,
        lines(&[
            "1 | null | [1] | null",
            "3 | [false] | [] | null",
            "4 | null | null | [4]",
            "5 | null | [5] | null"
        ])
    );
    let filled = render(&store, &frame().with_fill_latest_at(true)).1;
    assert_eq!(
        filled,
        lines(&[
            "1 | null | [1] | null",
            "3 | [false] | [] | null",
            "4 | [false] | null | [4]",
            "5 | [false] | [5] | [4]"
        ])
    );
    // Sampling agrees with latest-at: hidden (null) from the Clear on, visible again after.
    let sampled = render(&store, &frame().with_index_values([t(2), t(3), t(4), t(5)])).1;
    assert_eq!(
        sampled,
        lines(&[
            "2 | null | [1] | null",
            "3 | [false] | null | null",
            "4 | [false] | null | [4]",
            "5 | [false] | [5] | [4]"
        ])
    );
    for at in [3, 4] {
        let query = chunkstore::LatestAtQuery::new("frame", t(at));
        assert!(store.latest_at(&query, &path("/a"), "x").is_none());
    }
    // Before any data: null, not an empty list, when a Clear came first.
    let early = store_of([clear("/a", Some(1), 1, false), scalar("/a", "x", 3, 2, 3.0)]);
    assert_eq!(
        render(&early, &frame().with_index_values([t(0), t(1), t(2), t(3)])).1,
        lines(&[
            "0 | null | null",
            "1 | [false] | null",
            "2 | [false] | null",
            "3 | [false] | [3]"
        ])
    );
    // A logged empty list is a row of the column; a Clear's mark is told from it by the
    // Clear's own column (here `/a:Clear:is_recursive`), non-null in the same row.
    let logged = store_of([scalars("/a", "x", &[(1, 1, Some(vec![]))])]);
    assert_eq!(render(&logged, &frame()).1, lines(&["1 | []"]));
}

#[test]
fn a_recursive_clear_empties_descendants_at_its_time_and_a_later_row_id_survives() {
    let store = store_of([
        scalar("/r/a", "x", 1, 1, 1.0),
        scalar("/r/a/b", "x", 1, 2, 2.0),
        scalar("/other", "x", 1, 3, 3.0),
        clear("/r", Some(2), 10, true),
        scalar("/r/a", "x", 2, 11, 22.0), // same time, later row id: shows
        scalar("/r/a/b", "x", 2, 9, 99.0), // same time, earlier row id: cleared
    ]);
    let query = frame().with_contents(EntityPathFilter::parse(["/r/a/**", "/other"]).unwrap());
    let (names, rows) = render(&store, &query);
    // `/r` itself is not selected, yet its recursive Clear empties what is.
    assert_eq!(names, ["frame", "/other:x", "/r/a:x", "/r/a/b:x"]);
    assert_eq!(
        rows,
        lines(&["1 | [3] | [1] | [2]", "2 | null | [22] | []"])
    );
    let filled = render(&store, &query.clone().with_fill_latest_at(true)).1;
    assert_eq!(
        filled,
        lines(&["1 | [3] | [1] | [2]", "2 | [3] | [22] | []"])
    );
    // The Clear component is hidden by no Clear, but its column marks an ancestor's
    // recursive Clear at its time as every column of the subtree does (issue 32, item 10:
    // Rerun 0.41 shows `[]` there too); filling brings the entity's own Clear back.
    let nested = store_of([
        clear("/r/a", Some(1), 1, false),
        clear("/r", Some(2), 2, true),
        scalar("/r/a", "x", 3, 3, 3.0),
    ]);
    let query = frame().with_contents(EntityPathFilter::parse(["/r/a"]).unwrap());
    assert_eq!(
        render(&nested, &query).1,
        lines(&["1 | [false] | []", "2 | [] | []", "3 | null | [3]"])
    );
    assert_eq!(
        render(&nested, &query.clone().with_fill_latest_at(true)).1,
        lines(&["1 | [false] | []", "2 | [] | []", "3 | [false] | [3]"])
    );
    // A flat Clear at an ancestor hides nothing below it.
    let flat = store_of([
        scalar("/r/a", "x", 1, 1, 1.0),
        clear("/r", Some(2), 10, false),
    ]);
    let query = frame().with_contents(EntityPathFilter::parse(["/r/a"]).unwrap());
    assert_eq!(
        render(&flat, &query.with_fill_latest_at(true)).1,
        lines(&["1 | [1]"])
    );
}

#[test]
fn a_static_clear_hides_older_static_data_and_all_temporal_data_when_filling() {
    let store = store_of([
        static_scalar("/a", "s", 1, 1.0),
        scalar("/a", "x", 1, 2, 1.0),
        scalar("/b", "x", 2, 3, 2.0),
        clear("/a", None, 5, false),
        static_scalar("/a", "t", 6, 6.0), // written after the Clear: visible
    ]);
    let query = frame().with_contents(EntityPathFilter::parse(["/a", "/b"]).unwrap());
    let (names, rows) = render(&store, &query);
    assert_eq!(
        names,
        [
            "frame",
            "/a:Clear:is_recursive",
            "/a:s",
            "/a:t",
            "/a:x",
            "/b:x"
        ]
    );
    // A static Clear hides at every time, so the sparse view agrees with latest-at at
    // each row (issue 32, item 9: the temporal row at 1 used to show): the hidden static
    // cell and the hidden temporal row are null.
    assert_eq!(
        rows,
        lines(&[
            "1 | [false] | null | [6] | null | null",
            "2 | [false] | null | [6] | null | [2]"
        ])
    );
    let at_one = chunkstore::LatestAtQuery::new("frame", t(1));
    assert!(store.latest_at(&at_one, &path("/a"), "x").is_none());
    assert!(store.latest_at(&at_one, &path("/a"), "s").is_none());
    let filled = render(&store, &query.clone().with_fill_latest_at(true)).1;
    assert_eq!(
        filled,
        lines(&[
            "1 | [false] | null | [6] | null | null",
            "2 | [false] | null | [6] | null | [2]"
        ])
    );
    let sampled = render(&store, &query.with_index_values([t(0), t(1)])).1;
    assert_eq!(
        sampled,
        lines(&[
            "0 | [false] | null | [6] | null | null",
            "1 | [false] | null | [6] | null | null"
        ])
    );
}

#[test]
fn batches_hold_at_most_the_rows_asked_for_and_concatenate_to_the_table() {
    let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..50)
        .map(|i| (i, i as u128 + 1, Some(vec![i as f64])))
        .collect();
    let store = store_of([
        scalars("/a", "x", &rows),
        static_scalar("/s", "y", 100, 1.0),
    ]);
    let whole = render(&store, &frame()).1;
    assert_eq!(whole.len(), 50);
    for batch_rows in [1, 3, 7, 49, 50, 51] {
        let query = frame()
            .with_batch_rows(batch_rows)
            .with_fill_latest_at(true);
        let stream = store.dataframe(&query).unwrap();
        let sizes: Vec<usize> = stream.map(|b| b.unwrap().num_rows()).collect();
        assert!(
            sizes.iter().all(|&n| n >= 1 && n <= batch_rows),
            "{sizes:?}"
        );
        assert_eq!(sizes.iter().sum::<usize>(), 50);
        assert_eq!(render(&store, &query).1, whole);
    }
}

#[test]
fn components_logged_together_keep_their_own_rows_where_one_is_null() {
    // One chunk of 120 rows holds three components, some null on frames 50..60: past
    // the rows a column decodes ahead, so that only their validity tells one column's
    // times from the one before it (`a` makes the batch, `b` adds nothing, and `c` may
    // or may not have what `b` has).
    let frames: Vec<i64> = (0..120).collect();
    let cells = |gap: bool| -> Vec<Option<Vec<f64>>> {
        frames
            .iter()
            .map(|&f| (!(gap && (50..60).contains(&f))).then(|| vec![f as f64]))
            .collect()
    };
    let text = |f: i64, gap: bool| {
        if gap && (50..60).contains(&f) {
            "null".to_owned()
        } else {
            format!("[{f}]")
        }
    };
    for gaps in [
        [true, true, false],
        [false, false, true],
        [true, false, true],
    ] {
        let chunk = Chunk::try_new(
            ChunkId::new(),
            path("/e"),
            frames.iter().map(|&f| rid(f as u128 + 1)).collect(),
            vec![(
                Timeline::sequence("frame"),
                Arc::new(Int64Array::from(frames.clone())) as ArrayRef,
            )],
            ["a", "b", "c"]
                .iter()
                .zip(gaps)
                .map(|(name, gap)| ((*name).into(), f64_list(&cells(gap))))
                .collect(),
        )
        .unwrap();
        let store = store_of([chunk]);
        let expected: Vec<String> = frames
            .iter()
            .filter(|&&f| gaps.iter().any(|&gap| !(gap && (50..60).contains(&f))))
            .map(|&f| {
                let cells: Vec<String> = gaps.iter().map(|&gap| text(f, gap)).collect();
                format!("{f} | {}", cells.join(" | "))
            })
            .collect();
        for batch_rows in [4, 40, 100, 119, 200] {
            let query = frame().with_batch_rows(batch_rows);
            assert_eq!(
                render(&store, &query).1,
                expected,
                "gaps {gaps:?}, batches of {batch_rows}"
            );
        }
    }
}

#[test]
fn compaction_and_chunking_never_change_a_table() {
    let chunks = || {
        (0..40).map(|i| {
            scalar(
                if i % 3 == 0 { "/a" } else { "/b/c" },
                "x",
                (i * 7) % 23,
                i as u128 + 1,
                i as f64,
            )
        })
    };
    let plain = store_of(chunks());
    let mut compacted = ChunkStore::with_config(StoreConfig::DEFAULT.with_max_rows(4)).unwrap();
    for chunk in chunks() {
        compacted.insert(chunk).unwrap();
    }
    compacted.compact();
    for query in [
        frame(),
        frame().with_fill_latest_at(true),
        frame().with_index_values((0..25).map(t)),
    ] {
        assert_eq!(render(&plain, &query), render(&compacted, &query));
    }
}

#[test]
fn the_default_contents_leave_out_properties_and_filters_select() {
    let store = store_of([
        static_scalar("/__properties", "start", 1, 1.0),
        scalar("/world/a", "x", 1, 2, 1.0),
        scalar("/world/roads/main", "x", 1, 3, 1.0),
        scalar("/world/roads/side", "x", 1, 4, 1.0),
    ]);
    assert_eq!(
        render(&store, &frame()).0,
        [
            "frame",
            "/world/a:x",
            "/world/roads/main:x",
            "/world/roads/side:x"
        ]
    );
    let filter =
        EntityPathFilter::parse(["+ /world/**", "- /world/roads/**", "+ /world/roads/main"])
            .unwrap();
    assert_eq!(
        render(&store, &frame().with_contents(filter)).0,
        ["frame", "/world/a:x", "/world/roads/main:x"]
    );
    // Issue 32, item 11: as in Rerun, `/**` leaves the properties out unless named.
    let everything = EntityPathFilter::parse(["/**"]).unwrap();
    assert!(
        !render(&store, &frame().with_contents(everything))
            .0
            .contains(&"/__properties:start".to_owned())
    );
    let with_properties = EntityPathFilter::parse(["/**", "/__properties/**"]).unwrap();
    assert!(
        render(&store, &frame().with_contents(with_properties))
            .0
            .contains(&"/__properties:start".to_owned())
    );
    let nothing = EntityPathFilter::parse(["/nowhere"]).unwrap();
    let (names, rows) = render(&store, &frame().with_contents(nothing));
    assert_eq!((names, rows.len()), (vec!["frame".to_owned()], 0));
}

#[test]
fn bad_queries_are_named() {
    let store = store_of([scalar("/a", "x", 1, 1, 1.0)]);
    let error = store.dataframe(&DataframeQuery::new("nope")).unwrap_err();
    assert_eq!(
        error,
        DataframeError::UnknownIndex(chunkstore::UnknownTimeline {
            name: "nope".to_owned(),
            known: vec!["frame".to_owned()]
        })
    );
    assert!(error.to_string().contains("unknown timeline \"nope\""));
    assert_eq!(
        store.dataframe(&frame().with_batch_rows(0)).unwrap_err(),
        DataframeError::ZeroBatchRows
    );
}

#[test]
fn the_stream_is_a_record_batch_reader_and_the_default_batch_is_bounded_by_cells() {
    use arrow_array::RecordBatchReader;
    let store = store_of([scalar("/a", "x", 1, 1, 1.0)]);
    let stream = store.dataframe(&frame()).unwrap();
    assert_eq!(stream.batch_rows(), 65_536, "one column: the row cap");
    let reader: Box<dyn RecordBatchReader> = Box::new(stream);
    assert_eq!(reader.schema().fields().len(), 2);
    assert_eq!(reader.map(|b| b.unwrap().num_rows()).sum::<usize>(), 1);
    let wide = store_of((0..2000).map(|i| scalar(&format!("/e{i}"), "x", 1, i + 1, 1.0)));
    let stream = wide.dataframe(&frame()).unwrap();
    assert_eq!(stream.batch_rows(), chunkstore::DEFAULT_BATCH_CELLS / 2000);
    // A floor on the rows: wide tables get it, narrow ones keep their cells' worth;
    // rows asked for win.
    let stream = wide.dataframe(&frame().with_min_batch_rows(4_096)).unwrap();
    assert_eq!(stream.batch_rows(), 4_096);
    let stream = store
        .dataframe(&frame().with_min_batch_rows(4_096))
        .unwrap();
    assert_eq!(stream.batch_rows(), 65_536);
    let stream = store
        .dataframe(&frame().with_min_batch_rows(100_000))
        .unwrap();
    assert_eq!(stream.batch_rows(), 100_000);
    let both = frame().with_min_batch_rows(4_096).with_batch_rows(3);
    assert_eq!(wide.dataframe(&both).unwrap().batch_rows(), 3);
}

#[test]
fn a_snapshot_streams_the_same_table_from_another_thread_while_the_store_changes() {
    let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..30)
        .map(|i| (i, i as u128 + 1, Some(vec![i as f64])))
        .collect();
    let mut store = store_of([scalars("/a", "x", &rows)]);
    let query = frame().with_batch_rows(7).with_fill_latest_at(true);
    let expected: Vec<RecordBatch> = store
        .dataframe(&query)
        .unwrap()
        .map(Result::unwrap)
        .collect();

    let stream = store.snapshot().into_dataframe(&query).unwrap();
    // Written after the snapshot: the owned stream must not see it.
    store
        .insert(scalars("/a", "x", &[(100, 1_000, Some(vec![-1.0]))]))
        .unwrap();
    let streamed = std::thread::spawn(move || stream.map(Result::unwrap).collect::<Vec<_>>())
        .join()
        .unwrap();
    assert_eq!(streamed, expected);
    assert_eq!(
        streamed.iter().map(RecordBatch::num_rows).sum::<usize>(),
        30
    );
    assert_eq!(render(&store, &frame()).1.len(), 31);

    let unknown = store
        .snapshot()
        .into_dataframe(&DataframeQuery::new("nope"));
    assert!(matches!(unknown, Err(DataframeError::UnknownIndex { .. })));
}

/// A chunk sorted on the index whose column has no null cell is taken a stretch of rows
/// at a time where its rows are the batch's next ones: the table is the one its rows
/// give one by one. Rows tied on a time inside the chunk (the greater row id shows) and
/// across chunks, an empty list (valid, not null), a stretch that ends a batch, and a
/// column that fills the rows after its stretch with its last row.
#[test]
fn stretches_of_a_sorted_chunk_show_as_their_rows_one_by_one() {
    let rows = |frames: &[i64], first_row_id: u128| -> Vec<(i64, u128, Option<Vec<f64>>)> {
        frames
            .iter()
            .zip(first_row_id..)
            .map(|(&frame, row_id)| (frame, row_id, Some(vec![row_id as f64])))
            .collect()
    };
    let mut b = rows(&(0..=16).collect::<Vec<_>>(), 200);
    b[3].2 = Some(vec![]);
    let store = store_of([
        scalars(
            "/a",
            "x",
            &rows(&[0, 1, 2, 3, 4, 5, 5, 6, 7, 8, 9, 10, 11], 1),
        ),
        scalars("/a", "x", &rows(&[11, 12, 13, 14, 15, 16], 100)),
        scalars("/b", "x", &b),
        // A stretch (0 to 5) ended by a gap: the rows after it fill with its last.
        scalars("/d", "x", &rows(&[0, 1, 2, 3, 4, 5, 9], 300)),
        scalars("/d", "x", &rows(&[16], 316)),
    ]);
    let sparse = lines(&[
        "0 | [1] | [200] | [300]",
        "1 | [2] | [201] | [301]",
        "2 | [3] | [202] | [302]",
        "3 | [4] | [] | [303]",
        "4 | [5] | [204] | [304]",
        "5 | [7] | [205] | [305]",
        "6 | [8] | [206] | null",
        "7 | [9] | [207] | null",
        "8 | [10] | [208] | null",
        "9 | [11] | [209] | [306]",
        "10 | [12] | [210] | null",
        "11 | [100] | [211] | null",
        "12 | [101] | [212] | null",
        "13 | [102] | [213] | null",
        "14 | [103] | [214] | null",
        "15 | [104] | [215] | null",
        "16 | [105] | [216] | [316]",
    ]);
    let filled: Vec<String> = sparse
        .iter()
        .enumerate()
        .map(|(frame, l)| l.replace("null", if frame < 9 { "[305]" } else { "[306]" }))
        .collect();
    for batch_rows in [1, 2, 3, 5, 7, 100] {
        for (fill, expected) in [(false, &sparse), (true, &filled)] {
            let query = frame()
                .with_batch_rows(batch_rows)
                .with_fill_latest_at(fill);
            assert_eq!(&render(&store, &query).1, expected, "{batch_rows} {fill}");
        }
    }
}

/// A stream over a snapshot that reads its view to the end leaves the view's rows with the
/// snapshot: a later query of the same view (index, contents, kept kinds of column) over
/// that range or a part of it takes its rows from there and reads only the columns it
/// outputs, with the same answer as a store that keeps nothing. A query the kept rows do
/// not cover, another view, or a fresh snapshot gathers its rows again.
#[test]
fn a_snapshot_keeps_a_views_rows_and_later_queries_read_only_their_columns() {
    let mut chunks = Vec::new();
    for entity in 0..5_i64 {
        // Entity i logs every (i + 1)th frame: the rows are the union of their times.
        let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..60)
            .filter(|frame| frame % (entity + 1) == 0)
            .map(|frame| {
                let row = (frame * 10 + entity) as u128 + 1;
                (frame, row, Some(vec![(frame * 100 + entity) as f64]))
            })
            .collect();
        // In chunks of a few rows, so that a column's chunks can be counted.
        for part in rows.chunks(4) {
            chunks.push(scalars(&format!("/e/{entity}"), "x", part));
        }
    }
    chunks.push(clear("/e/2", Some(31), 5_000, false));
    chunks.push(static_scalar("/s", "y", 6_000, 7.0));
    let store = store_of(chunks);
    let expected = |query: &DataframeQuery| -> Vec<RecordBatch> {
        store
            .dataframe(query)
            .unwrap()
            .map(Result::unwrap)
            .collect()
    };
    let range = |min: i64, max: i64| TimeRange::new(t(min), t(max));
    let one_column = |query: DataframeQuery| query.with_columns(["frame", "/e/3:x"]);

    let snapshot = store.snapshot();
    // Read in two parts, as SQL's scans build a range: the parts' rows join.
    for part in [range(30, i64::MAX), range(i64::MIN + 1, 29)] {
        let query = frame().with_range(part).with_batch_rows(7);
        let read: Vec<RecordBatch> = snapshot
            .clone()
            .into_dataframe(&query)
            .unwrap()
            .map(Result::unwrap)
            .collect();
        assert_eq!(read, expected(&query));
    }
    let queries = [
        one_column(frame()),
        one_column(frame().with_range(range(10, 40))).with_batch_rows(3),
        one_column(frame().with_fill_latest_at(true).with_range(range(31, 50))),
        frame().with_columns(["/e/2:x"]).with_fill_latest_at(true),
        frame().with_range(range(5, 55)),
    ];
    for query in &queries {
        let kept = snapshot.clone().into_dataframe(query).unwrap();
        let fresh = store.snapshot().into_dataframe(query).unwrap();
        let (kept_chunks, fresh_chunks) = (kept.num_chunks_read(), fresh.num_chunks_read());
        let built: Vec<RecordBatch> = kept.map(Result::unwrap).collect();
        assert_eq!(built, expected(query), "{query:?}");
        if query.columns().is_some() {
            // One entity's chunks (and the static one, which every row shows) against
            // every entity's.
            assert!(
                kept_chunks < fresh_chunks / 2,
                "{kept_chunks} of {fresh_chunks}"
            );
        } else {
            assert_eq!(kept_chunks, fresh_chunks);
        }
    }
    // Not covered by the kept rows (past the timeline's end is covered: the parts were
    // open-ended), another view: every column's times read again.
    let other_view = one_column(frame().with_contents(EntityPathFilter::parse(["/e/**"]).unwrap()));
    let other = snapshot.clone().into_dataframe(&other_view).unwrap();
    assert_eq!(
        other.num_chunks_read(),
        store
            .snapshot()
            .into_dataframe(&other_view)
            .unwrap()
            .num_chunks_read()
    );
    assert_eq!(
        other.map(Result::unwrap).collect::<Vec<_>>(),
        expected(&other_view)
    );
    let sampled = one_column(frame().with_index_values([t(3), t(31)]));
    let read: Vec<RecordBatch> = snapshot
        .into_dataframe(&sampled)
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(read, expected(&sampled));
}

/// `ChunkTableQuery::with_columns` builds exactly the whole table's columns it names, in
/// the table's order, with the same rows; no column at all keeps the row count; an unknown
/// name is refused.
#[test]
fn a_chunk_table_with_columns_equals_the_whole_table_projected() {
    use arrow_select::concat::concat_batches;
    use chunkstore::ChunkTableQuery;
    let store = common::robot();
    let collect = |query: &ChunkTableQuery| {
        let stream = store.chunk_table(query).unwrap();
        let schema = stream.schema();
        let batches: Vec<RecordBatch> = stream.map(Result::unwrap).collect();
        let rows = batches.iter().map(RecordBatch::num_rows).sum::<usize>();
        (rows, concat_batches(&schema, &batches).unwrap())
    };
    for base in [
        ChunkTableQuery::new(),
        ChunkTableQuery::new()
            .with_index("frame_id")
            .with_batch_rows(7),
    ] {
        let (rows, whole) = collect(&base);
        let schema = whole.schema();
        let n = schema.fields().len();
        assert!(n > 6, "the robot's table has ids, timelines and components");
        // Each column alone, each neighbouring pair, every other one, and the last three
        // named backwards (the table's order wins).
        let mut selections: Vec<Vec<usize>> = (0..n).map(|i| vec![i]).collect();
        selections.extend((1..n).map(|i| vec![i - 1, i]));
        selections.push((0..n).step_by(2).collect());
        selections.push(vec![n - 1, n - 2, n - 3]);
        for selection in selections {
            let names: Vec<String> = selection
                .iter()
                .map(|&i| schema.field(i).name().clone())
                .collect();
            let (_, ours) = collect(&base.clone().with_columns(names.iter().cloned()));
            let mut sorted = selection.clone();
            sorted.sort_unstable();
            assert_eq!(ours, whole.project(&sorted).unwrap(), "{names:?}");
        }
        let (none_rows, none) = collect(&base.clone().with_columns(Vec::<String>::new()));
        assert_eq!(none.num_columns(), 0);
        assert_eq!(none_rows, rows);
        let error = store
            .chunk_table(&base.clone().with_columns(["nope"]))
            .unwrap_err();
        assert!(
            matches!(&error, DataframeError::UnknownColumn { name, num_columns } if name == "nope" && *num_columns == n),
            "{error}"
        );
    }
}

/// Issue 32, item 11: Rerun's reader leaves out tombstone (`Clear:is_recursive`) and
/// semantically empty columns by default; both are offered. Left out, a column is not in
/// the view (its rows make no rows), while a Clear still marks and hides the others.
#[test]
fn tombstone_and_empty_columns_can_be_left_out() {
    let store = store_of([
        scalar("/a", "x", 1, 1, 1.0),
        clear("/a", Some(3), 2, false),
        scalars("/a", "empty", &[(2, 3, Some(vec![])), (4, 4, None)]),
        clear("/b", Some(5), 5, true),
        scalar("/c", "y", 6, 6, 6.0),
    ]);
    let (names, rows) = render(&store, &frame());
    assert_eq!(
        names,
        [
            "frame",
            "/a:Clear:is_recursive",
            "/a:empty",
            "/a:x",
            "/b:Clear:is_recursive",
            "/c:y"
        ]
    );
    assert_eq!(rows.len(), 5, "{rows:?}"); // frame 4's null cell is no row
    let rerun_like = frame()
        .with_tombstone_columns(false)
        .with_semantically_empty_columns(false);
    let (names, rows) = render(&store, &rerun_like);
    assert_eq!(names, ["frame", "/a:x", "/c:y"]);
    // Frames 1, 3 (the Clear's mark in /a:x) and 6; /b's Clear and /a:empty's rows make
    // no rows now.
    assert_eq!(
        rows,
        lines(&["1 | [1] | null", "3 | [] | null", "6 | null | [6]"])
    );
    let only_tombstones_out = render(&store, &frame().with_tombstone_columns(false)).0;
    assert_eq!(only_tombstones_out, ["frame", "/a:empty", "/a:x", "/c:y"]);
    let only_empty_out = render(&store, &frame().with_semantically_empty_columns(false)).0;
    assert!(!only_empty_out.contains(&"/a:empty".to_owned()));
    assert!(only_empty_out.contains(&"/b:Clear:is_recursive".to_owned()));
}

/// Issue 32, item 11: sampling with exact hits, as Rerun's reader samples without
/// `fill_latest_at`: a sampled row shows what the sparse view has at exactly that time.
#[test]
fn exact_samples_show_only_what_was_logged_at_each_value() {
    let store = store_of([
        scalar("/a", "x", 1, 1, 1.0),
        scalar("/a", "x", 4, 2, 4.0),
        clear("/a", Some(3), 3, false),
        static_scalar("/s", "y", 4, 9.0),
    ]);
    let values = [t(0), t(1), t(2), t(3), t(4)];
    let latest = render(&store, &frame().with_index_values(values)).1;
    assert_eq!(
        latest,
        lines(&[
            "0 | null | null | [9]",
            "1 | null | [1] | [9]",
            "2 | null | [1] | [9]",
            "3 | [false] | null | [9]",
            "4 | [false] | [4] | [9]"
        ])
    );
    let exact = render(
        &store,
        &frame()
            .with_index_values(values)
            .with_exact_index_values(true),
    )
    .1;
    assert_eq!(
        exact,
        lines(&[
            "0 | null | null | [9]",
            "1 | null | [1] | [9]",
            "2 | null | null | [9]",
            "3 | [false] | [] | [9]",
            "4 | null | [4] | [9]"
        ])
    );
    // Each exact row is the sparse view's row at that time, where it has one.
    let sparse = render(&store, &frame()).1;
    for row in [
        "1 | null | [1] | [9]",
        "3 | [false] | [] | [9]",
        "4 | null | [4] | [9]",
    ] {
        assert!(sparse.contains(&row.to_owned()), "{row} in {sparse:?}");
    }
}

/// The model test's find: where an ancestor's recursive Clear and the entity's own Clear
/// share a time and the ancestor's came later, the entity's `Clear:is_recursive` column
/// shows the mark there, and filling goes on with the entity's own Clear (no Clear hides
/// that column), as latest-at answers.
#[test]
fn a_clear_column_fills_with_its_own_clear_after_an_ancestor_s_mark() {
    let store = store_of([
        clear("/r/a", Some(6), 1, false),
        clear("/r", Some(6), 2, true),
        scalar("/other", "x", 7, 3, 7.0),
    ]);
    let query = frame()
        .with_contents(EntityPathFilter::parse(["/r/a", "/other"]).unwrap())
        .with_fill_latest_at(true);
    assert_eq!(
        render(&store, &query).1,
        lines(&["6 | null | []", "7 | [7] | [false]"])
    );
    let at_seven = chunkstore::LatestAtQuery::new("frame", t(7));
    assert!(
        store
            .latest_at(&at_seven, &path("/r/a"), "Clear:is_recursive")
            .is_some()
    );
}
