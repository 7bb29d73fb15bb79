//! The data generator shared by the criterion benches and `examples/workloads.rs`: the
//! random numbers, component columns and chunk shapes of `../shared/bench/WORKLOADS.md`,
//! and the small readers that take a query's answer back out of Arrow.
//!
//! Everything here goes through the crate's public API only, as an embedding application
//! would.
#![allow(
    dead_code,
    reason = "each bench and the workloads example use a part of it"
)]
#![allow(
    clippy::expect_used,
    reason = "generated data is valid; a failure should stop loudly"
)]

use std::sync::Arc;

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type};
use arrow_array::{
    Array, ArrayRef, BooleanArray, FixedSizeListArray, Float32Array, Float64Array, Int64Array,
    ListArray, StringArray,
};
use arrow_buffer::OffsetBuffer;
use arrow_schema::{DataType, Field};
use chunkstore::{
    Chunk, ChunkId, ChunkStore, ComponentColumn, ComponentName, DataframeQuery, EntityPath,
    LatestAtQuery, RangeResult, RangeRun, RowId, StoreConfig, StoreView, TimeInt, Timeline,
};

/// The timeline every workload logs on.
pub const FRAME: &str = "frame";
/// `FixedSizeList<Float32, 3>` instances.
pub const POSITION3D: &str = "position3d";
/// One `Float64` instance per row.
pub const SCALAR: &str = "scalar";
/// One `Utf8` instance per row.
pub const TEXT: &str = "text";

/// WORKLOADS.md's random numbers: `SplitMix64`, seeded with 42.
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A fresh generator, as each workload creates at its start.
    pub fn new() -> Self {
        Self(42)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// `next() % n`.
    pub fn uniform(&mut self, n: u64) -> u64 {
        self.next_u64() % n
    }

    /// `uniform(n)` as an index or a time.
    #[expect(clippy::cast_possible_truncation, reason = "n fits the target type")]
    pub fn uniform_usize(&mut self, n: usize) -> usize {
        self.uniform(n as u64) as usize
    }

    /// A permutation of `0..n`: Fisher-Yates from the identity.
    #[expect(clippy::cast_possible_wrap, reason = "n < 2^63")]
    pub fn permutation(&mut self, n: usize) -> Vec<i64> {
        let mut v: Vec<i64> = (0..n as i64).collect();
        for i in (1..n).rev() {
            let j = self.uniform_usize(i + 1);
            v.swap(i, j);
        }
        v
    }
}

/// Row ids increasing in the order chunks are built (which is the order they are
/// inserted): one fresh id, then its successors.
pub struct RowIds(RowId);

impl RowIds {
    /// Starts after every id generated so far in this process.
    pub fn new() -> Self {
        Self(RowId::new())
    }

    /// The next `n` ids.
    pub fn take(&mut self, n: usize) -> Vec<RowId> {
        (0..n)
            .map(|_| {
                let id = self.0;
                self.0 = id.next();
                id
            })
            .collect()
    }
}

/// Entity paths `name(0)`, `name(1)`, ...
pub fn entities(n: usize, name: impl Fn(usize) -> String) -> Vec<EntityPath> {
    (0..n)
        .map(|i| EntityPath::parse(&name(i)).expect("generated paths are valid"))
        .collect()
}

/// A `List` column of `rows` cells of `per_row` instances each.
fn list_column(values: ArrayRef, per_row: usize, rows: usize) -> ArrayRef {
    let field = Arc::new(Field::new_list_field(values.data_type().clone(), true));
    let offsets = OffsetBuffer::from_lengths(std::iter::repeat_n(per_row, rows));
    Arc::new(ListArray::new(field, offsets, values, None))
}

