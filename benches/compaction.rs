//! Compaction on demand: a store filled with compaction off (single rows, in and out of
//! order) rewritten by `compact()`, the same with tiny thresholds at three sizes (the cost
//! per chunk must stay flat), chunks already split on insert (`compact()` only plans), and
//! the split of one oversized chunk on insert.

#![allow(
    clippy::expect_used,
    reason = "generated data is valid; a failure should stop the bench loudly"
)]

mod common;

use std::sync::Arc;

use chunkstore::{ChunkStore, StoreConfig};
use common::{RowIds, SplitMix64, entities, interleaved_streams, scalar_series, store_with};
use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};

fn bench_compact(c: &mut Criterion, id: &str, base: &ChunkStore, rows: u64) {
    let mut group = c.benchmark_group("compaction");
    group.sample_size(10);
    group.throughput(Throughput::Elements(rows));
    group.bench_function(id, |b| {
        b.iter_batched(
            || base.clone(),
            |mut store| {
                let events = store.compact();
                (store, events)
            },
            BatchSize::LargeInput,
        );
    });
    group.finish();
}

fn compaction(c: &mut Criterion) {
    let mut ids = RowIds::new();
    let series = entities(100, |e| format!("stream/{e:03}"));
    let store = store_with(
        StoreConfig::COMPACTION_OFF,
        &interleaved_streams(&mut ids, &series, 100),
    );
    bench_compact(c, "compact/100_entities/10k_single_rows", &store, 10_000);

    let one = entities(1, |_| "ooo".to_owned());
    let shuffled = SplitMix64::new().permutation(10_000);
    let store = store_with(
        StoreConfig::COMPACTION_OFF,
        &scalar_series(&mut ids, &one[0], &shuffled, 1),
    );
    bench_compact(c, "compact/out_of_order/10k_single_rows", &store, 10_000);

    // Tiny thresholds, where little can merge: compact() must stay O(chunks log chunks)
    // (a piece's copy once read every input chunk, 100 us a chunk at 20,000 chunks).
    let tiny = StoreConfig::COMPACTION_OFF
        .with_max_rows(3)
        .with_max_rows_unsorted(2)
        .with_max_bytes(4096);
    for n in [1_000, 10_000, 100_000] {
        let shuffled = SplitMix64::new().permutation(n);
        let store = store_with(tiny, &scalar_series(&mut ids, &one[0], &shuffled, 1));
        bench_compact(
            c,
            &format!("compact/tiny_thresholds/{n}_single_row_chunks"),
            &store,
            n as u64,
        );
    }

    // Chunks of 1,000 rows split on insert under the tiny thresholds (every tenth one's
    // rows shuffled): the pieces are already compact, so `compact()` only plans. It once
    // weighed each piece as its whole source chunk and rewrote every row, at several times
    // the cost of the load.
    let mut frames: Vec<i64> = (0..30_000).collect();
    let mut random = SplitMix64::new();
    for chunk in frames.chunks_mut(1_000).step_by(10) {
        let order = random.permutation(chunk.len());
        let shuffled: Vec<i64> = order.iter().map(|&i| chunk[0] + i).collect();
        chunk.copy_from_slice(&shuffled);
    }
    let store = store_with(
        tiny.with_compact_on_insert(true),
        &scalar_series(&mut ids, &one[0], &frames, 1_000),
    );
    bench_compact(c, "compact/split_on_insert/30k_rows", &store, 30_000);

    // A sorted chunk 25 times the row threshold: split into slices, nothing copied.
    let frames: Vec<i64> = (0..100_000).collect();
    let big = scalar_series(&mut ids, &one[0], &frames, frames.len());
    let mut group = c.benchmark_group("compaction");
    group.throughput(Throughput::Elements(frames.len() as u64));
    group.bench_function("split_on_insert/sorted_chunk_of_100k_rows", |b| {
        b.iter_batched(
            || ChunkStore::with_config(StoreConfig::DEFAULT).expect("a valid config"),
            |mut store| {
                drop(
                    store
                        .insert(Arc::clone(&big[0]))
                        .expect("a consistent chunk"),
                );
                store
            },
            BatchSize::LargeInput,
        );
    });
    group.finish();
}

criterion_group!(benches, compaction);
criterion_main!(benches);
