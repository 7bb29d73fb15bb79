//! Every rejection of SEMANTICS.md section 2 (and of insertion) has a test on its typed
//! error variant, and a rejected insert leaves the store unchanged.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::float_cmp,
    reason = "tests fail loudly on unexpected values; test values are small integers, exact in f64"
)]

use crate::common;

use std::collections::HashMap;
use std::sync::Arc;

use arrow_array::builder::{FixedSizeBinaryBuilder, Int64Builder};
use arrow_array::{ArrayRef, Float64Array, Int32Array, Int64Array, RecordBatch, StringArray};
use arrow_schema::{DataType, Field, Schema, TimeUnit};
use chunkstore::{
    Chunk, ChunkBuilder, ChunkError, ChunkId, ChunkStore, ComponentName, InsertError,
    LatestAtQuery, RowId, TimeRange, TimeType, Timeline,
};
use common::*;

fn frame(times: Vec<i64>) -> (Timeline, ArrayRef) {
    (
        Timeline::sequence("frame"),
        Arc::new(Int64Array::from(times)),
    )
}

fn chunk(
    row_ids: usize,
    times: Vec<(Timeline, ArrayRef)>,
    components: Vec<(&str, ArrayRef)>,
) -> Result<Chunk, ChunkError> {
    Chunk::try_new(
        ChunkId::new(),
        path("e"),
        (0..row_ids as u128).map(rid).collect(),
        times,
        components.into_iter().map(|(n, a)| (n.into(), a)).collect(),
    )
}

fn one_cell() -> ArrayRef {
    f64_list(&[Some(vec![1.0])])
}

#[test]
fn mismatched_lengths_name_the_column() {
    let err = chunk(2, vec![frame(vec![1, 2])], vec![("c", one_cell())]).unwrap_err();
    assert!(
        matches!(&err, ChunkError::LengthMismatch { column, expected: 2, actual: 1 } if column == "c"),
        "{err}"
    );
    let err = chunk(1, vec![frame(vec![1, 2])], vec![("c", one_cell())]).unwrap_err();
    assert!(
        matches!(&err, ChunkError::LengthMismatch { column, expected: 1, actual: 2 } if column == "frame"),
        "{err}"
    );
}

#[test]
fn nulls_in_a_time_column_are_rejected() {
    let times: ArrayRef = Arc::new(Int64Array::from(vec![Some(1), None]));
    let err = chunk(
        2,
        vec![(Timeline::sequence("frame"), times)],
        vec![("c", f64_list(&[None, None]))],
    )
    .unwrap_err();
    assert!(
        matches!(&err, ChunkError::NullTimes { timeline, null_count: 1 } if timeline == "frame"),
        "{err}"
    );
}

#[test]
fn reserved_time_is_rejected() {
    let err = chunk(1, vec![frame(vec![i64::MIN])], vec![("c", one_cell())]).unwrap_err();
    assert!(
        matches!(&err, ChunkError::ReservedTime { timeline, row: 0 } if timeline == "frame"),
        "{err}"
    );
}

#[test]
fn a_non_list_component_is_rejected() {
    let err = chunk(
        1,
        vec![],
        vec![("c", Arc::new(Float64Array::from(vec![1.0])) as ArrayRef)],
    )
    .unwrap_err();
    assert!(
        matches!(&err, ChunkError::NotAList { component, data_type: DataType::Float64 } if component == "c"),
        "{err}"
    );
}

#[test]
fn no_rows_and_no_components_are_rejected() {
    assert!(matches!(
        chunk(0, vec![], vec![("c", f64_list(&[]))]),
        Err(ChunkError::NoRows)
    ));
    assert!(matches!(
        chunk(1, vec![frame(vec![1])], vec![]),
        Err(ChunkError::NoComponents)
    ));
}