/// A `position3d` column: `rows` cells of `per_row` points, `point(row, instance)` each.
pub fn positions(
    rows: usize,
    per_row: usize,
    point: impl Fn(usize, usize) -> [f32; 3],
) -> ArrayRef {
    let mut flat = Vec::with_capacity(rows * per_row * 3);
    for r in 0..rows {
        for k in 0..per_row {
            flat.extend_from_slice(&point(r, k));
        }
    }
    let item = Arc::new(Field::new_list_field(DataType::Float32, false));
    let xyz = FixedSizeListArray::new(item, 3, Arc::new(Float32Array::from(flat)), None);
    list_column(Arc::new(xyz), per_row, rows)
}

/// A `scalar` column: one value per row.
pub fn scalars(values: Vec<f64>) -> ArrayRef {
    let rows = values.len();
    list_column(Arc::new(Float64Array::from(values)), 1, rows)
}

/// A `text` column: one string per row.
pub fn texts(values: Vec<String>) -> ArrayRef {
    let rows = values.len();
    list_column(Arc::new(StringArray::from(values)), 1, rows)
}

/// A chunk on the `frame` sequence timeline (`frames` need not be sorted).
pub fn temporal_chunk(
    ids: &mut RowIds,
    entity: &EntityPath,
    frames: Vec<i64>,
    columns: Vec<(&str, ArrayRef)>,
) -> Arc<Chunk> {
    let row_ids = ids.take(frames.len());
    let times: ArrayRef = Arc::new(Int64Array::from(frames));
    Arc::new(Chunk::new(
        ChunkId::new(),
        entity.clone(),
        row_ids,
        vec![(Timeline::sequence(FRAME), times)],
        columns.into_iter().map(|(c, a)| (c.into(), a)).collect(),
    ))
}

/// A static chunk: no timeline.
pub fn static_chunk(
    ids: &mut RowIds,
    entity: &EntityPath,
    columns: Vec<(&str, ArrayRef)>,
) -> Arc<Chunk> {
    let row_ids = ids.take(columns[0].1.len());
    Arc::new(Chunk::new(
        ChunkId::new(),
        entity.clone(),
        row_ids,
        Vec::new(),
        columns.into_iter().map(|(c, a)| (c.into(), a)).collect(),
    ))
}

/// A Clear at `frame` on `entity`: recursive (the subtree) or flat (the entity alone).
pub fn clear_chunk(
    ids: &mut RowIds,
    entity: &EntityPath,
    frame: i64,
    recursive: bool,
) -> Arc<Chunk> {
    let flag = Arc::new(BooleanArray::from(vec![recursive])) as ArrayRef;
    temporal_chunk(
        ids,
        entity,
        vec![frame],
        vec![(ComponentName::CLEAR_IS_RECURSIVE, list_column(flag, 1, 1))],
    )
}

/// The range of instances of cell `row` in a `List` column.
fn instances(list: &ListArray, row: usize) -> std::ops::Range<usize> {
    let offsets = list.value_offsets();
    #[expect(clippy::cast_sign_loss, reason = "list offsets are non-negative")]
    let range = offsets[row] as usize..offsets[row + 1] as usize;
    range
}

/// The first `scalar` instance of a cell.
pub fn first_f64(column: &ComponentColumn, row: usize) -> Option<f64> {
    column
        .primitive_values::<Float64Type>(row)?
        .first()
        .copied()
}

/// The `position3d` instances of a cell, as `[x, y, z]` (empty if the cell is null or
/// holds another type).
pub fn points(column: &ComponentColumn, row: usize) -> &[[f32; 3]] {
    column
        .fixed_size_values::<Float32Type, 3>(row)
        .unwrap_or_default()
}

/// Byte length of the first `text` instance of a cell.
pub fn first_text_len(list: &ListArray, row: usize) -> Option<usize> {
    let range = instances(list, row);
    let strings = list.values().as_string_opt::<i32>()?;
    (!range.is_empty()).then(|| strings.value(range.start).len())
}

