//! Unit tests of the chunk's columns and memory figures.

use std::sync::Arc;

use arrow_array::{ArrayRef, ListArray};
use arrow_schema::DataType;

use super::time_column::{guided_partition_point, interpolate};
use super::*;
use crate::ChunkError;

/// A chunk of one `frame` row per cell of `list` (times 0, 1, …), component `x`.
fn try_chunk_of(list: ListArray) -> Result<Chunk, ChunkError> {
    let n = u32::try_from(list.len()).unwrap();
    Chunk::try_new(
        ChunkId::new(),
        EntityPath::parse("a").unwrap(),
        (1..=u128::from(n)).map(RowId::from_u128).collect(),
        vec![(
            Timeline::sequence("frame"),
            Arc::new(arrow_array::Int64Array::from_iter_values(0..i64::from(n))) as ArrayRef,
        )],
        vec![("x".into(), Arc::new(list) as ArrayRef)],
    )
}

/// [`try_chunk_of`] for a valid column.
fn chunk_of(list: ListArray) -> Chunk {
    try_chunk_of(list).unwrap()
}

/// The flag holds exactly when every cell spans one value, a null cell included.
#[test]
fn one_instance_per_row_follows_the_offsets() {
    let list = |offsets: Vec<i32>, nulls: Option<Vec<bool>>| {
        let len = usize::try_from(*offsets.last().unwrap()).unwrap();
        ListArray::new(
            Arc::new(arrow_schema::Field::new_list_field(DataType::Float64, true)),
            arrow_buffer::OffsetBuffer::new(offsets.into()),
            Arc::new(arrow_array::Float64Array::from(vec![1.0; len])),
            nulls.map(arrow_buffer::NullBuffer::from),
        )
    };
    let flag = |l: ListArray| chunk_of(l).components()[0].has_one_instance_per_row();
    assert!(flag(list(vec![0, 1, 2, 3], None)));
    assert!(flag(list(vec![0, 1, 2], Some(vec![true, false]))));
    assert!(!flag(list(vec![0, 1, 3], None)), "a cell of two");
    assert!(!flag(list(vec![0, 1, 1, 2], None)), "an empty cell");
    assert!(
        !flag(list(vec![0, 1, 1], Some(vec![true, false]))),
        "a null spanning none"
    );
}

/// A column knows the bytes of one cell where a latest-at touches cells before reading
/// them (one instance a row of a primitive leaf: scalars, fixed-size lists), and 0 where it
/// touches none; a touch at any row, in the chunk or past it, reads nothing it should not.
#[test]
fn cell_bytes_follow_the_leaf_and_the_offsets() {
    use arrow_array::{FixedSizeListArray, Float32Array, StringArray};
    use arrow_schema::Field;

    let scalars = |offsets: Vec<i32>| {
        let len = usize::try_from(*offsets.last().unwrap()).unwrap();
        ListArray::new(
            Arc::new(Field::new_list_field(DataType::Float64, true)),
            arrow_buffer::OffsetBuffer::new(offsets.into()),
            Arc::new(arrow_array::Float64Array::from(vec![1.0; len])),
            None,
        )
    };
    let positions = {
        let item = Arc::new(Field::new_list_field(DataType::Float32, false));
        let points = FixedSizeListArray::new(
            Arc::clone(&item),
            3,
            Arc::new(Float32Array::from(vec![0.5_f32; 6])),
            None,
        );
        ListArray::new(
            Arc::new(Field::new_list_field(points.data_type().clone(), true)),
            arrow_buffer::OffsetBuffer::new(vec![0, 1, 2].into()),
            Arc::new(points),
            None,
        )
    };
    let texts = ListArray::new(
        Arc::new(Field::new_list_field(DataType::Utf8, true)),
        arrow_buffer::OffsetBuffer::new(vec![0, 1].into()),
        Arc::new(StringArray::from(vec!["a"])),
        None,
    );
    for (list, bytes) in [
        (scalars(vec![0, 1, 2]), 8),
        (positions, 12),
        (scalars(vec![0, 2]), 0),
        (texts, 0),
    ] {
        let chunk = chunk_of(list);
        let column = &chunk.components()[0];
        assert_eq!(column.cell_bytes, bytes, "{:?}", column.list.data_type());
        for row in [0, 1, 2, 1_000, usize::MAX] {
            column.touch_cell(row);
        }
        chunk.sanity_check().unwrap();
    }
}

