//! Datasets at scale (issue 36): generate many recordings, then measure what opening them
//! as a dataset and querying across them costs. Each measurement prints one JSON line;
//! peak RSS is the process's high-water mark (`VmHWM`, Linux).
//!
//! ```text
//! cargo run --release --example dataset_bench -- generate DIR 1000 10   # 1,000 files of ~10 MiB
//! cargo run --release --example dataset_bench -- open DIR               # footers only
//! cargo run --release --example dataset_bench -- range DIR BUDGET_MIB  # a 1% range, aggregated
//! cargo run --release --example dataset_bench -- scan DIR BUDGET_MIB   # one component, everywhere
//! cargo run --release --example dataset_bench -- table DIR BUDGET_MIB  # one entity's columns, everywhere
//! ```
//!
//! `DATASET_THREADS=N` sets the threads that read segments (by default one per core).
//! DIR may be a URL (`s3://bucket/ds1000/`, feature `object-store`): credentials from
//! the environment, and `STORAGE_OPTIONS=key=value,key=value` for more (with
//! `chunkstore_added_latency_ms=20`, a fixed delay per request); each line then has the
//! requests and bytes the step asked of the store.
//! `table` asks what `benches/dataset_catalog.py` asks Rerun's catalog server (one entity's
//! whole table, every column), so that the two compare.
//!
//! Each recording (`episode-NNNN`): 20 entities (`/robot/sensor<s>`), chunks of 512 rows on
//! a `frame` timeline, every row a `scalar` and 32 `position3d` points of sensor noise (LZ4
//! barely compresses them), until the file reaches its size.

#![allow(
    clippy::expect_used,
    clippy::cast_possible_wrap,
    clippy::cast_precision_loss,
    reason = "generated data is valid and small; a failure should stop the run loudly"
)]

#[path = "../benches/common/mod.rs"]
mod common;

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use arrow_array::cast::AsArray;
use arrow_array::types::Float64Type;
use chunkstore::dataset::{Dataset, DatasetOptions};
use chunkstore::rrd::{RrdWriter, StoreId};
use chunkstore::{DataframeQuery, EntityPath, EntityPathFilter, TimeInt, TimeRange};

const ENTITIES: usize = 20;
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
        ["generate", dir, segments, mib] => generate(dir, segments.parse()?, mib.parse()?),
        ["open", dir] => open(dir),
        ["range", dir, budget] => range(dir, budget.parse()?),
        ["scan", dir, budget] => scan(dir, budget.parse()?),
        ["table", dir, budget] => table(dir, budget.parse()?),
        #[cfg(all(feature = "object-store", feature = "parquet"))]
        ["delta", dir, table] => delta(dir, table),
        _ => Err(
            "usage: dataset_bench generate DIR SEGMENTS MIB | open DIR | range DIR \
                  BUDGET_MIB | scan DIR BUDGET_MIB | table DIR BUDGET_MIB | delta DIR TABLE_URL"
                .into(),
        ),
    }
}

fn write_segment(
    dir: &Path,
    n: usize,
    mib: u64,
) -> Result<u64, Box<dyn std::error::Error + Send + Sync>> {
    let id = format!("episode-{n:04}");
    let file = std::io::BufWriter::new(std::fs::File::create(dir.join(format!("{id}.rrd")))?);
    let mut writer = RrdWriter::new(file, StoreId::recording("dataset_bench", id.as_str()))?;
    let entities: Vec<EntityPath> = (0..ENTITIES)
        .map(|s| EntityPath::parse(&format!("/robot/sensor{s}")).expect("a valid path"))
        .collect();
    let mut seed = 0x9e37_79b9_7f4a_7c15_u64 ^ (n as u64).wrapping_mul(0x2545_f491_4f6c_dd1d);
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
        }
        round += 1;
    }
    let size = writer.position();
    writer.finish()?;
    Ok(size)
}

fn generate(dir: &str, segments: usize, mib: u64) -> Result<(), Box<dyn std::error::Error>> {
    let started = Instant::now();
    let dir = Path::new(dir);
    std::fs::create_dir_all(dir)?;
    let next = std::sync::atomic::AtomicUsize::new(0);
    let threads = std::thread::available_parallelism().map_or(1, usize::from);
    let bytes: u64 = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                scope.spawn(|| {
                    let mut bytes = 0;
                    loop {
                        let n = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        if n >= segments {
                            return bytes;
                        }
                        bytes += write_segment(dir, n, mib).expect("a writable directory");
                    }
                })
            })
            .collect();
        workers
            .into_iter()
            .map(|w| w.join().expect("a worker"))
            .sum()
    });
    println!(
        "{{\"generated\":{:?},\"segments\":{segments},\"bytes\":{bytes},\"seconds\":{:.1}}}",
        dir.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Threads a dataset reads with: `DATASET_THREADS`, by default one per core.
fn threads() -> usize {
    std::env::var("DATASET_THREADS")
        .ok()
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| DatasetOptions::default().threads)
}