/// Calls `f` with the first `scalar` instance of every non-empty, non-null cell of a range
/// run, in order: one downcast per run, and a plain loop over the offsets when the run is
/// a slice of its chunk.
pub fn for_each_first_f64(run: &RangeRun<'_>, mut f: impl FnMut(f64)) {
    let list = run.column().list_array();
    let Some(values) = list.values().as_primitive_opt::<Float64Type>() else {
        return;
    };
    let (offsets, values) = (list.value_offsets(), values.values());
    #[expect(clippy::cast_sign_loss, reason = "list offsets are non-negative")]
    let cell = |row: usize| (offsets[row] as usize, offsets[row + 1] as usize);
    match run.contiguous_rows() {
        Some(rows) if list.null_count() == 0 => {
            if run.column().has_one_instance_per_row() {
                #[expect(clippy::cast_sign_loss, reason = "list offsets are non-negative")]
                let first = offsets[rows.start] as usize;
                values[first..first + rows.len()]
                    .iter()
                    .copied()
                    .for_each(f);
                return;
            }
            #[expect(clippy::cast_sign_loss, reason = "list offsets are non-negative")]
            for bounds in offsets[rows.start..=rows.end].windows(2) {
                if bounds[0] < bounds[1] {
                    f(values[bounds[0] as usize]);
                }
            }
        }
        _ => {
            for row in run.rows() {
                let (start, end) = cell(row);
                if start < end && list.is_valid(row) {
                    f(values[start]);
                }
            }
        }
    }
}
/// A store with this configuration holding `chunks`, inserted in order.
pub fn store_with(config: StoreConfig, chunks: &[Arc<Chunk>]) -> ChunkStore {
    let mut store = ChunkStore::with_config(config).expect("a valid config");
    for chunk in chunks {
        store.insert(Arc::clone(chunk)).expect("consistent chunks");
    }
    store
}

/// One `scalar` series at `entity`: a chunk per `chunk_rows` consecutive `frames`, value =
/// frame.
#[expect(clippy::cast_precision_loss, reason = "bench frames are small")]
pub fn scalar_series(
    ids: &mut RowIds,
    entity: &EntityPath,
    frames: &[i64],
    chunk_rows: usize,
) -> Vec<Arc<Chunk>> {
    frames
        .chunks(chunk_rows)
        .map(|frames| {
            let values = scalars(frames.iter().map(|&f| f as f64).collect());
            temporal_chunk(ids, entity, frames.to_vec(), vec![(SCALAR, values)])
        })
        .collect()
}

/// WORKLOADS.md's `latest_at_batch` data: 1,000 single-row chunks at `entity`, frame `f`
/// in `0..1000`, each row with 1,000 `position3d` instances `[f, k, 0]`.
#[expect(
    clippy::cast_precision_loss,
    reason = "bench values are small integers"
)]
pub fn point_batches(ids: &mut RowIds, entity: &EntityPath) -> Vec<Arc<Chunk>> {
    (0..1000u16)
        .map(|f| {
            let pos = positions(1, 1000, |_, k| [f32::from(f), k as f32, 0.0]);
            temporal_chunk(ids, entity, vec![i64::from(f)], vec![(POSITION3D, pos)])
        })
        .collect()
}

/// WORKLOADS.md's `range_scalar` data: per entity `e` of `entities`, frames `0..100_000`
/// in chunks of 1,000 rows, `scalar` = `(frame * 7 + e) % 1000`.
#[expect(
    clippy::cast_precision_loss,
    reason = "bench values are small integers"
)]
pub fn range_series(ids: &mut RowIds, entities: &[EntityPath]) -> Vec<Arc<Chunk>> {
    let mut chunks = Vec::with_capacity(entities.len() * 100);
    for (e, entity) in (0i64..).zip(entities) {
        for c in 0..100i64 {
            let frames: Vec<i64> = (0..1000).map(|r| c * 1000 + r).collect();
            let values = frames
                .iter()
                .map(|&f| ((f * 7 + e) % 1000) as f64)
                .collect();
            chunks.push(temporal_chunk(
                ids,
                entity,
                frames,
                vec![(SCALAR, scalars(values))],
            ));
        }
    }
    chunks
}

/// A workload's time (every generated one is valid).
pub fn at(t: i64) -> TimeInt {
    TimeInt::new(t).expect("workload times are valid")
}