/// Scalars and fixed-size lists read as slices of the right cells, through slicing at
/// every level; nulls, other types and other widths read as `None`.
#[test]
fn primitive_and_fixed_size_values_read_the_cells() {
    use arrow_array::types::{Float32Type, Float64Type, Int64Type};
    use arrow_array::{FixedSizeListArray, Float32Array, Float64Array};
    use arrow_schema::Field;

    // Cells [1.0, 2.0], null, [], [4.0], sliced out of a longer values array.
    let values = Float64Array::from(vec![9.0, 1.0, 2.0, 3.0, 4.0]).slice(1, 4);
    let scalars = ListArray::new(
        Arc::new(Field::new_list_field(DataType::Float64, true)),
        arrow_buffer::OffsetBuffer::new(vec![0, 2, 3, 3, 4].into()),
        Arc::new(values),
        Some(arrow_buffer::NullBuffer::from(vec![
            true, false, true, true,
        ])),
    );
    let chunk = chunk_of(scalars);
    let column = &chunk.components()[0];
    assert_eq!(
        column.primitive_values::<Float64Type>(0),
        Some(&[1.0, 2.0][..])
    );
    assert_eq!(
        column.primitive_values::<Float64Type>(1),
        None,
        "a null cell"
    );
    assert_eq!(column.primitive_values::<Float64Type>(2), Some(&[][..]));
    assert_eq!(column.primitive_values::<Float64Type>(3), Some(&[4.0][..]));
    assert_eq!(
        column.primitive_values::<Float64Type>(4),
        None,
        "out of bounds"
    );
    assert_eq!(
        column.primitive_values::<Int64Type>(0),
        None,
        "another type"
    );
    assert_eq!(
        column.fixed_size_values::<Float64Type, 1>(0),
        None,
        "another shape"
    );
    assert_eq!(
        chunk_of_points_1().components()[0].primitive_values::<Float64Type>(0),
        None
    );

    // Points [0,1,2] | [3,4,5] [6,7,8], the list itself sliced past a first cell.
    let floats = Float32Array::from_iter_values((0..12u8).map(f32::from));
    let xyz = FixedSizeListArray::new(
        Arc::new(Field::new_list_field(DataType::Float32, false)),
        3,
        Arc::new(floats),
        None,
    );
    let points = ListArray::new(
        Arc::new(Field::new_list_field(xyz.data_type().clone(), false)),
        arrow_buffer::OffsetBuffer::new(vec![0, 1, 3, 4].into()),
        Arc::new(xyz),
        None,
    )
    .slice(1, 2);
    let chunk = chunk_of(points);
    let column = &chunk.components()[0];
    assert_eq!(
        column.fixed_size_values::<Float32Type, 3>(0),
        Some(&[[3.0, 4.0, 5.0], [6.0, 7.0, 8.0]][..])
    );
    assert_eq!(
        column.fixed_size_values::<Float32Type, 3>(1),
        Some(&[[9.0, 10.0, 11.0]][..])
    );
    assert_eq!(column.fixed_size_values::<Float32Type, 2>(0), None);
    assert_eq!(column.fixed_size_values::<Float32Type, 0>(0), None);
    assert_eq!(column.primitive_values::<Float32Type>(0), None);
    chunk.sanity_check().unwrap();
}

