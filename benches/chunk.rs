//! Chunk construction as the number of components grows: `Chunk::try_new` from whole
//! columns, `ChunkBuilder` row by row, and inserting the result into a store. Each should
//! grow as `n log n` at worst (issue 12 measured `Chunk::try_new` at 4.2 s for 10,000
//! components and over ten minutes for 100,000 before buffers were deduplicated by sorting).

#![allow(
    clippy::expect_used,
    reason = "generated data is valid; a failure should stop the bench loudly"
)]

mod common;

use std::sync::Arc;

use arrow_array::{ArrayRef, Float64Array, Int64Array};
use chunkstore::{
    Chunk, ChunkBuilder, ChunkId, ChunkStore, ComponentDescriptor, EntityPath, RowId, Timeline,
};
use common::{FRAME, scalars};
use criterion::{BatchSize, BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};

/// `n` one-row `List<Float64>` columns named `c0`, `c1`, ...
fn columns(n: usize) -> Vec<(ComponentDescriptor, ArrayRef)> {
    (0..n)
        .map(|i| {
            let name = format!("c{i}");
            (ComponentDescriptor::new(name.as_str()), scalars(vec![1.0]))
        })
        .collect()
}

fn wide_chunk(columns: Vec<(ComponentDescriptor, ArrayRef)>) -> Chunk {
    Chunk::try_new(
        ChunkId::new(),
        EntityPath::parse("wide").expect("a valid path"),
        vec![RowId::new()],
        vec![(
            Timeline::sequence(FRAME),
            Arc::new(Int64Array::from(vec![1])) as ArrayRef,
        )],
        columns,
    )
    .expect("valid columns")
}

fn chunk(c: &mut Criterion) {
    let mut group = c.benchmark_group("chunk");
    group.sample_size(10);
    for n in [1_000, 10_000, 100_000] {
        group.throughput(Throughput::Elements(n as u64));
        group.bench_with_input(BenchmarkId::new("try_new/components", n), &n, |b, &n| {
            b.iter_batched(|| columns(n), wide_chunk, BatchSize::LargeInput);
        });
        group.bench_with_input(BenchmarkId::new("builder/components", n), &n, |b, &n| {
            let cells: Vec<(String, ArrayRef)> = (0..n)
                .map(|i| {
                    let cell = Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
                    (format!("c{i}"), cell)
                })
                .collect();
            b.iter(|| {
                ChunkBuilder::new(ChunkId::new(), EntityPath::parse("wide").expect("valid"))
                    .with_row(
                        RowId::new(),
                        [(Timeline::sequence(FRAME), 1)],
                        cells
                            .iter()
                            .map(|(name, cell)| (name.as_str(), Arc::clone(cell))),
                    )
                    .build()
                    .expect("valid cells")
            });
        });
        group.bench_with_input(BenchmarkId::new("insert/components", n), &n, |b, &n| {
            b.iter_batched(
                || (ChunkStore::new(), Arc::new(wide_chunk(columns(n)))),
                |(mut store, chunk)| {
                    drop(store.insert(chunk).expect("a consistent chunk"));
                    store
                },
                BatchSize::LargeInput,
            );
        });
    }
    group.finish();
}

criterion_group!(benches, chunk);
criterion_main!(benches);
