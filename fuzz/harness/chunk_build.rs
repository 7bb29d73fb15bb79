//! The body of the `chunk_build` fuzz target: arbitrary bytes drive the construction of
//! chunks from Arrow arrays, through [`Chunk::try_new`] (whole columns: any timeline type,
//! length, null or reserved time; list columns of several element types, sliced, nested,
//! with null cells, empty cells and null instances, and columns that are not lists) and
//! through [`ChunkBuilder`] (rows naming timelines and components, repeated or with
//! conflicting types). Construction either fails with an error that displays or gives a
//! sane chunk; the chunks, some inserted twice, then go through everything a store does
//! ([`super::lifecycle::exercise`]).

use std::sync::Arc;

use arrow_array::builder::{
    BooleanBuilder, FixedSizeListBuilder, Float32Builder, Float64Builder, Int64Builder,
    ListBuilder, StringBuilder,
};
use arrow_array::types::{DurationNanosecondType, TimestampNanosecondType};
use arrow_array::{
    Array, ArrayRef, BooleanArray, Float64Array, Int32Array, Int64Array, PrimitiveArray,
    StringArray,
};
use chunkstore::{
    Chunk, ChunkBuilder, ChunkError, ChunkId, ComponentDescriptor, EntityPath, RowId, TimeType,
    Timeline,
};

/// Reads the input a byte at a time; past its end, every read is zero.
struct Input<'a>(&'a [u8]);

impl Input<'_> {
    fn byte(&mut self) -> u8 {
        let Some((&first, rest)) = self.0.split_first() else {
            return 0;
        };
        self.0 = rest;
        first
    }

    /// A number below `n` (which is at most 256).
    fn below(&mut self, n: usize) -> usize {
        usize::from(self.byte()) % n
    }

    fn one_in(&mut self, n: usize) -> bool {
        self.below(n) == 0
    }

    /// A time: small, at an extreme (the reserved `i64::MIN` included), or any.
    fn time(&mut self) -> i64 {
        match self.below(8) {
            0 => i64::MIN,
            1 => i64::MIN + 1,
            2 => i64::MAX,
            3 => i64::from_le_bytes([0; 8].map(|_| self.byte())),
            _ => i64::from(self.byte() % 12),
        }
    }

    fn pick<'t, T: ?Sized>(&mut self, table: &[&'t T]) -> &'t T {
        table[self.below(table.len())]
    }
}

const TIMELINES: [&str; 4] = ["frame", "t2", "frame", ""];
const COMPONENTS: [&str; 6] = ["x", "y", "x", "", "Clear:is_recursive", "z"];
const TIME_TYPES: [TimeType; 3] = [
    TimeType::Sequence,
    TimeType::DurationNs,
    TimeType::TimestampNs,
];

pub fn chunk_build(bytes: &[u8]) {
    let mut input = Input(bytes);
    let mut chunks: Vec<Chunk> = Vec::new();
    for _ in 0..=input.below(4) {
        if input.one_in(5)
            && let Some(previous) = chunks.last()
        {
            // The same chunk again, as a second copy read from its transport batch.
            let batch = previous.to_record_batch().expect("a chunk encodes");
            chunks.push(Chunk::from_record_batch(&batch).expect("its batch decodes"));
            continue;
        }
        let built = if input.one_in(2) {
            from_columns(&mut input)
        } else {
            from_rows(&mut input)
        };
        match built {
            Ok(chunk) => {
                chunk.sanity_check().expect("a built chunk is sane");
                chunks.push(chunk);
            }
            Err(error) => assert!(!error.to_string().is_empty(), "an error says what is wrong"),
        }
    }
    super::lifecycle::exercise(chunks);
}

/// Now and then one of a few fixed ids, so that ids repeat; else a fresh one.
fn chunk_id(input: &mut Input<'_>) -> ChunkId {
    if input.one_in(3) {
        ChunkId::from_u128(1 + input.below(3) as u128)
    } else {
        ChunkId::new()
    }
}

fn entity(input: &mut Input<'_>) -> EntityPath {
    let text = input.pick(&["/", "a", "a/b", "a/b/c", "e", "a/b\\/c"]);
    EntityPath::parse(text).expect("the table's paths are valid")
}

/// Row ids that increase, repeat, or jump back.
fn row_ids(input: &mut Input<'_>, num_rows: usize) -> Vec<RowId> {
    let mut next = 100u128;
    (0..num_rows)
        .map(|_| {
            match input.below(4) {
                0 => {}                                        // the same as the last
                1 => next = u128::from(input.byte()),          // anywhere
                _ => next += 1 + u128::from(input.byte() % 3), // forward
            }
            RowId::from_u128(next)
        })
        .collect()
}

/// An array of length about `len`: usually exactly.
fn length(input: &mut Input<'_>, len: usize) -> usize {
    if input.one_in(10) { len + 1 } else { len }
}

