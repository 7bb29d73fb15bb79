//! The `scaling` workload (this crate's own; `docs/PERFORMANCE.md` has its table and plot):
//! how the cost of an insert, a latest-at and a range grows with the store.
//!
//! One entity, one `scalar` series, frames `0..rows` (value = frame), in two shapes:
//! - `chunks10`: chunks of 10 rows, compaction off, so the store holds `rows / 10` chunks:
//!   10^3 to 10^7 rows are 10^2 to 10^6 chunks in one index;
//! - `stream`: single-row chunks in the default configuration (compaction on), as a live
//!   stream arrives: 10^3 to 10^6 rows (a prepared stream of 10^7 single-row chunks would
//!   not fit beside the store).
//!
//! Each in two arrival orders: `in_order` (frame order) and `out_of_order` (the chunks in a
//! random permutation; row ids increase in arrival order either way, as in WORKLOADS.md).
//! Per size, one JSON line per phase: `insert` (ns per row), `latest_at` (100,000 queries
//! at random frames, ns per query) and `range` (1,000 ranges of 1,000 frames, every row
//! visited, ns per row), with the store's chunks and bytes.
//! `SCALING_MAX_ROWS` caps the sizes (default 10^7); `benches/plot_scaling.py` turns the
//! lines into the SVG plot.

use std::sync::Arc;

use chunkstore::{ChunkStore, RangeQuery, StoreConfig, TimeRange};

use super::common::{
    FRAME, RowIds, SCALAR, SplitMix64, at, entities, latest_scalar, scalar_series,
    visit_range_scalars,
};
use super::{DEFAULT, IMPL, OFF, peak_rss_kib, time_inserts, time_query};

/// The sizes, in rows.
const SIZES: [usize; 5] = [1_000, 10_000, 100_000, 1_000_000, 10_000_000];
const LATEST_AT_QUERIES: usize = 100_000;
const RANGE_QUERIES: usize = 1_000;
const RANGE_FRAMES: i64 = 1_000;

/// One shape of the data: its name, rows per chunk, configuration and largest size.
struct Shape {
    name: &'static str,
    chunk_rows: usize,
    config: StoreConfig,
    max_rows: usize,
}

const SHAPES: [Shape; 2] = [
    Shape {
        name: "chunks10",
        chunk_rows: 10,
        config: OFF,
        max_rows: 10_000_000,
    },
    Shape {
        name: "stream",
        chunk_rows: 1,
        config: DEFAULT,
        max_rows: 1_000_000,
    },
];

pub fn scaling() -> bool {
    let cap = std::env::var("SCALING_MAX_ROWS")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .unwrap_or(usize::MAX);
    let mut all_ok = true;
    for shape in &SHAPES {
        for out_of_order in [false, true] {
            for &rows in SIZES.iter().filter(|&&n| n <= shape.max_rows && n <= cap) {
                all_ok &= measure(shape, out_of_order, rows);
            }
        }
    }
    all_ok
}

/// Builds, loads and queries one size; prints its three lines. False if an answer is
/// wrong.
fn measure(shape: &Shape, out_of_order: bool, rows: usize) -> bool {
    let entity = &entities(1, |_| "scaling/series".to_owned())[0];
    // Chunks are built in arrival order, so row ids increase in insertion order (as in
    // WORKLOADS.md): out-of-order times, not out-of-order ids.
    let mut rng = SplitMix64::new();
    let num_chunks = rows / shape.chunk_rows;
    let order: Vec<i64> = if out_of_order {
        rng.permutation(num_chunks)
    } else {
        (0..num_chunks as i64).collect()
    };
    let chunk_rows = shape.chunk_rows as i64;
    let frames: Vec<i64> = order
        .iter()
        .flat_map(|&c| c * chunk_rows..(c + 1) * chunk_rows)
        .collect();
    let chunks = scalar_series(&mut RowIds::new(), entity, &frames, shape.chunk_rows);
    let latest_times: Vec<i64> = (0..LATEST_AT_QUERIES)
        .map(|_| rng.uniform(rows as u64) as i64)
        .collect();
    let range_starts: Vec<i64> = (0..RANGE_QUERIES)
        .map(|_| rng.uniform(rows as u64) as i64)
        .collect();

    let (store, insert_ns_per_chunk) = time_inserts(shape.config, &chunks);
    drop(chunks);
    let arrival = if out_of_order {
        "out_of_order"
    } else {
        "in_order"
    };
    let line = |phase: &str, ops: u64, ns: f64, store: &ChunkStore| {
        let stats = store.stats();
        println!(
            "{{\"workload\":\"scaling\",\"shape\":\"{}\",\"arrival\":\"{arrival}\",\"rows\":{rows},\"phase\":\"{phase}\",\"impl\":\"{IMPL}\",\"ops\":{ops},\"ns_per_op\":{ns:.2},\"chunks\":{},\"store_bytes\":{},\"peak_rss_kib\":{}}}",
            shape.name,
            stats.num_chunks(),
            stats.heap_bytes,
            peak_rss_kib(),
        );
    };
    line(
        "insert",
        rows as u64,
        insert_ns_per_chunk / shape.chunk_rows as f64,
        &store,
    );

    let frame: Arc<str> = FRAME.into();
    let (ops, ns, latest_sum) = time_query(|| {
        let mut sum = 0u64;
        for &t in &latest_times {
            if let Some(v) = latest_scalar(&store, &frame, t, entity) {
                sum = sum.wrapping_add(v as u64);
            }
        }
        (latest_times.len() as u64, sum)
    });
    line("latest_at", ops, ns, &store);

    let (ops, ns, range_sum) = time_query(|| {
        let (mut visited, mut sum) = (0u64, 0u64);
        for &start in &range_starts {
            let query = RangeQuery::new(
                Arc::clone(&frame),
                TimeRange::new(at(start), at(start + RANGE_FRAMES - 1)),
            );
            visit_range_scalars(&store.range(&query, entity, SCALAR), &mut visited, &mut sum);
        }
        (visited, sum)
    });
    line("range", ops, ns, &store);

    // Every frame answers with itself, so the sums are known.
    let expected_latest: u64 = latest_times.iter().map(|&t| t as u64).sum();
    let expected_range: u64 = range_starts
        .iter()
        .flat_map(|&s| s..(s + RANGE_FRAMES).min(rows as i64))
        .map(|f| (f as f64).to_bits())
        .fold(0u64, u64::wrapping_add);
    let ok = latest_sum == expected_latest && range_sum == expected_range;
    if !ok {
        eprintln!(
            "WRONG ANSWER scaling/{}/{arrival}/{rows}: latest-at {latest_sum} (expected {expected_latest}), range {range_sum} (expected {expected_range})",
            shape.name
        );
    }
    ok
}
