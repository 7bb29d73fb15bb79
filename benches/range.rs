//! Range: sorted chunks in sequence, overlapping chunks that need a k-way merge, and one
//! long chunk beside many short ones. Every row is read back through [`RangeResult::runs`].

#![allow(
    clippy::expect_used,
    reason = "generated data is valid; a failure should stop the bench loudly"
)]

mod common;

use chunkstore::{ChunkStore, EntityPath, RangeQuery, StoreConfig, TimeInt, TimeRange};
use common::{FRAME, RowIds, SplitMix64, entities, for_each_first_f64, scalar_series, store_with};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

/// Sums every value of every range `[start, start + len)`, counting the rows visited.
fn visit(store: &ChunkStore, entity: &EntityPath, starts: &[i64], len: i64) -> (u64, f64) {
    let (mut rows, mut sum) = (0, 0.0);
    for &start in starts {
        let bounds = (TimeInt::new(start), TimeInt::new(start + len - 1));
        let (Some(min), Some(max)) = bounds else {
            continue;
        };
        let result = store.range(
            &RangeQuery::new(FRAME, TimeRange::new(min, max)),
            entity,
            common::SCALAR,
        );
        for run in result.runs() {
            for_each_first_f64(&run, |v| {
                rows += 1;
                sum += v;
            });
        }
    }
    (rows, sum)
}

fn bench_ranges(
    c: &mut Criterion,
    id: &str,
    store: &ChunkStore,
    entity: &EntityPath,
    span: u64,
    len: i64,
) {
    let mut rng = SplitMix64::new();
    #[expect(clippy::cast_possible_wrap, reason = "small bench times")]
    let starts: Vec<i64> = (0..100).map(|_| rng.uniform(span) as i64).collect();
    let (rows, _) = visit(store, entity, &starts, len);
    let mut group = c.benchmark_group("range");
    group.throughput(Throughput::Elements(rows));
    group.bench_function(id, |b| b.iter(|| visit(store, entity, &starts, len)));
    group.finish();
}

fn range(c: &mut Criterion) {
    let mut ids = RowIds::new();
    let series = entities(1, |_| "series".to_owned());
    let entity = &series[0];

    let frames: Vec<i64> = (0..100_000).collect();
    let store = store_with(
        StoreConfig::COMPACTION_OFF,
        &scalar_series(&mut ids, entity, &frames, 1000),
    );
    bench_ranges(
        c,
        "sorted/100_chunks_of_1000/10k_row_ranges",
        &store,
        entity,
        90_000,
        10_000,
    );

    // Chunks of 1,000 random frames each: every chunk overlaps every other.
    let shuffled = SplitMix64::new().permutation(100_000);
    let store = store_with(
        StoreConfig::COMPACTION_OFF,
        &scalar_series(&mut ids, entity, &shuffled, 1000),
    );
    bench_ranges(
        c,
        "overlapping/100_unsorted_chunks/1k_row_ranges",
        &store,
        entity,
        99_000,
        1000,
    );

    // The same rows after compaction on insert.
    let store = store_with(
        StoreConfig::DEFAULT,
        &scalar_series(&mut ids, entity, &shuffled, 1),
    );
    bench_ranges(
        c,
        "out_of_order_compacted/100k_rows/1k_row_ranges",
        &store,
        entity,
        99_000,
        1000,
    );

    // One chunk of every even frame beside single-row chunks of the odd ones.
    let even: Vec<i64> = (0..10_000).map(|f| f * 2).collect();
    let odd: Vec<i64> = (0..10_000).map(|f| f * 2 + 1).collect();
    let mut chunks = scalar_series(&mut ids, entity, &even, 10_000);
    chunks.extend(scalar_series(&mut ids, entity, &odd, 1));
    let store = store_with(StoreConfig::COMPACTION_OFF, &chunks);
    bench_ranges(
        c,
        "one_long_chunk_beside_10k_short/1k_frame_ranges",
        &store,
        entity,
        19_000,
        1000,
    );
}

criterion_group!(benches, range);
criterion_main!(benches);