fn time_column(input: &mut Input<'_>, num_rows: usize) -> (Timeline, ArrayRef) {
    let name = input.pick(&TIMELINES);
    let len = length(input, num_rows);
    let times: Vec<Option<i64>> = (0..len)
        .map(|_| (!input.one_in(12)).then(|| input.time()))
        .collect();
    let (time_type, array): (TimeType, ArrayRef) = match input.below(5) {
        0 => (TimeType::Sequence, Arc::new(Int64Array::from(times))),
        1 => (
            TimeType::DurationNs,
            Arc::new(PrimitiveArray::<DurationNanosecondType>::from(times)),
        ),
        2 => (
            TimeType::TimestampNs,
            Arc::new(PrimitiveArray::<TimestampNanosecondType>::from(times)),
        ),
        3 => (
            TimeType::TimestampNs,
            Arc::new(
                PrimitiveArray::<TimestampNanosecondType>::from(times).with_timezone("+01:00"),
            ),
        ),
        _ => {
            let small: Vec<Option<i32>> = times
                .iter()
                .map(|t| t.map(|t| i32::try_from(t % 1000).unwrap_or(0)))
                .collect();
            (TimeType::Sequence, Arc::new(Int32Array::from(small)))
        }
    };
    // Now and then a timeline whose type is not its array's.
    let time_type = if input.one_in(10) {
        TIME_TYPES[input.below(3)]
    } else {
        time_type
    };
    (Timeline::new(name, time_type), array)
}

/// A cell's instance count: usually one, sometimes none or several; `None` is a null cell.
fn instances(input: &mut Input<'_>) -> Option<usize> {
    match input.below(8) {
        0 => None,
        1 => Some(0),
        2 => Some(2),
        _ => Some(1),
    }
}

/// A component column of about `num_rows` cells, of one of several shapes.
fn component_column(input: &mut Input<'_>, num_rows: usize) -> ArrayRef {
    let len = length(input, num_rows);
    // A sliced column: built one cell longer, then the first cell cut off.
    let sliced = input.one_in(6);
    let cells = len + usize::from(sliced);
    let column: ArrayRef = match input.below(7) {
        0 | 1 => {
            let mut list = ListBuilder::new(Float64Builder::new());
            for _ in 0..cells {
                let n = instances(input);
                for _ in 0..n.unwrap_or(0) {
                    list.values().append_value(f64::from(input.byte()));
                }
                list.append(n.is_some());
            }
            Arc::new(list.finish())
        }
        2 => {
            let mut list = ListBuilder::new(StringBuilder::new());
            for _ in 0..cells {
                let n = instances(input);
                for _ in 0..n.unwrap_or(0) {
                    list.values().append_value(format!("s{}", input.byte()));
                }
                list.append(n.is_some());
            }
            Arc::new(list.finish())
        }
        3 => {
            let mut list = ListBuilder::new(FixedSizeListBuilder::new(Float32Builder::new(), 3));
            for _ in 0..cells {
                let n = instances(input);
                for _ in 0..n.unwrap_or(0) {
                    let point = list.values();
                    for _ in 0..3 {
                        point.values().append_value(f32::from(input.byte()));
                    }
                    point.append(!input.one_in(8));
                }
                list.append(n.is_some());
            }
            Arc::new(list.finish())
        }
        4 => {
            let mut list = ListBuilder::new(BooleanBuilder::new());
            for _ in 0..cells {
                let n = instances(input);
                for _ in 0..n.unwrap_or(0) {
                    let flag = input.below(3);
                    list.values().append_option((flag < 2).then_some(flag == 1));
                }
                list.append(n.is_some());
            }
            Arc::new(list.finish())
        }
        5 => {
            let mut list = ListBuilder::new(ListBuilder::new(Int64Builder::new()));
            for _ in 0..cells {
                let n = instances(input);
                for _ in 0..n.unwrap_or(0) {
                    let inner = list.values();
                    inner.values().append_value(i64::from(input.byte()));
                    inner.append(true);
                }
                list.append(n.is_some());
            }
            Arc::new(list.finish())
        }
        _ => Arc::new(Int64Array::from_iter_values(
            (0..cells).map(|i| i64::from(i % 100 == 0)),
        )),
    };
    if sliced { column.slice(1, len) } else { column }
}

fn from_columns(input: &mut Input<'_>) -> Result<Chunk, ChunkError> {
    let id = chunk_id(input);
    let entity = entity(input);
    let num_rows = input.below(6);
    let row_ids = row_ids(input, num_rows);
    let time_columns = (0..input.below(3))
        .map(|_| time_column(input, num_rows))
        .collect();
    let components = (0..input.below(4))
        .map(|_| {
            let name = input.pick(&COMPONENTS);
            (
                ComponentDescriptor::new(name),
                component_column(input, num_rows),
            )
        })
        .collect();
    Chunk::try_new(id, entity, row_ids, time_columns, components)
}

/// One cell for the builder: an array of a few values of one of several types.
fn cell(input: &mut Input<'_>) -> ArrayRef {
    let n = instances(input).unwrap_or(1);
    match input.below(4) {
        0 | 1 => Arc::new(Float64Array::from_iter_values(
            (0..n).map(|_| f64::from(input.byte())),
        )),
        2 => Arc::new(StringArray::from_iter_values(
            (0..n).map(|_| format!("s{}", input.byte())),
        )),
        _ => Arc::new(
            (0..n)
                .map(|_| Some(input.one_in(2)))
                .collect::<BooleanArray>(),
        ),
    }
}

fn from_rows(input: &mut Input<'_>) -> Result<Chunk, ChunkError> {
    let mut builder = ChunkBuilder::new(chunk_id(input), entity(input));
    let num_rows = input.below(5);
    for row_id in row_ids(input, num_rows) {
        let times: Vec<(Timeline, i64)> = (0..input.below(3))
            .map(|_| {
                let name = input.pick(&TIMELINES);
                (
                    Timeline::new(name, TIME_TYPES[input.below(3)]),
                    input.time(),
                )
            })
            .collect();
        let cells: Vec<(&str, ArrayRef)> = (0..input.below(4))
            .map(|_| (input.pick(&COMPONENTS), cell(input)))
            .collect();
        builder = builder.with_row(row_id, times, cells);
    }
    builder.build()
}
