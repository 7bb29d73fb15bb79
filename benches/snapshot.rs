//! Snapshots: taking one (the same cost whatever the store holds), and what publishing
//! costs a streaming writer: the `insert_streaming` shape (single-row chunks over 100
//! entities, default configuration) inserted into a plain store, and into a `SharedStore`
//! publishing after every insert, once per frame of the 100 entities, and once per ten
//! frames; and the same per-insert publication into one entity of 20,000 chunks
//! (compaction off), whose index a write under a snapshot must not copy whole.

#![allow(
    clippy::expect_used,
    clippy::cast_precision_loss,
    clippy::cast_possible_wrap,
    reason = "generated data is valid; a failure should stop the bench loudly"
)]

mod common;

use std::sync::Arc;

use chunkstore::{Chunk, ChunkStore, SharedStore, StoreConfig};
use common::{RowIds, SCALAR, entities, scalars, store_with, temporal_chunk};
use criterion::measurement::WallTime;
use criterion::{
    BatchSize, BenchmarkGroup, Criterion, Throughput, criterion_group, criterion_main,
};

const ENTITIES: usize = 100;

/// `rows` single-row chunks, chunk `k` at entity `k % 100` and frame `k / 100`.
fn streaming_chunks(rows: usize) -> Vec<Arc<Chunk>> {
    let entities = entities(ENTITIES, |e| format!("stream/{e:03}"));
    let mut ids = RowIds::new();
    (0..rows)
        .map(|k| {
            temporal_chunk(
                &mut ids,
                &entities[k % ENTITIES],
                vec![(k / ENTITIES) as i64],
                vec![(SCALAR, scalars(vec![(k % 1000) as f64]))],
            )
        })
        .collect()
}

fn take(c: &mut Criterion) {
    let mut group = c.benchmark_group("snapshot/take");
    for rows in [1_000, 100_000] {
        let chunks = streaming_chunks(rows);
        let store = store_with(StoreConfig::COMPACTION_OFF, &chunks);
        group.bench_function(format!("store_of_{rows}_chunks"), |b| {
            b.iter(|| store.snapshot());
        });
        let shared = SharedStore::new(store);
        group.bench_function(format!("shared_store_of_{rows}_chunks"), |b| {
            b.iter(|| shared.snapshot());
        });
    }
    group.finish();
}

/// `second` inserted into a store made by `filled`, plain and through a `SharedStore`
/// publishing after every insert: the pair both groups compare.
fn plain_and_publishing_each_insert(
    group: &mut BenchmarkGroup<'_, WallTime>,
    filled: &dyn Fn() -> ChunkStore,
    second: &[Arc<Chunk>],
) {
    group.bench_function("plain", |b| {
        b.iter_batched(
            filled,
            |mut store| {
                for chunk in second {
                    drop(store.insert(Arc::clone(chunk)).expect("consistent chunks"));
                }
                store
            },
            BatchSize::LargeInput,
        );
    });
    group.bench_function("shared_publish_each_insert", |b| {
        b.iter_batched(
            || SharedStore::new(filled()),
            |shared| {
                for chunk in second {
                    drop(shared.insert(Arc::clone(chunk)).expect("consistent chunks"));
                }
                shared
            },
            BatchSize::LargeInput,
        );
    });
}

fn streaming_writer(c: &mut Criterion) {
    // Half the rows fill the store untimed; the timed writer inserts the other half.
    let chunks = streaming_chunks(40_000);
    let (first, second) = chunks.split_at(chunks.len() / 2);
    let filled = || store_with(StoreConfig::DEFAULT, first);
    let mut group = c.benchmark_group("snapshot/streaming_writer");
    group.sample_size(10);
    group.throughput(Throughput::Elements(second.len() as u64));
    plain_and_publishing_each_insert(&mut group, &filled, second);
    for (name, rows_per_publication) in [
        ("shared_publish_each_frame", ENTITIES),
        ("shared_publish_each_10_frames", 10 * ENTITIES),
    ] {
        group.bench_function(name, |b| {
            b.iter_batched(
                || SharedStore::new(filled()),
                |shared| {
                    for batch in second.chunks(rows_per_publication) {
                        drop(
                            shared
                                .insert_batch(batch.iter().cloned())
                                .expect("consistent chunks"),
                        );
                    }
                    shared
                },
                BatchSize::LargeInput,
            );
        });
    }
    group.finish();
}

fn big_entity(c: &mut Criterion) {
    // One entity, frames 0.. in order: its index is a sequence of 20,000 chunks, then
    // 22,000.
    let entity = entities(1, |_| "big".to_owned());
    let mut ids = RowIds::new();
    let chunks: Vec<Arc<Chunk>> = (0..22_000)
        .map(|k: i32| {
            temporal_chunk(
                &mut ids,
                &entity[0],
                vec![i64::from(k)],
                vec![(SCALAR, scalars(vec![f64::from(k % 1000)]))],
            )
        })
        .collect();
    let (first, second) = chunks.split_at(20_000);
    let filled = || store_with(StoreConfig::COMPACTION_OFF, first);
    let mut group = c.benchmark_group("snapshot/big_entity");
    group.sample_size(10);
    group.throughput(Throughput::Elements(second.len() as u64));
    plain_and_publishing_each_insert(&mut group, &filled, second);
    group.finish();
}

criterion_group!(benches, take, streaming_writer, big_entity);
criterion_main!(benches);