fn opened(dir: &str, budget_mib: u64) -> Result<(Dataset, f64), Box<dyn std::error::Error>> {
    let started = Instant::now();
    let options = DatasetOptions::default()
        .with_memory_budget(budget_mib << 20)
        .with_threads(threads())
        .with_storage(storage_options());
    let dataset = Dataset::open(dir.as_ref(), &options)?;
    Ok((dataset, started.elapsed().as_secs_f64()))
}

fn open(dir: &str) -> Result<(), Box<dyn std::error::Error>> {
    let before = Requests::now();
    let (dataset, seconds) = opened(dir, 0)?;
    let segments = dataset.segments();
    println!(
        "{{\"open\":{dir:?},\"segments\":{},\"chunks\":{},\"file_bytes\":{},\"seconds\":{seconds:.3},\"peak_rss\":{}{}}}",
        segments.len(),
        segments.iter().map(|s| s.num_chunks).sum::<u64>(),
        segments.iter().map(|s| s.file_bytes).sum::<u64>(),
        common::peak_rss(),
        before.since_json()
    );
    Ok(())
}

/// `STORAGE_OPTIONS`: `key=value` pairs, comma-separated.
fn storage_options() -> chunkstore::storage::StorageOptions {
    std::env::var("STORAGE_OPTIONS")
        .unwrap_or_default()
        .split(',')
        .filter_map(|pair| pair.split_once('='))
        .collect()
}

/// The object-store requests made since it was taken (none without the feature).
struct Requests {
    #[cfg(feature = "object-store")]
    at: chunkstore::storage::object::StorageCounters,
}

impl Requests {
    fn now() -> Self {
        Self {
            #[cfg(feature = "object-store")]
            at: chunkstore::storage::object::counters(),
        }
    }

    /// The requests since, as JSON fields to append to a line (`,"gets":…`).
    fn since_json(&self) -> String {
        #[cfg(feature = "object-store")]
        {
            let c = chunkstore::storage::object::counters().since(&self.at);
            format!(
                ",\"gets\":{},\"lists\":{},\"bytes_fetched\":{},\"puts\":{},\"bytes_sent\":{}",
                c.gets, c.lists, c.bytes_fetched, c.puts, c.bytes_sent
            )
        }
        #[cfg(not(feature = "object-store"))]
        String::new()
    }
}

/// The dataset's telemetry (every sensor's scalar on `frame`, not the point clouds) as a
/// Delta table under the prefix `table`, a partition per segment and per tenth of
/// `frame`'s span: what an analytics export of it is, for engines that read Delta (the
/// storage bench's DuckDB run).
#[cfg(all(feature = "object-store", feature = "parquet"))]
fn delta(dir: &str, table: &str) -> Result<(), Box<dyn std::error::Error>> {
    use chunkstore::parquet::HiveLayout;
    let (dataset, _) = opened(dir, 0)?;
    let span = dataset.time_range("frame").ok_or("no frame timeline")?;
    let width = ((span.max().as_i64() - span.min().as_i64()) / 10).max(1);
    let columns = std::iter::once("frame".to_owned())
        .chain((0..ENTITIES).map(|s| format!("/robot/sensor{s}:scalar")));
    let query = DataframeQuery::new("frame")
        .with_contents(EntityPathFilter::parse(["/robot/**"]).expect("a valid filter"))
        .with_columns(columns);
    let layout = HiveLayout::ByTimeBucket {
        timeline: "frame".into(),
        width,
        query: Some(query),
    };
    let store = chunkstore::storage::object::ObjectTable::new(
        table,
        &storage_options(),
        Arc::new(std::sync::atomic::AtomicBool::new(false)),
    )?;
    let before = Requests::now();
    let started = Instant::now();
    let commit = dataset.write_delta(&store, &layout, false, &|_, _| {})?;
    println!(
        "{{\"delta\":{table:?},\"bucket_width\":{width},\"version\":{},\"files\":{},\"rows\":{},\"bytes\":{},\"seconds\":{:.3},\"peak_rss\":{}{}}}",
        commit.version,
        commit.files.len(),
        commit.rows(),
        commit.files.iter().map(|(_, f)| f.bytes).sum::<u64>(),
        started.elapsed().as_secs_f64(),
        common::peak_rss(),
        before.since_json()
    );
    Ok(())
}

