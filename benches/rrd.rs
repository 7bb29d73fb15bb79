//! `.rrd` decoding and encoding, beside the physical limit on the same bytes: LZ4
//! decompression of the payloads alone, and a memcpy of their decompressed size. Two
//! recordings: many small chunks (a streamed log: one row each) and few large ones
//! (point clouds, megabytes each). Throughput is decompressed payload bytes.

#![allow(
    clippy::expect_used,
    clippy::cast_precision_loss,
    clippy::cast_possible_truncation,
    clippy::cast_possible_wrap,
    clippy::cast_sign_loss,
    reason = "generated data is valid and small; a failure should stop the bench loudly"
)]

mod common;

use std::sync::Arc;

use arrow_buffer::Buffer;
use chunkstore::Chunk;
use chunkstore::rrd::{self, RrdWriter, StoreId};
use common::{RowIds, entities, positions, scalars, temporal_chunk};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

/// 20,000 one-row chunks over 100 entities: a scalar and one point each.
fn small_chunks() -> Vec<Arc<Chunk>> {
    let mut ids = RowIds::new();
    let paths = entities(100, |i| format!("/robot/sensor{i}"));
    (0..20_000_i64)
        .map(|i| {
            let f = i as f32;
            temporal_chunk(
                &mut ids,
                &paths[(i % 100) as usize],
                vec![i],
                vec![
                    ("scalar", scalars(vec![f64::from(f).sin()])),
                    (
                        "position",
                        positions(1, 1, |_, _| [f.cos(), f.sin(), f * 0.01]),
                    ),
                ],
            )
        })
        .collect()
}

/// 8 chunks of 32,768 rows of 16 points (6 MiB of points each).
fn large_chunks() -> Vec<Arc<Chunk>> {
    let mut ids = RowIds::new();
    let paths = entities(8, |i| format!("/lidar{i}"));
    (0..8)
        .map(|c| {
            let rows = 32_768;
            temporal_chunk(
                &mut ids,
                &paths[c],
                (0..rows as i64).collect(),
                vec![(
                    "points",
                    positions(rows, 16, |r, k| {
                        let a = (r * 16 + k) as f32 * 0.001;
                        [a.cos() * 10.0, a.sin() * 10.0, (a * 3.0).sin()]
                    }),
                )],
            )
        })
        .collect()
}

fn encode(chunks: &[Arc<Chunk>], compress: bool) -> Vec<u8> {
    let info = rrd::StoreInfo::new(StoreId::recording("bench", "rrd"));
    let mut writer = RrdWriter::with_store_info(Vec::new(), &info, compress).expect("in memory");
    for chunk in chunks {
        writer.write_chunk(chunk).expect("in memory");
    }
    writer.finish().expect("in memory")
}

/// The LZ4 blocks of the chunks' IPC streams, and the decompressed sizes: what a decoder
/// must at least decompress.
fn blocks(chunks: &[Arc<Chunk>]) -> Vec<(Vec<u8>, usize)> {
    chunks
        .iter()
        .map(|chunk| {
            let batch = chunk.to_record_batch().expect("valid");
            let mut ipc = Vec::new();
            let mut writer =
                arrow_ipc::writer::StreamWriter::try_new(&mut ipc, &batch.schema()).expect("valid");
            writer.write(&batch).expect("valid");
            writer.finish().expect("valid");
            drop(writer);
            (lz4_flex::block::compress(&ipc), ipc.len())
        })
        .collect()
}

fn rrd(c: &mut Criterion) {
    for (name, chunks) in [
        ("small_chunks", small_chunks()),
        ("large_chunks", large_chunks()),
    ] {
        let compressed = Buffer::from_vec(encode(&chunks, true));
        let uncompressed = Buffer::from_vec(encode(&chunks, false));
        let blocks = blocks(&chunks);
        let payload_bytes: usize = blocks.iter().map(|b| b.1).sum();
        let flat = vec![7u8; payload_bytes];
        println!(
            "{name}: {} chunks, {payload_bytes} payload bytes, file {} bytes (LZ4), {} bytes (none)",
            chunks.len(),
            compressed.len(),
            uncompressed.len()
        );
        let mut group = c.benchmark_group(format!("rrd/{name}"));
        group.sample_size(10);
        group.throughput(Throughput::Bytes(payload_bytes as u64));
        group.bench_function("decode_lz4", |b| {
            b.iter(|| {
                rrd::read_rrd(compressed.clone(), false)
                    .expect("valid")
                    .chunks
                    .len()
            });
        });
        group.bench_function("decode_uncompressed_zero_copy", |b| {
            b.iter(|| {
                rrd::read_rrd(uncompressed.clone(), false)
                    .expect("valid")
                    .chunks
                    .len()
            });
        });
        group.bench_function("decode_lz4_streamed", |b| {
            b.iter(|| {
                rrd::read_rrd_from(compressed.as_slice(), false)
                    .expect("valid")
                    .chunks
                    .len()
            });
        });
        // The limits keep what they produce until the end of the iteration, as a decoder
        // keeps its chunks: fresh memory (page faults included), not one reused buffer.
        group.bench_function("limit_lz4_decompress_only", |b| {
            b.iter(|| {
                let outputs: Vec<Vec<u8>> = blocks
                    .iter()
                    .map(|(block, size)| {
                        let mut out = vec![0u8; *size];
                        lz4_flex::block::decompress_into(block, &mut out).expect("valid");
                        out
                    })
                    .collect();
                std::hint::black_box(outputs)
            });
        });
        group.bench_function("limit_memcpy", |b| {
            b.iter(|| {
                let outputs: Vec<Vec<u8>> = blocks
                    .iter()
                    .scan(0, |at, (_, size)| {
                        let out = std::hint::black_box(&flat[*at..*at + size]).to_vec();
                        *at += size;
                        Some(out)
                    })
                    .collect();
                std::hint::black_box(outputs)
            });
        });
        group.bench_function("encode_lz4", |b| b.iter(|| encode(&chunks, true).len()));
        group.finish();
    }
}

criterion_group!(benches, rrd);
criterion_main!(benches);
