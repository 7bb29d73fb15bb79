//! Publishing per insert, without a reader, for instruction counts: the `insert_streaming`
//! rows (one-row chunks round-robin over 100 entities), the first half into a store, the
//! second half through either the plain store or a `SharedStore` publishing after every
//! insert. Each second half runs in its own `#[inline(never)]` function, so that callgrind
//! can count it alone (`docs/PERFORMANCE.md`, "Snapshots and the shared store"):
//!
//! ```text
//! cargo build --release --example publish_probe
//! valgrind --tool=callgrind --toggle-collect='*probe_shared*' \
//!     target/release/examples/publish_probe shared 200000
//! valgrind --tool=callgrind --toggle-collect='*probe_plain*' \
//!     target/release/examples/publish_probe plain 200000
//! ```
//!
//! It prints the rows held and, on stderr, the second half's wall time per row.
#![allow(
    clippy::cast_precision_loss,
    clippy::cast_possible_wrap,
    reason = "benchmark arithmetic on small counts"
)]
#![allow(
    clippy::expect_used,
    reason = "a measurement program: its own generated inputs are valid, and a failure should stop it loudly"
)]

#[path = "../benches/common/mod.rs"]
mod common;

use std::sync::Arc;

use chunkstore::{Chunk, ChunkStore, SharedStore, StoreConfig};
use common::{RowIds, entities, scalars, temporal_chunk};

#[inline(never)]
fn probe_plain(store: &mut ChunkStore, chunks: &[Arc<Chunk>]) {
    for chunk in chunks {
        drop(store.insert(Arc::clone(chunk)).expect("consistent chunks"));
    }
}

#[inline(never)]
fn probe_shared(store: &SharedStore, chunks: &[Arc<Chunk>]) {
    for chunk in chunks {
        drop(store.insert(Arc::clone(chunk)).expect("consistent chunks"));
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let mode = args.next().unwrap_or_else(|| "shared".into());
    let rows: usize = args
        .next()
        .map_or(200_000, |rows| rows.parse().expect("ROWS is a number"));
    let paths = entities(100, |e| format!("stream/{e:03}"));
    let mut ids = RowIds::new();
    let chunks: Vec<Arc<Chunk>> = (0..rows)
        .map(|k| {
            temporal_chunk(
                &mut ids,
                &paths[k % paths.len()],
                vec![(k / paths.len()) as i64],
                vec![("scalar", scalars(vec![(k % 1000) as f64]))],
            )
        })
        .collect();
    let (first, second) = chunks.split_at(rows / 2);
    let mut store = ChunkStore::with_config(StoreConfig::DEFAULT).expect("a valid config");
    for chunk in first {
        drop(store.insert(Arc::clone(chunk)).expect("consistent chunks"));
    }
    let start = std::time::Instant::now();
    let held = match mode.as_str() {
        "plain" => {
            probe_plain(&mut store, second);
            store.stats().num_rows()
        }
        "shared" => {
            let shared = SharedStore::new(store);
            probe_shared(&shared, second);
            shared.snapshot().stats().num_rows()
        }
        other => panic!("MODE is plain or shared, not {other}"),
    };
    let ns = start.elapsed().as_nanos() as f64 / second.len() as f64;
    println!("{held}");
    eprintln!("{mode}: {ns:.0} ns per row");
}
