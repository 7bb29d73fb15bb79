//! Latest-at under Clears: a deep entity tree with recursive Clears on some ancestors and
//! flat ones on others, queried before and after the Clears.

#![allow(
    clippy::expect_used,
    reason = "generated data is valid; a failure should stop the bench loudly"
)]

mod common;

use std::sync::Arc;

use chunkstore::{EntityPath, StoreConfig};
use common::{RowIds, clear_chunk, latest_scalar, scalar_series, store_with};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

/// Every path of a tree `depth` levels deep with `fanout` children per node, under `root`.
fn tree(root: &EntityPath, depth: usize, fanout: usize) -> Vec<EntityPath> {
    let mut level = vec![root.clone()];
    let mut all = Vec::new();
    for _ in 0..depth {
        level = level
            .iter()
            .flat_map(|p| (0..fanout).map(move |i| p.join(i.to_string())))
            .collect();
        all.extend(level.iter().cloned());
    }
    all
}

fn clear(c: &mut Criterion) {
    let mut ids = RowIds::new();
    let root = EntityPath::parse("world").expect("a valid path");
    // 4 + 16 + 64 + 256 + 1024 + 4096 = 5,460 entities, 6 levels below the root.
    let paths = tree(&root, 6, 4);
    let frames: Vec<i64> = (0..50).collect();
    let mut chunks: Vec<_> = paths
        .iter()
        .flat_map(|p| scalar_series(&mut ids, p, &frames, 50))
        .collect();
    // Recursive Clears at frame 50 on every node of depth 2, flat ones on every node of
    // depth 4; a recursive Clear of the whole tree at frame 90.
    for path in &paths {
        match path.num_parts() {
            3 => chunks.push(clear_chunk(&mut ids, path, 50, true)),
            5 => chunks.push(clear_chunk(&mut ids, path, 50, false)),
            _ => {}
        }
    }
    chunks.push(clear_chunk(&mut ids, &root, 90, true));
    let store = store_with(StoreConfig::COMPACTION_OFF, &chunks);

    let frame: Arc<str> = common::FRAME.into();
    let mut group = c.benchmark_group("clear");
    group.throughput(Throughput::Elements(paths.len() as u64));
    for (id, t) in [
        ("deep_tree/5k_entities/before_clears", 25),
        ("deep_tree/5k_entities/after_recursive_and_flat_clears", 75),
        ("deep_tree/5k_entities/after_root_clear", 95),
    ] {
        group.bench_function(id, |b| {
            b.iter(|| {
                paths
                    .iter()
                    .filter_map(|p| latest_scalar(&store, &frame, t, p))
                    .count()
            });
        });
    }
    group.finish();
}

criterion_group!(benches, clear);
criterion_main!(benches);
