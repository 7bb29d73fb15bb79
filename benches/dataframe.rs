//! Dataframe views: the table (1,000 entities × 3 components × 10,000 times, every
//! entity on its own frame offset) streamed whole, sparse and filled, over all frames and
//! over 1% of them, and sampled at 100 frames. Throughput is in cells (rows × data
//! columns), each batch read through once. `DATAFRAME_SCALE=N` divides the entities and
//! the times by N, to iterate quickly.

#![allow(
    clippy::expect_used,
    reason = "generated data is valid; a failure should stop the bench loudly"
)]

mod common;

use chunkstore::{DataframeQuery, StoreConfig, TimeInt, TimeRange};
use common::{FRAME, at, dataframe_chunks, store_with, stream_dataframe};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

fn dataframe(c: &mut Criterion) {
    let scale = std::env::var("DATAFRAME_SCALE")
        .ok()
        .and_then(|s| s.parse::<usize>().ok())
        .filter(|&s| s >= 1)
        .unwrap_or(1);
    let (entities, times) = (1_000 / scale, 10_000 / scale);
    let store = store_with(
        StoreConfig::COMPACTION_OFF,
        &dataframe_chunks(entities, times, 1_000),
    );
    #[expect(clippy::cast_possible_wrap, reason = "small bench times")]
    let frames = 3 * times as i64;
    let one_percent = TimeRange::new(at(frames / 2), at(frames / 2 + frames / 100 - 1));
    let samples: Vec<TimeInt> = (0..100).map(|k| at(k * frames / 100)).collect();

    let mut group = c.benchmark_group("dataframe");
    group.sample_size(10);
    for (id, query) in [
        ("sparse_all", DataframeQuery::new(FRAME)),
        (
            "filled_all",
            DataframeQuery::new(FRAME).with_fill_latest_at(true),
        ),
        (
            "sparse_1pct",
            DataframeQuery::new(FRAME).with_range(one_percent),
        ),
        (
            "filled_1pct",
            DataframeQuery::new(FRAME)
                .with_range(one_percent)
                .with_fill_latest_at(true),
        ),
        (
            "sampled_100",
            DataframeQuery::new(FRAME).with_index_values(samples.iter().copied()),
        ),
    ] {
        let (rows, columns, _) = stream_dataframe(&store, &query);
        group.throughput(Throughput::Elements(rows * columns));
        group.bench_function(id, |b| b.iter(|| stream_dataframe(&store, &query)));
    }
    group.finish();
}

criterion_group!(benches, dataframe);
criterion_main!(benches);