/// WORKLOADS.md's `latest_at_batch` query times, drawn from a fresh generator.
#[expect(clippy::cast_possible_wrap, reason = "times below 1,000")]
pub fn point_batch_queries() -> Vec<i64> {
    let mut rng = SplitMix64::new();
    (0..10_000).map(|_| rng.uniform(1000) as i64).collect()
}

/// `latest_at_batch`'s visit of one answer: the IEEE-754 bit patterns of `x` and `y` of
/// every point (`f32::to_bits`, widened to `u64`), summed with wrapping, as WORKLOADS.md
/// defines it: the values are read as a viewer's upload would, with no float conversion.
pub fn sum_of_xy(points: &[[f32; 3]]) -> u64 {
    points.iter().fold(0u64, |sum, p| {
        sum.wrapping_add(u64::from(p[0].to_bits()) + u64::from(p[1].to_bits()))
    })
}

/// WORKLOADS.md's `range_scalar` queries `(entity, start)`, drawn from a fresh generator.
#[expect(clippy::cast_possible_wrap, reason = "starts below 100,000")]
pub fn range_series_queries() -> Vec<(usize, i64)> {
    let mut rng = SplitMix64::new();
    (0..1000)
        .map(|_| {
            let entity = rng.uniform_usize(10);
            (entity, rng.uniform(100_000) as i64)
        })
        .collect()
}

/// `range_scalar`'s visit of one answer: adds the IEEE-754 bit pattern of every row's
/// first `scalar` (`f64::to_bits`) to `sum`, wrapping, as WORKLOADS.md defines it, and
/// counts the rows in `rows`.
pub fn visit_range_scalars(result: &RangeResult, rows: &mut u64, sum: &mut u64) {
    for run in result.runs() {
        for_each_first_f64(&run, |v| {
            *sum = sum.wrapping_add(v.to_bits());
            *rows += 1;
        });
    }
}

/// `n` single-row `scalar` chunks per entity, interleaved across `entities` as a live
/// stream of `entities.len()` series arrives: frame `k` of every series, then `k + 1`.
pub fn interleaved_streams(ids: &mut RowIds, entities: &[EntityPath], n: usize) -> Vec<Arc<Chunk>> {
    let mut chunks = Vec::with_capacity(n * entities.len());
    for frame in 0..n {
        for entity in entities {
            #[expect(clippy::cast_possible_wrap, reason = "bench frames are small")]
            let frame = frame as i64;
            chunks.extend(scalar_series(ids, entity, &[frame], 1));
        }
    }
    chunks
}

/// Latest-at `scalar` at `entity` as of `t` on `timeline`, read back as a number. The
/// caller makes the timeline's name once, so a timed loop allocates nothing per query.
pub fn latest_scalar(
    store: &StoreView,
    timeline: &Arc<str>,
    t: i64,
    entity: &EntityPath,
) -> Option<f64> {
    let query = LatestAtQuery::new(Arc::clone(timeline), TimeInt::new(t)?);
    let cell = store.latest_at(&query, entity, SCALAR)?;
    first_f64(cell.column(), cell.row())
}

/// The dataframe workload's data: `entities` entities (`/fleet/g{e / 100}/r{e}`), each
/// logging `scalar`, `position3d` and `text` at `times` frames `3k + e % 3` (so a third
/// of the entities has a row at any one frame: sparse rows differ from filled ones), in
/// chunks of `rows_per_chunk` rows.
#[expect(
    clippy::cast_possible_wrap,
    clippy::cast_precision_loss,
    reason = "bench sizes are small integers"
)]
pub fn dataframe_chunks(entities: usize, times: usize, rows_per_chunk: usize) -> Vec<Arc<Chunk>> {
    let mut ids = RowIds::new();
    let mut chunks = Vec::new();
    let words = ["idle", "moving", "charging", "blocked"];
    for e in 0..entities {
        let entity = EntityPath::parse(&format!("/fleet/g{}/r{e}", e / 100)).expect("a valid path");
        for start in (0..times).step_by(rows_per_chunk) {
            let ks: Vec<usize> = (start..(start + rows_per_chunk).min(times)).collect();
            let frames = ks.iter().map(|&k| (3 * k + e % 3) as i64).collect();
            let scalar = scalars(ks.iter().map(|&k| (k + e) as f64).collect());
            let position = positions(ks.len(), 1, |r, _| [ks[r] as f32, e as f32, 0.0]);
            let text = texts(ks.iter().map(|&k| words[(k + e) % 4].to_owned()).collect());
            chunks.push(temporal_chunk(
                &mut ids,
                &entity,
                frames,
                vec![(SCALAR, scalar), (POSITION3D, position), (TEXT, text)],
            ));
        }
    }
    chunks
}