/// One scalar column of one entity, on `range` (or everywhere).
fn scalar_query(range: Option<TimeRange>) -> DataframeQuery {
    let query = DataframeQuery::new("frame")
        .with_contents(EntityPathFilter::parse(["/robot/sensor0"]).expect("a valid filter"))
        .with_columns(["frame", "/robot/sensor0:scalar"]);
    match range {
        Some(range) => query.with_range(range),
        None => query,
    }
}

/// Rows and the sum of the scalars of a table of `scalar_query`'s columns.
fn aggregate(
    dataset: &Dataset,
    query: &DataframeQuery,
) -> Result<(u64, f64), Box<dyn std::error::Error>> {
    let (mut rows, mut sum) = (0u64, 0.0);
    for batch in dataset.dataframe(query)? {
        let batch = batch?;
        rows += batch.num_rows() as u64;
        let column = batch.column(2).as_list::<i32>();
        sum += column
            .values()
            .as_primitive::<Float64Type>()
            .values()
            .iter()
            .sum::<f64>();
    }
    Ok((rows, sum))
}

fn range(dir: &str, budget_mib: u64) -> Result<(), Box<dyn std::error::Error>> {
    let (dataset, open_seconds) = opened(dir, budget_mib)?;
    let span = dataset.time_range("frame").ok_or("no frame timeline")?;
    let (lo, hi) = (span.min().as_i64(), span.max().as_i64());
    let width = ((hi - lo) / 100).max(1);
    let start = lo + (hi - lo) / 2;
    let range = TimeRange::new(
        TimeInt::new(start).ok_or("time")?,
        TimeInt::new(start + width - 1).ok_or("time")?,
    );
    let started = Instant::now();
    let before = Requests::now();
    let (rows, sum) = aggregate(&dataset, &scalar_query(Some(range)))?;
    let read = dataset.read_stats();
    let segments = dataset.segments();
    println!(
        "{{\"range\":[{start},{}],\"rows\":{rows},\"sum\":{sum:.3},\"open_seconds\":{open_seconds:.3},\"seconds\":{:.3},\"chunks_decoded\":{},\"chunks\":{},\"bytes_read\":{},\"file_bytes\":{},\"budget_mib\":{budget_mib},\"peak_rss\":{}{}}}",
        start + width - 1,
        started.elapsed().as_secs_f64(),
        read.chunks_decoded,
        segments.iter().map(|s| s.num_chunks).sum::<u64>(),
        read.bytes_read,
        segments.iter().map(|s| s.file_bytes).sum::<u64>(),
        common::peak_rss(),
        before.since_json()
    );
    Ok(())
}

fn scan(dir: &str, budget_mib: u64) -> Result<(), Box<dyn std::error::Error>> {
    let (dataset, _) = opened(dir, budget_mib)?;
    let started = Instant::now();
    let (rows, sum) = aggregate(&dataset, &scalar_query(None))?;
    let seconds = started.elapsed().as_secs_f64();
    let read = dataset.read_stats();
    println!(
        "{{\"scan\":{dir:?},\"rows\":{rows},\"sum\":{sum:.3},\"seconds\":{seconds:.3},\"rows_per_second\":{:.0},\"chunks_decoded\":{},\"bytes_read\":{},\"budget_mib\":{budget_mib},\"threads\":{},\"peak_rss\":{}}}",
        rows as f64 / seconds,
        read.chunks_decoded,
        read.bytes_read,
        threads(),
        common::peak_rss()
    );
    Ok(())
}

/// Every column of one entity (`/robot/sensor0`), in every segment, read to the end.
fn table(dir: &str, budget_mib: u64) -> Result<(), Box<dyn std::error::Error>> {
    let (dataset, open_seconds) = opened(dir, budget_mib)?;
    let started = Instant::now();
    let query = DataframeQuery::new("frame")
        .with_contents(EntityPathFilter::parse(["/robot/sensor0"]).expect("a valid filter"));
    let (mut rows, mut columns) = (0u64, 0);
    for batch in dataset.dataframe(&query)? {
        let batch = batch?;
        rows += batch.num_rows() as u64;
        columns = batch.num_columns();
    }
    let seconds = started.elapsed().as_secs_f64();
    println!(
        "{{\"table\":{dir:?},\"rows\":{rows},\"columns\":{columns},\"open_seconds\":{open_seconds:.3},\"seconds\":{seconds:.3},\"budget_mib\":{budget_mib},\"threads\":{},\"peak_rss\":{}}}",
        threads(),
        common::peak_rss()
    );
    Ok(())
}