#[test]
fn wrong_time_types_are_rejected() {
    let millis: ArrayRef = Arc::new(arrow_array::DurationMillisecondArray::from(vec![1]));
    let err = chunk(
        1,
        vec![(Timeline::new("d", TimeType::DurationNs), millis)],
        vec![("c", one_cell())],
    )
    .unwrap_err();
    assert!(
        matches!(&err, ChunkError::BadTimeType { timeline, .. } if timeline == "d"),
        "{err}"
    );
    let mismatched = chunk(
        1,
        vec![(
            Timeline::new("f", TimeType::TimestampNs),
            Arc::new(Int64Array::from(vec![1])) as ArrayRef,
        )],
        vec![("c", one_cell())],
    );
    assert!(
        matches!(mismatched, Err(ChunkError::BadTimeType { .. })),
        "the timeline's type must match the array"
    );
}

#[test]
fn duplicate_and_empty_names_are_rejected() {
    let twice = chunk(
        1,
        vec![frame(vec![1]), frame(vec![2])],
        vec![("c", one_cell())],
    );
    assert!(
        matches!(twice, Err(ChunkError::DuplicateTimeline { timeline }) if timeline == "frame")
    );
    let twice = chunk(1, vec![], vec![("c", one_cell()), ("c", one_cell())]);
    assert!(matches!(twice, Err(ChunkError::DuplicateComponent { component }) if component == "c"));
    assert!(matches!(
        chunk(1, vec![], vec![("", one_cell())]),
        Err(ChunkError::EmptyName { kind: "component" })
    ));
    // A few columns are compared pairwise, many go through a set: both find the pair.
    for num_columns in [3, 40] {
        let names: Vec<String> = (0..num_columns).map(|c| format!("c{c}")).collect();
        let mut columns: Vec<(&str, ArrayRef)> =
            names.iter().map(|n| (n.as_str(), one_cell())).collect();
        assert!(chunk(1, vec![], columns.clone()).is_ok());
        columns.push(("c1", one_cell()));
        let twice = chunk(1, vec![], columns);
        assert!(
            matches!(&twice, Err(ChunkError::DuplicateComponent { component }) if component == "c1"),
            "{num_columns} columns: {twice:?}"
        );
    }
}

#[test]
fn builder_rejects_rows_missing_a_timeline_and_mixed_cell_types() {
    let cell = |v: f64| Arc::new(Float64Array::from(vec![v])) as ArrayRef;
    let missing = ChunkBuilder::new(ChunkId::new(), path("e"))
        .with_row(
            rid(1),
            [(Timeline::sequence("frame"), 1)],
            [("c", cell(1.0))],
        )
        .with_row(rid(2), [], [("c", cell(2.0))])
        .build();
    assert!(
        matches!(missing, Err(ChunkError::NullTimes { timeline, null_count: 1 }) if timeline == "frame")
    );
    let mixed = ChunkBuilder::new(ChunkId::new(), path("e"))
        .with_static_row(rid(1), [("c", cell(1.0))])
        .with_static_row(
            rid(2),
            [("c", Arc::new(Int32Array::from(vec![1])) as ArrayRef)],
        )
        .build();
    assert!(
        matches!(mixed, Err(ChunkError::CellTypeMismatch { component, .. }) if component == "c")
    );
}

/// Issue 12, item 3: a row naming one component or timeline twice used to keep the last
/// value silently.
#[test]
fn builder_rejects_a_row_that_names_a_component_or_timeline_twice() {
    let cell = |v: f64| Arc::new(Float64Array::from(vec![v])) as ArrayRef;
    let frame = Timeline::sequence("frame");
    let twice_a_component = ChunkBuilder::new(ChunkId::new(), path("e"))
        .with_row(rid(1), [(frame.clone(), 1)], [("c", cell(1.0))])
        .with_row(
            rid(2),
            [(frame.clone(), 2)],
            [("c", cell(2.0)), ("c", cell(3.0))],
        )
        .build();
    assert!(
        matches!(&twice_a_component, Err(ChunkError::ComponentRepeatedInRow { row: 1, component }) if component == "c"),
        "{twice_a_component:?}"
    );
    let twice_a_timeline = ChunkBuilder::new(ChunkId::new(), path("e"))
        .with_row(
            rid(1),
            [(frame.clone(), 1), (frame.clone(), 5)],
            [("c", cell(1.0))],
        )
        .build();
    assert!(
        matches!(&twice_a_timeline, Err(ChunkError::TimelineRepeatedInRow { row: 0, timeline }) if timeline == "frame"),
        "{twice_a_timeline:?}"
    );
    assert!(
        twice_a_timeline
            .unwrap_err()
            .to_string()
            .contains("row 0 gives timeline \"frame\" two times")
    );
}

