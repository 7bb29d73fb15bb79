//! `.rrd` files at scale: generate a large recording, then measure what opening it costs,
//! eagerly and lazily. Each measuring command prints one JSON line; peak RSS is the
//! process's high-water mark (`VmHWM`, Linux).
//!
//! ```text
//! cargo run --release --example rrd_scale -- generate big.rrd 1024   # ~1024 MiB on disk
//! cargo run --release --example rrd_scale -- lazy big.rrd            # one latest-at, lazily
//! cargo run --release --example rrd_scale -- eager big.rrd           # every chunk into a store
//! ```
//!
//! The recording: 400 entities (`/robot<r>/sensor<s>`), each logging chunks of 512 rows on
//! a `frame` sequence timeline, every row a `scalar` and 32 `position3d` points (LZ4 barely
//! compresses them: sensor noise).

#![allow(
    clippy::expect_used,
    clippy::cast_possible_wrap,
    reason = "generated data is valid and small; a failure should stop the run loudly"
)]

#[path = "../benches/common/mod.rs"]
mod common;

use std::sync::Arc;
use std::time::Instant;

use chunkstore::rrd::{LazyRecording, RrdItem, RrdReader, RrdWriter, StoreId};
use chunkstore::{ChunkStore, EntityPath, LatestAtQuery, TimeInt};

const ENTITIES: usize = 400;
const ROWS: usize = 512;
const POINTS: usize = 32;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>()
        .as_slice()
    {
        ["generate", path, mib] => generate(path, mib.parse()?),
        ["lazy", path] => lazy(path),
        ["eager", path] => eager(path),
        _ => Err("usage: rrd_scale generate <PATH> <MiB> | lazy <PATH> | eager <PATH>".into()),
    }
}

fn entity(i: usize) -> EntityPath {
    EntityPath::parse(&format!("/robot{}/sensor{}", i / 20, i % 20)).expect("a valid path")
}

fn generate(path: &str, mib: u64) -> Result<(), Box<dyn std::error::Error>> {
    let started = Instant::now();
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut writer = RrdWriter::new(file, StoreId::recording("rrd_scale", "big"))?;
    let entities: Vec<EntityPath> = (0..ENTITIES).map(entity).collect();
    let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
    let mut chunks = 0u64;
    let mut round = 0i64;
    while writer.position() < mib << 20 {
        for entity in &entities {
            writer.write_chunk(&Arc::new(common::sensor_chunk(
                entity,
                round * ROWS as i64,
                ROWS,
                POINTS,
                &mut seed,
            )))?;
            chunks += 1;
        }
        round += 1;
    }
    let size = writer.position();
    writer.finish()?;
    println!(
        "{{\"generated\":{path:?},\"bytes\":{size},\"chunks\":{chunks},\"rounds\":{round},\"seconds\":{:.1}}}",
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

fn lazy(path: &str) -> Result<(), Box<dyn std::error::Error>> {
    let started = Instant::now();
    let mut recording = LazyRecording::open(path.as_ref())?.ok_or("the file has no footer")?;
    let opened = started.elapsed();
    let after_open = recording.stats();
    let rss_open = common::peak_rss();
    let last = recording
        .time_range("frame")
        .ok_or("no frame timeline")?
        .max();
    let target = entity(ENTITIES / 2);
    let started = Instant::now();
    let query = LatestAtQuery::new("frame", last);
    let latest = recording
        .latest_at(&query, &target, "position3d")?
        .ok_or("no answer")?;
    let middle = LatestAtQuery::new("frame", TimeInt::new(last.as_i64() / 2).ok_or("time")?);
    let middle_answer = recording
        .latest_at(&middle, &target, "scalar")?
        .ok_or("no answer")?;
    let queried = started.elapsed();
    let stats = recording.stats();
    #[expect(clippy::cast_precision_loss, reason = "a ratio")]
    let fraction = stats.bytes_read as f64 / stats.file_bytes as f64;
    println!(
        "{{\"mode\":\"lazy\",\"file_bytes\":{},\"chunks_in_file\":{},\"open_ms\":{:.1},\"bytes_read_at_open\":{},\"two_latest_at_ms\":{:.1},\"bytes_read\":{},\"fraction_read\":{fraction:.6},\"chunks_decoded\":{},\"answer_times\":[{},{}],\"peak_rss_after_open\":{rss_open},\"peak_rss\":{}}}",
        stats.file_bytes,
        stats.chunks_in_file,
        opened.as_secs_f64() * 1e3,
        after_open.bytes_read,
        queried.as_secs_f64() * 1e3,
        stats.bytes_read,
        stats.chunks_decoded,
        latest.time().map_or(-1, TimeInt::as_i64),
        middle_answer.time().map_or(-1, TimeInt::as_i64),
        common::peak_rss()
    );
    Ok(())
}

fn eager(path: &str) -> Result<(), Box<dyn std::error::Error>> {
    let started = Instant::now();
    let file = std::fs::File::open(path)?;
    let reader = RrdReader::new(std::io::BufReader::with_capacity(1 << 20, file))?;
    // Compaction off: the chunks as the file has them (the store's default would merge
    // them further, copying).
    let mut store = ChunkStore::with_config(chunkstore::StoreConfig::COMPACTION_OFF)?;
    let mut decompressed = 0u64;
    for item in reader {
        match item? {
            RrdItem::Chunk { chunk, .. } => {
                store.insert(chunk)?;
            }
            RrdItem::Footer(manifests) => {
                decompressed = manifests
                    .iter()
                    .flat_map(|m| &m.entries)
                    .map(|e| e.uncompressed_size)
                    .sum();
            }
            _ => {}
        }
    }
    let loaded = started.elapsed();
    let stats = store.stats();
    let rss = common::peak_rss();
    #[expect(clippy::cast_precision_loss, reason = "a ratio")]
    let ratio = rss as f64 / decompressed as f64;
    println!(
        "{{\"mode\":\"eager\",\"chunks\":{},\"rows\":{},\"load_s\":{:.2},\"decompressed_payload_bytes\":{decompressed},\"store_heap_bytes\":{},\"peak_rss\":{rss},\"peak_rss_over_decompressed\":{ratio:.3}}}",
        stats.num_chunks(),
        stats.num_rows(),
        loaded.as_secs_f64(),
        stats.heap_bytes
    );
    Ok(())
}