/// With one instance per row a cell is found without the offsets; the list's own first
/// offset still counts (a sliced list), and so do null cells and the bounds.
#[test]
fn one_instance_cells_read_past_a_sliced_lists_first_offset() {
    use arrow_array::types::{Float32Type, Float64Type};
    use arrow_array::{FixedSizeListArray, Float32Array, Float64Array};
    use arrow_schema::Field;

    // Cells [10] [11] null [13] [14], then sliced to rows 1..5: the first offset is 1.
    let scalars = ListArray::new(
        Arc::new(Field::new_list_field(DataType::Float64, true)),
        arrow_buffer::OffsetBuffer::new(vec![0, 1, 2, 3, 4, 5].into()),
        Arc::new(Float64Array::from(vec![10.0, 11.0, 12.0, 13.0, 14.0])),
        Some(arrow_buffer::NullBuffer::from(vec![
            true, true, false, true, true,
        ])),
    )
    .slice(1, 4);
    let chunk = chunk_of(scalars);
    let column = &chunk.components()[0];
    assert!(column.has_one_instance_per_row());
    assert_eq!(column.primitive_values::<Float64Type>(0), Some(&[11.0][..]));
    assert_eq!(column.primitive_values::<Float64Type>(1), None, "a null");
    assert_eq!(column.primitive_values::<Float64Type>(3), Some(&[14.0][..]));
    assert_eq!(
        column.primitive_values::<Float64Type>(4),
        None,
        "past the end"
    );
    assert_eq!(column.leaf_bytes(2), Some(&13.0f64.to_le_bytes()[..]));

    // Points [0,1,2] [3,4,5] [6,7,8], sliced past the first.
    let xyz = FixedSizeListArray::new(
        Arc::new(Field::new_list_field(DataType::Float32, false)),
        3,
        Arc::new(Float32Array::from_iter_values((0..9u8).map(f32::from))),
        None,
    );
    let points = ListArray::new(
        Arc::new(Field::new_list_field(xyz.data_type().clone(), false)),
        arrow_buffer::OffsetBuffer::new(vec![0, 1, 2, 3].into()),
        Arc::new(xyz),
        None,
    )
    .slice(1, 2);
    let chunk = chunk_of(points);
    let column = &chunk.components()[0];
    assert!(column.has_one_instance_per_row());
    assert_eq!(
        column.fixed_size_values::<Float32Type, 3>(1),
        Some(&[[6.0, 7.0, 8.0]][..])
    );
    chunk.sanity_check().unwrap();
}

/// One cell holding one fixed-size list of one `Float64`.
fn chunk_of_points_1() -> Chunk {
    let xyz = arrow_array::FixedSizeListArray::new(
        Arc::new(arrow_schema::Field::new_list_field(
            DataType::Float64,
            false,
        )),
        1,
        Arc::new(arrow_array::Float64Array::from(vec![1.0])),
        None,
    );
    chunk_of(ListArray::new(
        Arc::new(arrow_schema::Field::new_list_field(
            xyz.data_type().clone(),
            false,
        )),
        arrow_buffer::OffsetBuffer::new(vec![0, 1].into()),
        Arc::new(xyz),
        None,
    ))
}

/// A chunk built from arrays nobody else holds owns its buffers, although its columns
/// keep second handles on their leaf values; one whose arrays are also held elsewhere
/// does not.
#[test]
fn a_chunk_owns_buffers_only_nobody_else_holds() {
    let list = || {
        ListArray::new(
            Arc::new(arrow_schema::Field::new_list_field(DataType::Float64, true)),
            arrow_buffer::OffsetBuffer::new(vec![0, 1, 2].into()),
            Arc::new(arrow_array::Float64Array::from(vec![1.0, 2.0])),
            None,
        )
    };
    let alone = chunk_of(list());
    assert!(alone.components()[0].leaf.is_some());
    assert!(alone.owns_all_buffers_now());
    assert!(alone.owns_all_buffers());

    let shared = list();
    let sharing = chunk_of(shared.clone());
    assert!(!sharing.owns_all_buffers_now());
    assert!(!sharing.owns_all_buffers());
    drop(shared);
    assert!(sharing.owns_all_buffers_now(), "the other holder is gone");
}

