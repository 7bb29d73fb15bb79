//! Garbage collection: everything, half of the store oldest first with the latest chunks
//! protected, and furthest from a time cursor. Each run collects a fresh clone of the
//! store, cloned untimed.

#![allow(
    clippy::expect_used,
    reason = "generated data is valid; a failure should stop the bench loudly"
)]

mod common;

use chunkstore::{ChunkStore, GcOptions, GcOrder, StoreConfig, TimeInt};
use common::{FRAME, RowIds, entities, scalar_series, store_with};
use criterion::{BatchSize, Criterion, criterion_group, criterion_main};

fn bench_gc(c: &mut Criterion, id: &str, base: &ChunkStore, options: &GcOptions) {
    let mut group = c.benchmark_group("gc");
    group.sample_size(20);
    group.bench_function(id, |b| {
        b.iter_batched(
            || base.clone(),
            |mut store| {
                let events = store.gc(options);
                (store, events)
            },
            BatchSize::LargeInput,
        );
    });
    group.finish();
}

fn gc(c: &mut Criterion) {
    let mut ids = RowIds::new();
    let series = entities(100, |e| format!("gc/{e}"));
    let frames: Vec<i64> = (0..2000).collect();
    let chunks: Vec<_> = series
        .iter()
        .flat_map(|e| scalar_series(&mut ids, e, &frames, 100))
        .collect();
    let store = store_with(StoreConfig::COMPACTION_OFF, &chunks);

    bench_gc(
        c,
        "everything/100_entities/20_chunks_each",
        &store,
        &GcOptions::everything(),
    );
    bench_gc(
        c,
        "half_oldest_first_protect_latest/100_entities/20_chunks_each",
        &store,
        &GcOptions::drop_at_least_fraction(0.5).expect("0.5 is a valid fraction"),
    );
    let cursor = GcOptions::drop_at_least_fraction(0.5)
        .expect("0.5 is a valid fraction")
        .with_order(GcOrder::furthest_from(
            FRAME,
            TimeInt::new(1000).expect("a valid time"),
        ));
    bench_gc(
        c,
        "half_furthest_from_cursor/100_entities/20_chunks_each",
        &store,
        &cursor,
    );
}

criterion_group!(benches, gc);
criterion_main!(benches);