/// Streams a dataframe view whole, reading every batch: (rows, data columns, non-null
/// cells), so that nothing is optimized away.
pub fn stream_dataframe(store: &ChunkStore, query: &DataframeQuery) -> (u64, u64, u64) {
    let (mut rows, mut non_null) = (0, 0);
    let stream = store.dataframe(query).expect("a known index");
    let columns = stream.schema().fields().len() as u64 - 1;
    for batch in stream {
        let batch = batch.expect("a batch");
        rows += batch.num_rows() as u64;
        non_null += batch.columns()[1..]
            .iter()
            .map(|c| (c.len() - c.null_count()) as u64)
            .sum::<u64>();
    }
    (rows, columns, non_null)
}

/// A small xorshift step: reproducible sensor noise in `[0, 1)` (LZ4 barely compresses it),
/// for the generators of large files (`examples/rrd_scale.rs`, `examples/dataset_bench.rs`).
pub fn noise(state: &mut u64) -> f32 {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    #[expect(clippy::cast_precision_loss, reason = "noise")]
    let unit = (*state >> 40) as f32 / (1u64 << 24) as f32;
    unit
}

/// A sensor's chunk of `rows` rows from `first_frame` on `frame`: each row a `scalar` and
/// `points` `position3d` points, all noise.
pub fn sensor_chunk(
    entity: &EntityPath,
    first_frame: i64,
    rows: usize,
    points: usize,
    seed: &mut u64,
) -> Chunk {
    let frames: Vec<i64> = (first_frame..).take(rows).collect();
    let scalars = Float64Array::from_iter_values((0..rows).map(|_| f64::from(noise(seed))));
    let scalars = ListArray::new(
        Arc::new(Field::new_list_field(DataType::Float64, true)),
        OffsetBuffer::from_lengths(std::iter::repeat_n(1, rows)),
        Arc::new(scalars),
        None,
    );
    let xyz = Float32Array::from_iter_values((0..rows * points * 3).map(|_| noise(seed)));
    let xyz = FixedSizeListArray::new(
        Arc::new(Field::new_list_field(DataType::Float32, false)),
        3,
        Arc::new(xyz),
        None,
    );
    let positions = ListArray::new(
        Arc::new(Field::new_list_field(xyz.data_type().clone(), true)),
        OffsetBuffer::from_lengths(std::iter::repeat_n(points, rows)),
        Arc::new(xyz),
        None,
    );
    Chunk::try_new(
        ChunkId::new(),
        entity.clone(),
        (0..rows).map(|_| RowId::new()).collect(),
        vec![(
            Timeline::sequence("frame"),
            Arc::new(Int64Array::from(frames)) as ArrayRef,
        )],
        vec![
            ("scalar".into(), Arc::new(scalars) as ArrayRef),
            ("position3d".into(), Arc::new(positions) as ArrayRef),
        ],
    )
    .expect("valid columns")
}

/// Peak resident memory of this process so far, in bytes (`VmHWM`, Linux; 0 elsewhere).
pub fn peak_rss() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|status| {
            let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
            line.split_whitespace().nth(1)?.parse::<u64>().ok()
        })
        .map_or(0, |kib| kib * 1024)
}