/// The memory figures read from typed arrays equal those of Arrow's generic
/// `ArrayData` tree, for lists of primitives and of fixed-size lists of them, with
/// nulls at every level, sliced, and with item fields no other chunk shares.
#[test]
fn typed_memory_figures_equal_the_generic_ones() {
    use arrow_array::{FixedSizeListArray, Float32Array, Int16Array};
    use arrow_buffer::{NullBuffer, OffsetBuffer};
    use arrow_schema::Field;

    let nulls = |bits: &[bool]| Some(NullBuffer::from(bits.to_vec()));
    let primitive = |leaf_nulls: Option<NullBuffer>| {
        Arc::new(Int16Array::new(vec![1, 2, 3, 4, 5, 6].into(), leaf_nulls)) as ArrayRef
    };
    let points = |point_nulls: Option<NullBuffer>, leaf_nulls: Option<NullBuffer>| {
        let leaf = Float32Array::new((0..12u8).map(f32::from).collect(), leaf_nulls);
        Arc::new(FixedSizeListArray::new(
            Arc::new(Field::new_list_field(DataType::Float32, true)),
            2,
            Arc::new(leaf),
            point_nulls,
        )) as ArrayRef
    };
    let list = |items: ArrayRef, list_nulls: Option<NullBuffer>, field_name: &str| {
        ListArray::new(
            Arc::new(Field::new(field_name, items.data_type().clone(), true)),
            OffsetBuffer::new(vec![0, 2, 3, 3, 6].into()),
            items,
            list_nulls,
        )
    };
    let some = [true, false, true, true];
    let lists = vec![
        list(primitive(None), None, "item"),
        list(
            primitive(nulls(&[true, false, true, true, false, true])),
            nulls(&some),
            "item",
        ),
        list(points(None, None), None, "item"),
        list(
            points(
                nulls(&[true, true, false, true, true, true]),
                nulls(&[true; 12]),
            ),
            nulls(&some),
            "item",
        ),
        // Not the shared item field: the chunk owns its own.
        list(primitive(None), None, "unshared"),
        list(points(None, None), nulls(&some), "unshared").slice(1, 3),
        list(primitive(None), None, "item").slice(2, 2),
    ];
    for list in lists {
        let chunk = chunk_of(list);
        assert!(chunk.components()[0].leaf.is_some());
        let (typed, generic) = (
            memory::ChunkMemory::of(&chunk),
            memory::ChunkMemory::compute(&chunk, true),
        );
        assert_eq!(
            (
                typed.own_bytes,
                typed.payload_bytes,
                typed.buffer_bytes,
                typed.buffers.len()
            ),
            (
                generic.own_bytes,
                generic.payload_bytes,
                generic.buffer_bytes,
                generic.buffers.len()
            ),
            "{:?}",
            chunk.components()[0].list_array().data_type()
        );
        chunk.sanity_check().unwrap();
    }
}

/// A slice of a chunk (a piece of a split) weighs what a copy of its rows weighs: only the
/// part of each list's child that its cells reference counts, at every level of nesting,
/// whichever path (typed or Arrow's generic tree) computes it.
#[test]
fn a_slice_weighs_what_a_copy_of_its_rows_weighs() {
    use arrow_array::{FixedSizeListArray, Float32Array, Int16Array, Int32Array, StringArray};
    use arrow_buffer::{NullBuffer, OffsetBuffer};
    use arrow_schema::Field;

    let list = |items: ArrayRef, offsets: Vec<i32>| {
        ListArray::new(
            Arc::new(Field::new_list_field(items.data_type().clone(), true)),
            OffsetBuffer::new(offsets.into()),
            items,
            None,
        )
    };
    let offsets = || vec![0, 2, 3, 3, 6];
    let int16 = Arc::new(Int16Array::from(vec![1, 2, 3, 4, 5, 6])) as ArrayRef;
    let int16_nulls = Arc::new(Int16Array::new(
        vec![1, 2, 3, 4, 5, 6].into(),
        Some(NullBuffer::from(vec![true, false, false, true, true, true])),
    )) as ArrayRef;
    let points = Arc::new(FixedSizeListArray::new(
        Arc::new(Field::new_list_field(DataType::Float32, true)),
        2,
        Arc::new(Float32Array::from_iter_values((0..12u8).map(f32::from))),
        None,
    )) as ArrayRef;
    let text = Arc::new(StringArray::from(vec!["a", "bb", "ccc", "dddd", "e", "ff"])) as ArrayRef;
    let nested = Arc::new(list(
        Arc::new(Int32Array::from_iter_values(0..12)),
        vec![0, 1, 3, 6, 6, 10, 12],
    )) as ArrayRef;
    for items in [int16, int16_nulls, points, text, nested] {
        let whole = chunk_of(list(items, offsets()));
        let slice = whole.slice(1, 2).unwrap();
        let copy = Chunk::gather(&[&whole], &[(0, 1), (0, 2)]).unwrap();
        let data_type = whole.components()[0].list_array().data_type().clone();
        assert_eq!(slice.payload_bytes(), copy.payload_bytes(), "{data_type:?}");
        assert!(
            slice.payload_bytes() < whole.payload_bytes(),
            "{data_type:?}"
        );
        assert_eq!(
            memory::ChunkMemory::compute(&slice, true).payload_bytes,
            slice.payload_bytes(),
            "{data_type:?}"
        );
        slice.sanity_check().unwrap();
    }
}

