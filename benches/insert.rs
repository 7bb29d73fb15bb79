//! Insertion: whole chunks with compaction off, and single-row streams with compaction on
//! (in order, out of order, all at one time, and a 2 kHz stream over many series).

#![allow(
    clippy::expect_used,
    reason = "generated data is valid; a failure should stop the bench loudly"
)]

mod common;

use std::sync::Arc;

use chunkstore::{Chunk, ChunkStore, StoreConfig};
use common::{RowIds, SplitMix64, entities, interleaved_streams, scalar_series};
use criterion::{BatchSize, Criterion, Throughput, criterion_group, criterion_main};

/// Times inserting `chunks` into a fresh store; the store is made, and dropped, untimed.
fn bench_inserts(c: &mut Criterion, id: &str, config: StoreConfig, chunks: &[Arc<Chunk>]) {
    let mut group = c.benchmark_group("insert");
    group.throughput(Throughput::Elements(chunks.len() as u64));
    group.sample_size(10);
    group.bench_function(id, |b| {
        b.iter_batched(
            || ChunkStore::with_config(config).expect("a valid config"),
            |mut store| {
                for chunk in chunks {
                    drop(store.insert(Arc::clone(chunk)).expect("consistent chunks"));
                }
                store
            },
            BatchSize::LargeInput,
        );
    });
    group.finish();
}

fn insert(c: &mut Criterion) {
    let mut ids = RowIds::new();
    let one = entities(1, |_| "e".to_owned());
    let frames: Vec<i64> = (0..100_000).collect();

    let batched = scalar_series(&mut ids, &one[0], &frames, 1000);
    bench_inserts(
        c,
        "batched/100_chunks_of_1000_rows/compaction_off",
        StoreConfig::COMPACTION_OFF,
        &batched,
    );

    let series = entities(100, |e| format!("stream/{e:03}"));
    let streaming = interleaved_streams(&mut ids, &series, 200);
    bench_inserts(
        c,
        "streaming/100_entities/20k_single_rows",
        StoreConfig::DEFAULT,
        &streaming,
    );

    let shuffled = SplitMix64::new().permutation(20_000);
    let out_of_order = scalar_series(&mut ids, &one[0], &shuffled, 1);
    bench_inserts(
        c,
        "out_of_order/20k_single_rows",
        StoreConfig::DEFAULT,
        &out_of_order,
    );

    let same_time = scalar_series(&mut ids, &one[0], &vec![7; 20_000], 1);
    bench_inserts(
        c,
        "same_time/20k_single_rows_at_one_frame",
        StoreConfig::DEFAULT,
        &same_time,
    );

    // One second of a 2 kHz sensor over 50 series: 100,000 single-row chunks.
    let sensors = entities(50, |e| format!("imu/{e}"));
    let two_khz = interleaved_streams(&mut ids, &sensors, 2000);
    bench_inserts(
        c,
        "2khz/50_series/1s_of_single_rows",
        StoreConfig::DEFAULT,
        &two_khz,
    );
}

criterion_group!(benches, insert);
criterion_main!(benches);
