//! Compaction on insert, alone, for instruction and cache-miss counts: one-row chunks
//! inserted into a store with the default configuration, in one pass (the `workloads`
//! example repeats a phase as often as its time budget allows, so its counts under
//! callgrind are of as many runs as fit). The inserts run in an `#[inline(never)]`
//! function, so that callgrind can count them alone (`docs/performance-log.md`):
//!
//! ```text
//! cargo build --release --example insert_probe
//! valgrind --tool=callgrind --toggle-collect='*probe_inserts*' \
//!     target/release/examples/insert_probe MODE
//! ```
//!
//! `MODE` is `stream` (the 1,000,000 rows of `insert_streaming`'s shape: 100 entities,
//! one frame of each in turn), `ooo` (`out_of_order`'s 100,000 rows of one entity,
//! frames a permutation), or `level1`
//! (160,000 streamed rows with chunks of at most 16 rows, so that every merge is a write
//! buffer's fan of one-row chunks). It prints the wall time per row (noisy; judge with
//! the counts), the chunks, the rows compaction copied and the store's heap.
#![allow(
    clippy::cast_precision_loss,
    reason = "benchmark arithmetic on small counts"
)]
#![allow(
    clippy::expect_used,
    reason = "a measurement program: its own generated inputs are valid, and a failure should stop it loudly"
)]

#[path = "../benches/common/mod.rs"]
mod common;

use std::sync::Arc;

use chunkstore::{Chunk, ChunkStore, StoreConfig};
use common::{RowIds, SplitMix64, entities, interleaved_streams, scalar_series};

#[inline(never)]
fn probe_inserts(store: &mut ChunkStore, chunks: &[Arc<Chunk>]) {
    for chunk in chunks {
        drop(store.insert(Arc::clone(chunk)).expect("consistent chunks"));
    }
}

/// `frames` one-row chunks of each of 100 entities, one frame of each in turn.
fn streamed(ids: &mut RowIds, frames: usize) -> Vec<Arc<Chunk>> {
    let paths = entities(100, |e| format!("stream/{e:03}"));
    interleaved_streams(ids, &paths, frames)
}

fn main() {
    let mode = std::env::args().nth(1).unwrap_or_else(|| "stream".into());
    let mut ids = RowIds::new();
    let (chunks, config) = match mode.as_str() {
        "stream" => (streamed(&mut ids, 10_000), StoreConfig::DEFAULT),
        "level1" => (
            streamed(&mut ids, 1_600),
            StoreConfig::DEFAULT.with_max_rows(16),
        ),
        "ooo" => {
            let paths = entities(1, |_| "ooo".to_owned());
            let frames = SplitMix64::new().permutation(100_000);
            let chunks = scalar_series(&mut ids, &paths[0], &frames, 1);
            (chunks, StoreConfig::DEFAULT)
        }
        other => panic!("MODE is stream, ooo or level1, not {other:?}"),
    };
    let mut store = ChunkStore::with_config(config).expect("a valid config");
    let start = std::time::Instant::now();
    probe_inserts(&mut store, &chunks);
    let ns_per_row = start.elapsed().as_nanos() as f64 / chunks.len() as f64;
    let stats = store.stats();
    println!(
        "{mode}: {ns_per_row:.0} ns a row, {} chunks, {} rows copied by compaction, {} heap bytes",
        stats.num_chunks(),
        stats.rows_copied_by_compaction,
        stats.heap_bytes,
    );
}