/// The guided search finds exactly the partition point a binary search finds, for
/// evenly spread, clustered, duplicated and extreme times, and targets inside, between
/// and beyond them.
#[test]
fn guided_partition_point_agrees_with_a_binary_search() {
    let mut state = 7u64;
    let mut random = move |n: u64| {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1);
        (state >> 33) % n
    };
    let shapes: Vec<Vec<i64>> = vec![
        (0..1000).collect(),
        (0..1000).map(|i| i / 10).collect(),
        (0..200)
            .map(|i| if i < 190 { i } else { 1_000_000 + i })
            .collect(),
        (0..300).map(|i| i * i * i).collect(),
        vec![i64::MIN + 1, -5, 0, 0, 0, 3, i64::MAX - 1]
            .into_iter()
            .chain(std::iter::repeat_n(i64::MAX, 40))
            .collect(),
        {
            let mut v: Vec<i64> = (0..500)
                .map(|_| random(10_000).cast_signed() - 5_000)
                .collect();
            v.sort_unstable();
            v
        },
    ];
    for times in shapes {
        let range = (
            TimeInt::saturating(times[0]),
            TimeInt::saturating(*times.last().unwrap()),
        );
        let targets = times
            .iter()
            .flat_map(|&t| [t.saturating_sub(1), t, t.saturating_add(1)])
            .chain([i64::MIN, i64::MAX, 0]);
        for target in targets {
            for strict in [false, true] {
                let holds = |time: i64| {
                    if strict {
                        time < target
                    } else {
                        time <= target
                    }
                };
                assert_eq!(
                    guided_partition_point(times.len(), range, target, |p| times[p], holds, |_| {}),
                    times.partition_point(|&time| holds(time)),
                    "target {target}, strict {strict}"
                );
            }
        }
    }
}

/// The guided search's guess is `offset * last / span` rounded down, exactly, whether the
/// product fits in 64 bits (one division instruction) or not (128-bit arithmetic): spans
/// and offsets at every edge of the two, the greatest row counts and the widest times.
#[test]
fn the_guess_is_the_exact_quotient_on_both_sides_of_64_bits() {
    let wide = |offset: i128, last: usize, span: i128| {
        usize::try_from(offset * i128::try_from(last).unwrap() / span).unwrap()
    };
    let spans = [
        1_i128,
        2,
        999,
        i128::from(u32::MAX),
        i128::from(u32::MAX) + 1,
        i128::from(u64::MAX / 3),
        i128::from(i64::MAX),
        i128::from(u64::MAX),
    ];
    let lasts = [0_usize, 1, 31, 99, 65_535, u32::MAX as usize];
    for span in spans {
        for last in lasts {
            for offset in [0, 1, span / 3, span / 2, span - 1, span] {
                assert_eq!(
                    interpolate(offset, last, span),
                    wide(offset, last, span),
                    "offset {offset}, last {last}, span {span}"
                );
            }
        }
    }
}

/// A slice past the end names the problem; so does an empty one.
#[test]
fn a_slice_out_of_range_is_named_as_such() {
    let chunk = chunk_of_points_1();
    let rows = chunk.num_rows();
    assert!(chunk.slice(0, rows).is_ok());
    for (offset, len) in [(0, rows + 1), (rows, 1), (usize::MAX, 2), (0, 0)] {
        let error = chunk.slice(offset, len).unwrap_err();
        assert!(
            matches!(error, ChunkError::SliceOutOfRange { num_rows, .. } if num_rows == rows),
            "{offset}+{len}: {error}"
        );
    }
}

/// `is_valid` answers for any row: a row past the end holds no cell.
#[test]
fn is_valid_is_false_past_the_last_row() {
    let chunk = chunk_of_points_1();
    let column = &chunk.components()[0];
    assert!(column.is_valid(0));
    assert!(!column.is_valid(chunk.num_rows()));
    assert!(!column.is_valid(usize::MAX));
}

