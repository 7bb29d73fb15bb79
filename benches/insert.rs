//! Insertion: whole chunks with compaction off, and single-row streams with compaction on
//! (in order, out of order, all at one time, and a 2 kHz stream over many series); and
//! inserting again what the store holds (idempotent ingest), as the same chunks and as
//! their rows under new ids.

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

/// Times inserting `again` into a clone of `store`, which holds their rows already; the
/// clone is made, and dropped, untimed.
fn bench_again(c: &mut Criterion, id: &str, store: &ChunkStore, again: &[Arc<Chunk>]) {
    let mut group = c.benchmark_group("insert_again");
    group.throughput(Throughput::Elements(
        again.iter().map(|c| c.num_rows() as u64).sum(),
    ));
    group.sample_size(10);
    group.bench_function(id, |b| {
        b.iter_batched(
            || store.clone(),
            |mut store| {
                for chunk in again {
                    let events = store.insert(Arc::clone(chunk)).expect("held rows");
                    assert!(events.is_empty(), "held rows change nothing");
                }
                store
            },
            BatchSize::LargeInput,
        );
    });
    group.finish();
}

/// Inserting again what the store holds: the same chunks (found by id), and the same rows
/// re-chunked under new ids (found row by row through the index), with compaction off and
/// on (where the rows live in merged chunks).
fn insert_again(c: &mut Criterion) {
    let mut ids = RowIds::new();
    let one = entities(1, |_| "e".to_owned());
    let frames: Vec<i64> = (0..100_000).collect();
    let batched = scalar_series(&mut ids, &one[0], &frames, 1000);
    // The same rows in chunks of 100 under new ids: what a re-chunked copy of a
    // recording looks like.
    let rechunked: Vec<Arc<Chunk>> = batched
        .iter()
        .flat_map(|chunk| (0..10).map(move |piece| (chunk, piece)))
        .map(|(chunk, piece)| {
            let rows = piece * 100..(piece + 1) * 100;
            let batch = chunk
                .to_record_batch()
                .expect("a chunk encodes")
                .slice(rows.start, rows.len());
            let mut batch_meta = batch.schema().metadata().clone();
            batch_meta.insert(
                "rerun:id".to_owned(),
                chunkstore::ChunkId::new().to_string(),
            );
            let schema = Arc::new(batch.schema().as_ref().clone().with_metadata(batch_meta));
            let batch = arrow_array::RecordBatch::try_new(schema, batch.columns().to_vec())
                .expect("the same columns");
            Arc::new(Chunk::from_record_batch(&batch).expect("a valid chunk"))
        })
        .collect();
    for (name, config) in [
        ("compaction_off", StoreConfig::COMPACTION_OFF),
        ("compaction_on", StoreConfig::DEFAULT),
    ] {
        let mut store = ChunkStore::with_config(config).expect("a valid config");
        for chunk in &batched {
            drop(store.insert(Arc::clone(chunk)).expect("consistent chunks"));
        }
        bench_again(
            c,
            &format!("same_chunks/100k_rows_in_1000_row_chunks/{name}"),
            &store,
            &batched,
        );
        bench_again(
            c,
            &format!("rechunked_under_new_ids/100k_rows_in_100_row_chunks/{name}"),
            &store,
            &rechunked,
        );
    }
}

criterion_group!(benches, insert, insert_again);
criterion_main!(benches);