/// Issue 12, item 6: one timeline name with two types used to be reported as null times.
#[test]
fn builder_names_a_timeline_given_with_two_types() {
    let cell = Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
    let built = ChunkBuilder::new(ChunkId::new(), path("e"))
        .with_row(
            rid(1),
            [(Timeline::sequence("t"), 1)],
            [("c", Arc::clone(&cell))],
        )
        .with_row(
            rid(2),
            [(Timeline::new("t", TimeType::DurationNs), 2)],
            [("c", cell)],
        )
        .build();
    assert!(
        matches!(
            &built,
            Err(ChunkError::TimelineTypeMismatch {
                timeline,
                first: TimeType::Sequence,
                second: TimeType::DurationNs,
            }) if timeline == "t"
        ),
        "{built:?}"
    );
}

/// A valid transport batch, as the pieces to break it.
fn transport_parts() -> (Vec<Field>, Vec<ArrayRef>, HashMap<String, String>) {
    let mut row_ids = FixedSizeBinaryBuilder::new(16);
    row_ids.append_value(RowId::new().to_be_bytes()).unwrap();
    let kind = |k: &str| HashMap::from([("rerun:kind".to_owned(), k.to_owned())]);
    let fields = vec![
        Field::new("rerun.controls.RowId", DataType::FixedSizeBinary(16), false)
            .with_metadata(kind("control")),
        Field::new("frame", DataType::Int64, true).with_metadata(kind("index")),
        Field::new("c", one_cell().data_type().clone(), true).with_metadata(kind("data")),
    ];
    let columns: Vec<ArrayRef> = vec![
        Arc::new(row_ids.finish()),
        Arc::new(Int64Array::from(vec![1])),
        one_cell(),
    ];
    let meta = HashMap::from([
        ("rerun:id".to_owned(), ChunkId::new().to_string()),
        ("rerun:entity_path".to_owned(), "/e".to_owned()),
    ]);
    (fields, columns, meta)
}

fn decode(
    fields: Vec<Field>,
    columns: Vec<ArrayRef>,
    meta: HashMap<String, String>,
) -> Result<Chunk, ChunkError> {
    let batch =
        RecordBatch::try_new(Arc::new(Schema::new_with_metadata(fields, meta)), columns).unwrap();
    Chunk::from_record_batch(&batch)
}

#[test]
fn transport_decoding_accepts_the_valid_batch() {
    let (fields, columns, meta) = transport_parts();
    let chunk = decode(fields, columns, meta).unwrap();
    assert_eq!(chunk.num_rows(), 1);
}

#[test]
fn transport_rejects_missing_metadata_bad_ids_and_bad_paths() {
    for (key, value, check) in [
        (
            "rerun:id",
            None,
            (|e: &ChunkError| matches!(e, ChunkError::MissingMetadata { key: "rerun:id" }))
                as fn(&ChunkError) -> bool,
        ),
        ("rerun:entity_path", None, |e| {
            matches!(
                e,
                ChunkError::MissingMetadata {
                    key: "rerun:entity_path"
                }
            )
        }),
        ("rerun:id", Some("chunk_nothex"), |e| {
            matches!(e, ChunkError::BadChunkId(_))
        }),
        ("rerun:entity_path", Some("a//b"), |e| {
            matches!(e, ChunkError::BadEntityPath(_))
        }),
    ] {
        let (fields, columns, mut meta) = transport_parts();
        match value {
            Some(value) => meta.insert(key.to_owned(), value.to_owned()),
            None => meta.remove(key),
        };
        let err = decode(fields, columns, meta).unwrap_err();
        assert!(check(&err), "{key}={value:?}: {err}");
    }
}