/// A merge's value-by-value copy of one-instance cells gives exactly what Arrow's
/// interleave gives, through sliced sources, null cells and fixed-size items; any other
/// shape is left to interleave.
#[test]
fn single_values_gather_equals_interleave() {
    use arrow_array::{Array, FixedSizeListArray, Float32Array, Float64Array, StringArray};
    use arrow_buffer::{NullBuffer, OffsetBuffer};
    use arrow_schema::Field;

    use super::rewrite::gather_single_values;

    let scalar_list = |values: Vec<Option<f64>>, offsets: Vec<i32>, nulls: Option<Vec<bool>>| {
        ListArray::new(
            Arc::new(Field::new_list_field(DataType::Float64, true)),
            OffsetBuffer::new(offsets.into()),
            Arc::new(Float64Array::from(values)),
            nulls.map(NullBuffer::from),
        )
    };
    let both = |lists: Vec<ListArray>, rows: &[(usize, usize)]| {
        let chunks: Vec<Chunk> = lists.into_iter().map(chunk_of).collect();
        let columns: Vec<&ComponentColumn> = chunks.iter().map(|c| &c.components()[0]).collect();
        let fast = gather_single_values(&columns, rows).map(|array| array.unwrap().to_data());
        let lists: Vec<&dyn Array> = columns
            .iter()
            .map(|c| c.list_array() as &dyn Array)
            .collect();
        let slow = arrow_select::interleave::interleave(&lists, rows)
            .unwrap()
            .to_data();
        (fast, slow)
    };

    // Scalars: one source sliced (its first offset is 2), one with a null cell.
    let sliced = scalar_list(
        vec![Some(7.0), Some(8.0), Some(1.0), Some(2.0), Some(3.0)],
        vec![0, 1, 2, 3, 4, 5],
        None,
    )
    .slice(2, 3);
    let with_null = scalar_list(
        vec![Some(10.0), Some(0.0), Some(12.0)],
        vec![0, 1, 2, 3],
        Some(vec![true, false, true]),
    );
    let rows = [(1, 2), (0, 0), (1, 1), (0, 2), (1, 0), (0, 1)];
    let (fast, slow) = both(vec![sliced.clone(), with_null.clone()], &rows);
    assert_eq!(fast.as_ref(), Some(&slow));
    assert_eq!(fast.unwrap().nulls().map(NullBuffer::null_count), Some(1));

    // Fixed-size lists of three floats (positions).
    let positions = |n: i32| {
        let items = FixedSizeListArray::new(
            Arc::new(Field::new_list_field(DataType::Float32, true)),
            3,
            Arc::new(Float32Array::from_iter_values(
                (0..3 * n).map(|v| f32::from(u8::try_from(v).unwrap())),
            )),
            None,
        );
        ListArray::new(
            Arc::new(Field::new_list_field(items.data_type().clone(), true)),
            OffsetBuffer::from_lengths(std::iter::repeat_n(1, usize::try_from(n).unwrap())),
            Arc::new(items),
            None,
        )
    };
    let (fast, slow) = both(vec![positions(2), positions(3)], &[(1, 2), (0, 1), (1, 0)]);
    assert_eq!(fast, Some(slow));

    // Shapes the copy leaves to interleave (which still answers).
    let null_instance = scalar_list(vec![Some(1.0), None], vec![0, 1, 2], None);
    let (fast, _) = both(vec![sliced.clone(), null_instance], &[(1, 0), (0, 0)]);
    assert!(fast.is_none(), "a null instance");
    let two_in_a_cell = scalar_list(vec![Some(1.0), Some(2.0)], vec![0, 2], None);
    let (fast, _) = both(vec![with_null, two_in_a_cell], &[(1, 0), (0, 0)]);
    assert!(fast.is_none(), "a cell of two instances");
    let strings = ListArray::new(
        Arc::new(Field::new_list_field(DataType::Utf8, true)),
        OffsetBuffer::from_lengths([1, 1]),
        Arc::new(StringArray::from(vec!["a", "b"])),
        None,
    );
    let (fast, slow) = both(vec![strings], &[(0, 1), (0, 0)]);
    assert!(fast.is_none(), "strings");
    assert_eq!(slow.len(), 2);
}

