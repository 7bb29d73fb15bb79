//! Measures compaction thresholds on the two streaming shapes of
//! `../shared/bench/WORKLOADS.md` that use the default configuration, and prints one
//! Markdown table row per setting (the table in `docs/performance-log.md`):
//!
//! ```text
//! cargo run --release --example compaction_sweep
//! ```
//!
//! - `insert_streaming`: 1,000,000 single-row scalar chunks over 100 entities, frames in
//!   order; then 100,000 latest-at queries at frame 5,000.
//! - `out_of_order`: 100,000 single-row chunks whose frames are a permutation of
//!   `0..100,000` (`SplitMix64`, seed 42); then 100,000 latest-at queries at random frames.
//!
//! Chunks come from the generator the benches and `examples/workloads.rs` share
//! (`benches/common/`), values being the frame.
//!
//! Reported per setting: insert time per row, the store's heap bytes per row, chunks
//! left, copy amplification (rows and payload bytes compaction copied ÷ inserted), and
//! latest-at time per query. Times are wall-clock on a shared machine: compare rows of one
//! run, not runs.
#![allow(
    clippy::cast_precision_loss,
    clippy::cast_possible_truncation,
    clippy::cast_possible_wrap,
    clippy::cast_sign_loss,
    reason = "benchmark arithmetic on small counts"
)]
#![allow(
    clippy::expect_used,
    reason = "a measurement program: its own fixed inputs are valid, and a failure should stop it loudly"
)]

use std::sync::Arc;
use std::time::Instant;

#[path = "../benches/common/mod.rs"]
mod common;

use chunkstore::{Chunk, ChunkStore, EntityPath, StoreConfig};
use common::{RowIds, SplitMix64, entities, interleaved_streams, latest_scalar, scalar_series};

/// One measured shape: what the table prints.
struct Measured {
    insert_ns_per_row: f64,
    bytes_per_row: f64,
    chunks: u64,
    copied_rows: f64,
    copied_bytes: f64,
    query_ns: f64,
    checksum: f64,
}

fn insert_all(config: StoreConfig, chunks: &[Arc<Chunk>]) -> (ChunkStore, f64) {
    let mut store = ChunkStore::with_config(config).expect("valid config");
    let start = Instant::now();
    for chunk in chunks {
        store.insert(Arc::clone(chunk)).expect("consistent chunks");
    }
    let ns = start.elapsed().as_nanos() as f64 / chunks.len() as f64;
    (store, ns)
}

fn measure(store: &ChunkStore, insert_ns_per_row: f64, queries: &[(EntityPath, i64)]) -> Measured {
    let start = Instant::now();
    let frame: Arc<str> = common::FRAME.into();
    let checksum: f64 = queries
        .iter()
        .filter_map(|(entity, at)| latest_scalar(store, &frame, *at, entity))
        .sum();
    let query_ns = start.elapsed().as_nanos() as f64 / queries.len() as f64;
    let stats = store.stats();
    Measured {
        insert_ns_per_row,
        bytes_per_row: stats.heap_bytes as f64 / stats.num_rows() as f64,
        chunks: stats.num_chunks(),
        copied_rows: stats.rows_copied_by_compaction as f64 / stats.rows_inserted as f64,
        copied_bytes: stats.payload_bytes_copied_by_compaction as f64
            / stats.payload_bytes_inserted as f64,
        query_ns,
        checksum,
    }
}

fn insert_streaming(config: StoreConfig) -> Measured {
    let entities = entities(100, |e| format!("stream/{e:03}"));
    let chunks = interleaved_streams(&mut RowIds::new(), &entities, 10_000);
    let (store, ns) = insert_all(config, &chunks);
    let queries: Vec<(EntityPath, i64)> = (0..100_000)
        .map(|q| (entities[q % 100].clone(), 5_000))
        .collect();
    measure(&store, ns, &queries)
}

fn out_of_order(config: StoreConfig) -> Measured {
    let mut random = SplitMix64::new();
    let frames = random.permutation(100_000);
    let entity = EntityPath::parse("ooo").expect("valid path");
    let queries: Vec<(EntityPath, i64)> = (0..100_000)
        .map(|_| (entity.clone(), random.uniform(100_000) as i64))
        .collect();
    let chunks = scalar_series(&mut RowIds::new(), &entity, &frames, 1);
    let (store, ns) = insert_all(config, &chunks);
    measure(&store, ns, &queries)
}

fn main() {
    println!(
        "| max_rows | merge_fanout | shape | insert ns/row | heap B/row | chunks | copied rows | copied bytes | latest-at ns | checksum |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for max_rows in [1024, 4096, 16_384] {
        for merge_fanout in [4, 8, 16] {
            let config = StoreConfig::DEFAULT
                .with_max_rows(max_rows)
                .with_merge_fanout(merge_fanout);
            for (shape, run) in [
                (
                    "insert_streaming",
                    insert_streaming as fn(StoreConfig) -> Measured,
                ),
                ("out_of_order", out_of_order),
            ] {
                let m = run(config);
                println!(
                    "| {max_rows} | {merge_fanout} | {shape} | {:.0} | {:.2} | {} | {:.2} | {:.2} | {:.0} | {} |",
                    m.insert_ns_per_row,
                    m.bytes_per_row,
                    m.chunks,
                    m.copied_rows,
                    m.copied_bytes,
                    m.query_ns,
                    m.checksum
                );
            }
        }
    }
}