#[test]
fn transport_rejects_null_row_ids_wrong_row_id_type_and_missing_row_ids() {
    let (mut fields, mut columns, meta) = transport_parts();
    let mut nulls = FixedSizeBinaryBuilder::new(16);
    nulls.append_null();
    columns[0] = Arc::new(nulls.finish());
    fields[0] = fields[0].clone().with_nullable(true);
    assert!(matches!(
        decode(fields, columns, meta),
        Err(ChunkError::NullRowIds { null_count: 1 })
    ));

    let (mut fields, mut columns, meta) = transport_parts();
    columns[0] = Arc::new(StringArray::from(vec!["x"]));
    fields[0] = Field::new("rerun.controls.RowId", DataType::Utf8, false)
        .with_metadata(fields[0].metadata().clone());
    assert!(matches!(
        decode(fields, columns, meta),
        Err(ChunkError::BadRowIdType {
            data_type: DataType::Utf8
        })
    ));

    let (mut fields, mut columns, meta) = transport_parts();
    fields.remove(0);
    columns.remove(0);
    assert!(matches!(
        decode(fields, columns, meta),
        Err(ChunkError::MissingRowIds)
    ));
}

#[test]
fn transport_names_a_second_row_id_column() {
    let (mut fields, mut columns, meta) = transport_parts();
    fields.push(fields[0].clone().with_name("second_row_ids"));
    columns.push(Arc::clone(&columns[0]));
    let error = decode(fields, columns, meta).unwrap_err();
    assert!(
        matches!(&error, ChunkError::DuplicateRowIds { column } if column == "second_row_ids"),
        "{error}"
    );
}

#[test]
fn try_from_a_record_batch_is_from_record_batch() {
    let (fields, columns, meta) = transport_parts();
    let batch =
        RecordBatch::try_new(Arc::new(Schema::new_with_metadata(fields, meta)), columns).unwrap();
    let chunk = Chunk::try_from(&batch).unwrap();
    let direct = Chunk::from_record_batch(&batch).unwrap();
    assert_eq!(
        chunk.to_record_batch().unwrap(),
        direct.to_record_batch().unwrap()
    );
    assert_eq!(
        chunk.id().to_string(),
        batch.schema().metadata()["rerun:id"]
    );
    let mut no_id = batch.schema().metadata().clone();
    no_id.remove("rerun:id");
    let fields = batch.schema().fields().clone();
    let batch = RecordBatch::try_new(
        Arc::new(Schema::new_with_metadata(fields, no_id)),
        batch.columns().to_vec(),
    )
    .unwrap();
    assert!(matches!(
        Chunk::try_from(&batch),
        Err(ChunkError::MissingMetadata { key: "rerun:id" })
    ));
}

#[test]
fn transport_rejects_unknown_column_kinds_and_bad_time_columns() {
    let (mut fields, columns, meta) = transport_parts();
    fields[2] = fields[2].clone().with_metadata(HashMap::from([(
        "rerun:kind".to_owned(),
        "mystery".to_owned(),
    )]));
    assert!(
        matches!(decode(fields, columns, meta), Err(ChunkError::UnknownColumnKind { column, kind }) if column == "c" && kind == "mystery")
    );

    let (mut fields, mut columns, meta) = transport_parts();
    columns[1] = Arc::new(Int32Array::from(vec![1]));
    fields[1] =
        Field::new("frame", DataType::Int32, true).with_metadata(fields[1].metadata().clone());
    assert!(
        matches!(decode(fields, columns, meta), Err(ChunkError::BadTimeType { timeline, .. }) if timeline == "frame")
    );

    let (mut fields, mut columns, meta) = transport_parts();
    let mut times = Int64Builder::new();
    times.append_null();
    columns[1] = Arc::new(times.finish());
    fields[1] = fields[1].clone().with_nullable(true);
    assert!(matches!(
        decode(fields, columns, meta),
        Err(ChunkError::NullTimes { .. })
    ));
}