/// A column may not describe more values than its buffers could hold: offsets spanning a
/// million values of a type without data (empty structs, nulls, also under a fixed-size
/// list) are refused, the same shapes at one value a row are not, and booleans (8 to a
/// byte) are not.
#[test]
fn values_without_bytes_are_refused() {
    use arrow_array::{BooleanArray, FixedSizeListArray, NullArray, StructArray, new_null_array};
    use arrow_buffer::OffsetBuffer;
    use arrow_schema::{Field, Fields};

    let build = |items: ArrayRef, lengths: &[usize]| {
        let field = Arc::new(Field::new_list_field(items.data_type().clone(), true));
        let offsets = OffsetBuffer::from_lengths(lengths.iter().copied());
        try_chunk_of(ListArray::new(field, offsets, items, None))
    };
    let empty_structs = |n: usize| Arc::new(StructArray::new_empty_fields(n, None)) as ArrayRef;
    let nulls = |n: usize| Arc::new(NullArray::new(n)) as ArrayRef;
    let unbacked = |result: Result<Chunk, ChunkError>| {
        matches!(result, Err(ChunkError::UnbackedValues { ref component, values, .. })
            if component == "x" && values > 1_000_000)
    };

    assert!(unbacked(build(empty_structs(1_000_000), &[1_000_000])));
    assert!(unbacked(build(nulls(1_000_001), &[1, 1_000_000])));
    // A million nulls as one fixed-size item.
    let fixed = FixedSizeListArray::new(
        Arc::new(Field::new_list_field(DataType::Null, true)),
        1_000_000,
        nulls(1_000_000),
        None,
    );
    assert!(unbacked(build(Arc::new(fixed), &[1])));
    // Structs of a field that takes no bytes either.
    let struct_of_nulls = StructArray::new(
        Fields::from(vec![Field::new("n", DataType::Null, true)]),
        vec![new_null_array(&DataType::Null, 1_000_000)],
        None,
    );
    assert!(unbacked(build(Arc::new(struct_of_nulls), &[1_000_000])));

    // One value a row, of any type, and booleans at eight to a byte, are fine.
    assert!(build(empty_structs(3), &[1, 1, 1]).is_ok());
    // Accepted whole, a chunk stays splittable and mergeable, though a piece holds most of
    // its values in few rows and a copy of it has far fewer bytes of offsets (found by
    // fuzzing: `tests/fuzz_crashes/ipc_insert/slice_of_unbacked_like_values_refused`).
    // 100 rows: 404 bytes of offsets allow 3,232 + 100 values.
    let mut lengths = vec![0; 100];
    lengths[1] = 3_200;
    let whole = build(nulls(3_200), &lengths).unwrap();
    let piece = whole.slice(0, 3).unwrap();
    assert_eq!(piece.num_rows(), 3);
    assert!(Chunk::gather(&[&whole, &piece], &[(1, 1), (0, 1), (1, 2)]).is_ok());
    assert!(build(nulls(2), &[1, 0, 1]).is_ok());
    let booleans = BooleanArray::from(vec![true; 80_000]);
    assert!(build(Arc::new(booleans), &[40_000, 40_000]).is_ok());
    // The message names the column and the figures.
    let message = build(empty_structs(1_000_000), &[1_000_000])
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("\"x\"") && message.contains("1000001 values"),
        "{message}"
    );
}

proptest::proptest! {
    // Its seeds beside every other property test's (`tests/core/seeds.rs`).
    #![proptest_config(proptest::test_runner::Config {
        failure_persistence: Some(Box::new(proptest::test_runner::FileFailurePersistence::Direct(
            "tests/proptest-regressions/lib/chunk.txt",
        ))),
        ..proptest::test_runner::Config::default()
    })]

    /// What a chunk derives from rows in `(time, row id)` or row-id order by shortcut (the
    /// time range from the ends, each component's bounds from its first and last non-null
    /// cells, the best cell as the last non-null one, the row-id range) equals what reading
    /// every row gives, whatever the order, ties and nulls: `sanity_check` recomputes each
    /// by a scan.
    #[test]
    fn shortcuts_for_sorted_rows_agree_with_scans(
        rows in proptest::collection::vec(
            (0i64..4, 0u128..4, proptest::option::of(0.0f64..1.0)),
            1..12,
        ),
        order in 0u8..3,
    ) {
        let mut rows = rows;
        match order {
            0 => rows.sort_by_key(|&(time, id, _)| (time, id)),
            1 => rows.sort_by_key(|&(_, id, _)| id),
            _ => {}
        }
        let chunk = Chunk::try_new(
            ChunkId::new(),
            EntityPath::parse("a").unwrap(),
            rows.iter().map(|&(_, id, _)| RowId::from_u128(id + 1)).collect(),
            vec![(
                Timeline::sequence("frame"),
                Arc::new(arrow_array::Int64Array::from_iter_values(
                    rows.iter().map(|&(time, _, _)| time),
                )) as ArrayRef,
            )],
            vec![(
                "x".into(),
                Arc::new(ListArray::from_iter_primitive::<
                    arrow_array::types::Float64Type,
                    _,
                    _,
                >(rows.iter().map(|&(_, _, value)| value.map(|v| vec![Some(v)]))))
                    as ArrayRef,
            )],
        )
        .unwrap();
        chunk.sanity_check().unwrap();
    }
}

