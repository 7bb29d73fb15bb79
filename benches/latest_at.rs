//! Latest-at: many entities of sorted chunks, a live stream with its write buffers,
//! compacted out-of-order data, rows sharing one time, one long chunk beside many short
//! ones, and static data shadowing temporal data.

#![allow(
    clippy::expect_used,
    reason = "generated data is valid; a failure should stop the bench loudly"
)]

mod common;

use std::sync::Arc;

use chunkstore::{ChunkStore, EntityPath, StoreConfig};
use common::{
    FRAME, RowIds, SCALAR, SplitMix64, TEXT, entities, latest_scalar, scalar_series, scalars,
    static_chunk, store_with, texts,
};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

/// Times one batch of latest-at `scalar` queries, `(entity, time)` each.
fn bench_queries(c: &mut Criterion, id: &str, store: &ChunkStore, queries: &[(EntityPath, i64)]) {
    let mut group = c.benchmark_group("latest_at");
    group.throughput(Throughput::Elements(queries.len() as u64));
    let frame: Arc<str> = FRAME.into();
    group.bench_function(id, |b| {
        b.iter(|| {
            queries
                .iter()
                .filter_map(|(entity, t)| latest_scalar(store, &frame, *t, entity))
                .sum::<f64>()
        });
    });
    group.finish();
}

fn random_queries(entities: &[EntityPath], max_time: u64, n: usize) -> Vec<(EntityPath, i64)> {
    let mut rng = SplitMix64::new();
    (0..n)
        .map(|_| {
            let entity = entities[rng.uniform_usize(entities.len())].clone();
            #[expect(clippy::cast_possible_wrap, reason = "small bench times")]
            let t = rng.uniform(max_time) as i64;
            (entity, t)
        })
        .collect()
}

fn latest_at(c: &mut Criterion) {
    let mut ids = RowIds::new();

    // 1,000 entities, 10 sorted chunks of 100 rows each, compaction off.
    let points = entities(1000, |i| format!("points/{i}"));
    let frames: Vec<i64> = (0..1000).collect();
    let chunks: Vec<_> = points
        .iter()
        .flat_map(|e| scalar_series(&mut ids, e, &frames, 100))
        .collect();
    let store = store_with(StoreConfig::COMPACTION_OFF, &chunks);
    let queries = random_queries(&points, 1100, 10_000);
    bench_queries(c, "1k_entities/10_chunks_each", &store, &queries);

    // A live stream as a viewer sees it: 100 entities, 1,007 single-row chunks each in
    // time order, default configuration, so each entity's write buffer holds its last 15
    // rows (their chunks in no index) and a tenth of the queries ask past the newest.
    let streams = entities(100, |i| format!("stream/{i}"));
    let mut stream_chunks = Vec::new();
    for frame in 0..1007 {
        for entity in &streams {
            stream_chunks.push(common::temporal_chunk(
                &mut ids,
                entity,
                vec![frame],
                vec![(SCALAR, scalars(vec![1.0]))],
            ));
        }
    }
    let store = store_with(StoreConfig::DEFAULT, &stream_chunks);
    let queries = random_queries(&streams, 1100, 10_000);
    bench_queries(c, "stream/100_entities/write_buffer", &store, &queries);

    // 20,000 single rows in random time order, compacted on insert.
    let ooo = entities(1, |_| "ooo".to_owned());
    let shuffled = SplitMix64::new().permutation(20_000);
    let store = store_with(
        StoreConfig::DEFAULT,
        &scalar_series(&mut ids, &ooo[0], &shuffled, 1),
    );
    let queries = random_queries(&ooo, 20_000, 10_000);
    bench_queries(c, "out_of_order/20k_rows_compacted", &store, &queries);

    // 100 rows at every one of 100 frames: ties broken by row id, in 10-row chunks.
    let same: Vec<i64> = (0..100).flat_map(|f| [f; 100]).collect();
    let store = store_with(
        StoreConfig::COMPACTION_OFF,
        &scalar_series(&mut ids, &ooo[0], &same, 10),
    );
    let queries = random_queries(&ooo, 100, 10_000);
    bench_queries(c, "same_time/100_rows_per_frame", &store, &queries);

    // One chunk of 10,000 rows spanning every frame, beside 10,000 single-row chunks.
    let long: Vec<i64> = (0..10_000).map(|f| f * 100).collect();
    let short: Vec<i64> = (0..10_000).map(|f| f * 100 + 50).collect();
    let mut chunks = scalar_series(&mut ids, &ooo[0], &long, 10_000);
    chunks.extend(scalar_series(&mut ids, &ooo[0], &short, 1));
    let store = store_with(StoreConfig::COMPACTION_OFF, &chunks);
    let queries = random_queries(&ooo, 1_000_000, 10_000);
    bench_queries(c, "one_long_chunk_beside_10k_short", &store, &queries);

    // Static text shadows temporal text at 10,000 entities.
    let props = entities(10_000, |i| format!("props/{i}"));
    let mut chunks = Vec::new();
    for (i, entity) in props.iter().enumerate() {
        chunks.push(static_chunk(
            &mut ids,
            entity,
            vec![(TEXT, texts(vec![format!("name-{i}")]))],
        ));
        let frames: Vec<i64> = (0..10).collect();
        chunks.push(common::temporal_chunk(
            &mut ids,
            entity,
            frames.clone(),
            vec![
                (
                    TEXT,
                    texts(frames.iter().map(|f| format!("t-{f}")).collect()),
                ),
                (SCALAR, scalars(vec![1.0; 10])),
            ],
        ));
    }
    let store = store_with(StoreConfig::COMPACTION_OFF, &chunks);
    let queries = random_queries(&props, 20, 10_000);
    let mut group = c.benchmark_group("latest_at");
    group.throughput(Throughput::Elements(queries.len() as u64));
    group.bench_function("static_shadow/10k_entities", |b| {
        b.iter(|| {
            queries
                .iter()
                .filter(|(entity, t)| {
                    let query = chunkstore::LatestAtQuery::new(
                        FRAME,
                        chunkstore::TimeInt::new(*t).expect("a valid time"),
                    );
                    store
                        .latest_at(&query, entity, TEXT)
                        .is_some_and(|c| c.is_static())
                })
                .count()
        });
    });
    group.finish();
}

criterion_group!(benches, latest_at);
criterion_main!(benches);