#[test]
fn insert_rejects_a_timeline_with_another_type_and_leaves_the_store_unchanged() {
    let mut store = ChunkStore::new();
    store.insert(scalar("e", "c", 1, 1, 1.0)).unwrap();
    let before = store.to_string();
    let as_duration = chunk(
        1,
        vec![(
            Timeline::new("frame", TimeType::DurationNs),
            Arc::new(arrow_array::DurationNanosecondArray::from(vec![5])) as ArrayRef,
        )],
        vec![("c", one_cell())],
    )
    .unwrap();
    let err = store.insert(as_duration).unwrap_err();
    assert!(
        matches!(&err, InsertError::TimelineTypeConflict { timeline, existing: TimeType::Sequence, incoming: TimeType::DurationNs, .. } if timeline == "frame"),
        "{err}"
    );
    assert_eq!(store.to_string(), before);
    store.sanity_check().unwrap();
}

#[test]
fn insert_rejects_a_component_with_another_type_and_leaves_the_store_unchanged() {
    let mut store = ChunkStore::new();
    store.insert(scalar("e", "c", 1, 1, 1.0)).unwrap();
    let before = store.to_string();
    let ints: ArrayRef = Arc::new(arrow_array::ListArray::from_iter_primitive::<
        arrow_array::types::Int32Type,
        _,
        _,
    >([Some([Some(1)])]));
    let err = store
        .insert(chunk(1, vec![frame(vec![2])], vec![("c", ints)]).unwrap())
        .unwrap_err();
    assert!(
        matches!(&err, InsertError::ComponentTypeConflict { component, existing: DataType::Float64, incoming: DataType::Int32, .. } if component == "c"),
        "{err}"
    );
    assert_eq!(store.to_string(), before);
    let answer = store
        .latest_at(&LatestAtQuery::new("frame", t(5)), &path("e"), "c")
        .unwrap();
    assert_eq!(
        first_f64(&answer.cell()),
        1.0,
        "the rejected chunk is not visible"
    );
    // Another entity may use another type for the same component name.
    let ints: ArrayRef = Arc::new(arrow_array::ListArray::from_iter_primitive::<
        arrow_array::types::Int32Type,
        _,
        _,
    >([Some([Some(1)])]));
    let other = Chunk::try_new(
        ChunkId::new(),
        path("f"),
        vec![rid(9)],
        vec![frame(vec![2])],
        vec![("c".into(), ints)],
    )
    .unwrap();
    store.insert(other).unwrap();
}

/// Issue 12, item 4: a Clear cell says once whether the Clear is recursive. Empty cells,
/// cells of several booleans and null booleans used to be accepted (and read as "no
/// Clear" or by their first instance); they are refused, naming the row. A null cell (no
/// Clear in that row) is fine.
#[test]
fn insert_rejects_clear_cells_that_are_not_one_boolean() {
    use arrow_array::builder::{BooleanBuilder, ListBuilder};
    let clears = |cells: &[Option<Vec<Option<bool>>>]| {
        let mut builder = ListBuilder::new(BooleanBuilder::new());
        for cell in cells {
            match cell {
                Some(flags) => {
                    for flag in flags {
                        builder.values().append_option(*flag);
                    }
                    builder.append(true);
                }
                None => builder.append(false),
            }
        }
        Arc::new(builder.finish()) as ArrayRef
    };
    let mut store = ChunkStore::new();
    for (cells, expected_row, expected) in [
        (vec![Some(vec![Some(true), Some(false)])], 0, Some(2)),
        (vec![Some(vec![Some(true)]), Some(vec![])], 1, Some(0)),
        (vec![None, Some(vec![None])], 1, None),
    ] {
        let rows = cells.len();
        let bad = chunk(
            rows,
            vec![frame((0..i64::try_from(rows).unwrap()).collect())],
            vec![(ComponentName::CLEAR_IS_RECURSIVE, clears(&cells))],
        )
        .unwrap();
        let error = store.insert(bad).unwrap_err();
        match (&error, expected) {
            (InsertError::MalformedClear { row, instances, .. }, Some(n)) => {
                assert_eq!((*row, *instances), (expected_row, n), "{error}");
            }
            (InsertError::NullClearFlag { row, .. }, None) => assert_eq!(*row, expected_row),
            _ => panic!("{cells:?}: {error:?}"),
        }
        assert!(
            error.to_string().contains(&format!("row {expected_row}")),
            "{error}"
        );
        assert_eq!(store.num_chunks(), 0, "a refused chunk leaves no trace");
    }
    let fine = chunk(
        2,
        vec![frame(vec![0, 1])],
        vec![(
            ComponentName::CLEAR_IS_RECURSIVE,
            clears(&[None, Some(vec![Some(false)])]),
        )],
    )
    .unwrap();
    store.insert(fine).unwrap();
    store.sanity_check().unwrap();
}