/// A query's reads of a chunk (its columns, row ids, flags and first time column's times,
/// range and order) stay in the first 128 bytes of the chunk's `Arc` allocation, and a
/// cell's read of its column (the list, the shape flag, the leaf) in the column's first
/// 152: a field added in front of them would cost every query another cache miss.
#[test]
fn a_query_reads_the_front_of_a_chunk_and_of_its_columns() {
    use std::mem::offset_of;

    use super::{ComponentColumn, TimeColumn};

    let chunk = chunk_of(ListArray::new(
        Arc::new(arrow_schema::Field::new_list_field(DataType::Float64, true)),
        arrow_buffer::OffsetBuffer::new(vec![0, 1].into()),
        Arc::new(arrow_array::Float64Array::from(vec![1.0])),
        None,
    ));
    let arc_counts = 2 * size_of::<usize>();
    let start = std::ptr::from_ref(&chunk) as usize;
    let first_time_column = chunk.time_columns.as_ptr() as usize - start;
    let hot_chunk_end = arc_counts
        + first_time_column
        + [
            offset_of!(TimeColumn, times) + size_of::<arrow_buffer::ScalarBuffer<i64>>(),
            offset_of!(TimeColumn, time_range) + size_of::<crate::TimeRange>(),
            offset_of!(TimeColumn, index_order) + size_of::<Option<Box<[u32]>>>(),
        ]
        .into_iter()
        .max()
        .unwrap();
    assert!(hot_chunk_end <= 128, "{hot_chunk_end}");
    for end in [
        offset_of!(Chunk, components) + size_of::<Vec<ComponentColumn>>(),
        offset_of!(Chunk, row_ids) + size_of::<Box<[RowId]>>(),
        offset_of!(Chunk, has_clears) + 1,
    ] {
        assert!(arc_counts + end <= 64, "{end}");
    }
    let hot_column_end = [
        offset_of!(ComponentColumn, list) + size_of::<ListArray>(),
        offset_of!(ComponentColumn, one_instance_per_row) + 1,
        offset_of!(ComponentColumn, leaf)
            + size_of::<Option<super::component_column::PrimitiveLeaf>>(),
    ]
    .into_iter()
    .max()
    .unwrap();
    assert!(hot_column_end <= 152, "{hot_column_end}");
}

/// The inline type comparisons agree with `DataType`'s: variants alone decide only for
/// types without parameters; a list's field shared by pointer is equal.
#[test]
fn inline_type_comparisons_agree_with_data_types() {
    use arrow_schema::{Field, TimeUnit};

    use super::data_types::same_data_type;
    let item = Arc::new(Field::new("item", DataType::Float32, true));
    let types = [
        DataType::Null,
        DataType::Boolean,
        DataType::Int32,
        DataType::Int64,
        DataType::UInt8,
        DataType::Float32,
        DataType::Float64,
        DataType::Utf8,
        DataType::LargeUtf8,
        DataType::Binary,
        DataType::Date32,
        DataType::Timestamp(TimeUnit::Nanosecond, None),
        DataType::Timestamp(TimeUnit::Millisecond, None),
        DataType::Timestamp(TimeUnit::Nanosecond, Some("UTC".into())),
        DataType::FixedSizeBinary(16),
        DataType::FixedSizeBinary(8),
        DataType::List(Arc::clone(&item)),
        DataType::List(Arc::new(Field::new("item", DataType::Float32, true))),
        DataType::List(Arc::new(Field::new("item", DataType::Float64, true))),
        // Equal to the lists of `item` but for the field's name and nullability.
        DataType::List(Arc::new(Field::new("element", DataType::Float32, false))),
        DataType::FixedSizeList(Arc::clone(&item), 3),
        DataType::FixedSizeList(Arc::clone(&item), 2),
    ];
    for a in &types {
        for b in &types {
            assert_eq!(same_data_type(a, b), a == b, "{a} against {b}");
            assert_eq!(
                equal_element_types(a, b),
                a.equals_datatype(b),
                "{a} against {b}"
            );
        }
    }
    let shared = DataType::List(Arc::clone(&item));
    assert!(same_data_type(&shared, &DataType::List(item)));
}