#[test]
fn insert_rejects_a_clear_that_is_not_boolean() {
    let mut store = ChunkStore::new();
    let err = store
        .insert(
            chunk(
                1,
                vec![frame(vec![1])],
                vec![(ComponentName::CLEAR_IS_RECURSIVE, one_cell())],
            )
            .unwrap(),
        )
        .unwrap_err();
    assert!(matches!(
        err,
        InsertError::ClearNotBoolean {
            data_type: DataType::Float64,
            ..
        }
    ));
    assert_eq!(store.num_chunks(), 0);
    let ok = chunk(
        1,
        vec![frame(vec![1])],
        vec![(ComponentName::CLEAR_IS_RECURSIVE, bool_list(&[Some(true)]))],
    )
    .unwrap();
    store.insert(ok).unwrap();
}

#[test]
fn timestamps_with_any_timezone_are_accepted_and_kept() {
    let times: ArrayRef =
        Arc::new(arrow_array::TimestampNanosecondArray::from(vec![5]).with_timezone("+02:00"));
    let chunk = chunk(
        1,
        vec![(Timeline::new("log_time", TimeType::TimestampNs), times)],
        vec![("c", one_cell())],
    )
    .unwrap();
    let column = chunk.time_column("log_time").unwrap();
    assert_eq!(
        column.data_type(),
        &DataType::Timestamp(TimeUnit::Nanosecond, Some("+02:00".into()))
    );
    let back = Chunk::from_record_batch(&chunk.to_record_batch().unwrap()).unwrap();
    assert_eq!(
        back.time_column("log_time").unwrap().data_type(),
        column.data_type()
    );
}

#[test]
fn inserting_the_same_chunk_twice_changes_nothing() {
    let chunk = Arc::new(scalar("e", "c", 1, 1, 1.0));
    let mut store = ChunkStore::new();
    assert_eq!(store.insert(Arc::clone(&chunk)).unwrap().len(), 1);
    assert!(store.insert(chunk).unwrap().is_empty());
    assert_eq!(store.num_chunks(), 1);
    store.sanity_check().unwrap();
}

#[test]
fn duplicated_row_ids_never_crash() {
    let mut store = ChunkStore::new();
    store
        .insert(scalars(
            "e",
            "c",
            &[
                (1, 7, Some(vec![1.0])),
                (1, 7, Some(vec![2.0])),
                (0, 7, None),
            ],
        ))
        .unwrap();
    store
        .insert(scalars("e", "c", &[(1, 7, Some(vec![3.0]))]))
        .unwrap();
    store.insert(clear("e", Some(1), 7, false)).unwrap();
    store.insert(clear("e", Some(1), 7, false)).unwrap();
    store.sanity_check().unwrap();
    assert!(
        store
            .latest_at(&LatestAtQuery::new("frame", t(1)), &path("e"), "c")
            .is_none(),
        "a clear with an equal index hides"
    );
    let result = store.range(
        &chunkstore::RangeQuery::new("frame", TimeRange::new(t(0), t(5))),
        &path("e"),
        "c",
    );
    assert_eq!(result.iter().count(), 3);
}
