//! SQL over a generated store: a 1% time-range aggregation with the range pushed down to
//! the store's index, and the same query with pushdown defeated (`frame % 2^62`, which
//! keeps every frame here; `benches/sql_engines.py` says why not `frame + 0`), then an
//! aggregation over the chunk table for one entity and for all, reporting chunks read,
//! wall time and memory; optionally the store's dataframe view as one sorted
//! Parquet file, for the same query through other engines (DataFusion's Python package,
//! DuckDB).
//!
//! ```sh
//! cargo run --release --features datafusion --example sql_bench -- 100 1000000 1000 [PARQUET]
//! ```
//! (entities, frames, rows per chunk: 100 entities × 1,000,000 frames = 100 M rows;
//! `SQL_BENCH_ONLY=pushdown` runs that query alone, for a profiler; `SQL_BENCH_RUNS=11`
//! runs each query 11 times rather than 3; `DATAFUSION_EXECUTION_TARGET_PARTITIONS=1`
//! builds each range in one part). Every
//! entity `/e/{i}` logs `x` = frame + i at every frame, in chunks of consecutive frames,
//! compaction off (the chunks as generated).
#![allow(
    clippy::expect_used,
    clippy::cast_precision_loss,
    clippy::cast_possible_wrap,
    reason = "a benchmark over generated data: failing loudly is its error handling, and its sizes are small integers"
)]

use std::sync::Arc;
use std::time::Instant;

use arrow_array::{ArrayRef, Float64Array, Int64Array, ListArray};
use arrow_buffer::OffsetBuffer;
use arrow_schema::{DataType, Field};
use chunkstore::parquet::{ParquetOptions, write_parquet_file};
use chunkstore::sql::StoreScanExec;
use chunkstore::{
    Chunk, ChunkId, ChunkStore, DataframeQuery, EntityPath, RowId, StoreConfig, Timeline,
};
use datafusion::physical_plan::{ExecutionPlan, collect};
use datafusion::prelude::SessionContext;

fn arg(n: usize, default: usize) -> usize {
    std::env::args()
        .nth(n)
        .and_then(|a| a.parse().ok())
        .unwrap_or(default)
}

/// `VmHWM` and `VmRSS` from `/proc/self/status`, in MiB.
fn memory() -> (u64, u64) {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |name: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
            .map_or(0, |kib| kib / 1024)
    };
    (field("VmHWM:"), field("VmRSS:"))
}

fn build(entities: usize, frames: usize, rows_per_chunk: usize) -> ChunkStore {
    let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).expect("a valid config");
    let item = Arc::new(Field::new("item", DataType::Float64, true));
    for start in (0..frames).step_by(rows_per_chunk) {
        let end = (start + rows_per_chunk).min(frames);
        let rows = end - start;
        for e in 0..entities {
            let entity = EntityPath::parse(&format!("/e/{e}")).expect("a valid path");
            let times: ArrayRef =
                Arc::new(Int64Array::from_iter_values((start..end).map(|f| f as i64)));
            let values = Float64Array::from_iter_values((start..end).map(|f| (f + e) as f64));
            let list = ListArray::new(
                Arc::clone(&item),
                OffsetBuffer::from_lengths(std::iter::repeat_n(1, rows)),
                Arc::new(values),
                None,
            );
            let chunk = Chunk::try_new(
                ChunkId::new(),
                entity,
                (0..rows).map(|_| RowId::new()).collect(),
                vec![(Timeline::sequence("frame"), times)],
                vec![("x".into(), Arc::new(list) as ArrayRef)],
            )
            .expect("a valid chunk");
            store.insert(chunk).expect("a valid insert");
        }
    }
    store
}

struct Run {
    seconds: f64,
    chunks_read: usize,
    answer: String,
}

fn chunks_read(plan: &dyn ExecutionPlan) -> usize {
    let own = plan
        .downcast_ref::<StoreScanExec>()
        .and_then(ExecutionPlan::metrics)
        .and_then(|m| m.sum_by_name("chunks_read"))
        .map_or(0, |v| v.as_usize());
    own + plan
        .children()
        .into_iter()
        .map(|c| chunks_read(c.as_ref()))
        .sum::<usize>()
}

fn run(runtime: &tokio::runtime::Runtime, ctx: &SessionContext, sql: &str) -> Run {
    runtime.block_on(async {
        let start = Instant::now();
        let frame = ctx.sql(sql).await.expect("a valid query");
        let plan = frame.create_physical_plan().await.expect("a plan");
        let batches = collect(Arc::clone(&plan), ctx.task_ctx())
            .await
            .expect("an answer");
        let seconds = start.elapsed().as_secs_f64();
        let answer = datafusion::arrow::util::pretty::pretty_format_batches(&batches)
            .map(|t| t.to_string().lines().nth(3).unwrap_or_default().to_owned())
            .unwrap_or_default();
        Run {
            seconds,
            chunks_read: chunks_read(plan.as_ref()),
            answer,
        }
    })
}

/// One line per query: every run's time, and the first run apart from the later ones. The
/// first run of a query gathers the view's rows, which the snapshot keeps; the later runs
/// read only the columns they output.
fn report(name: &str, runs: &[Run]) {
    let (hwm, rss) = memory();
    let later = runs.get(1..).unwrap_or_default();
    let last = runs.last().expect("at least one run");
    println!(
        "{name:>12}: median {:.4} s of {:?}, chunks read {} (first run) / {} (last), answer {}; \
         later runs median {:.4} s; RSS {rss} MiB, peak {hwm} MiB",
        median(runs.iter().map(|r| r.seconds).collect()),
        runs.iter()
            .map(|r| format!("{:.4}", r.seconds))
            .collect::<Vec<_>>(),
        runs[0].chunks_read,
        last.chunks_read,
        runs[0].answer.trim(),
        if later.is_empty() {
            f64::NAN
        } else {
            median(later.iter().map(|r| r.seconds).collect())
        },
    );
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn main() {
    let entities = arg(1, 100);
    let frames = arg(2, 100_000);
    let rows_per_chunk = arg(3, 1_000);
    let parquet = std::env::args().nth(4);
    // One query alone (`SQL_BENCH_ONLY=pushdown`), for a profiler.
    let only = std::env::var("SQL_BENCH_ONLY").ok();
    // Runs per query (the median is reported): `SQL_BENCH_RUNS`, 3 by default.
    let repeats: usize = std::env::var("SQL_BENCH_RUNS")
        .ok()
        .and_then(|r| r.parse().ok())
        .filter(|&r| r > 0)
        .unwrap_or(3);
    let start = Instant::now();
    let store = build(entities, frames, rows_per_chunk);
    let (hwm, rss) = memory();
    println!(
        "store: {} rows in {} chunks ({:.0} MiB by its own count), built in {:.1} s; RSS {rss} MiB, peak {hwm} MiB",
        entities * frames,
        store.num_chunks(),
        store.stats().heap_bytes as f64 / f64::from(1 << 20),
        start.elapsed().as_secs_f64()
    );
    let snapshot = store.snapshot();
    // `DATAFUSION_EXECUTION_TARGET_PARTITIONS=1` builds each range in one part.
    let ctx = SessionContext::new_with_config(
        datafusion::prelude::SessionConfig::from_env().expect("a valid DataFusion environment"),
    );
    chunkstore::sql::register(&ctx, &snapshot).expect("registered");
    // A worker per core for DataFusion's partitions, as `chunkstore sql` runs (the
    // scan's parts have threads of their own either way).
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .build()
        .expect("a runtime");
    let (lo, hi) = (frames / 2, frames / 2 + frames / 100 - 1);
    let overlapping = snapshot
        .chunks()
        .iter()
        .filter(|c| {
            c.time_column("frame").is_some_and(|t| {
                let range = t.time_range();
                range.min().as_i64() <= hi as i64 && lo as i64 <= range.max().as_i64()
            })
        })
        .count();
    println!("range [{lo}, {hi}] (1% of the frames): {overlapping} chunks overlap it");
    let query = |column: &str| {
        format!(
            r#"SELECT count(*) AS n, avg("/e/7:x"[1]) AS mean FROM frame WHERE {column} BETWEEN {lo} AND {hi}"#
        )
    };
    for (name, sql) in [
        ("pushdown", query("frame")),
        ("no pushdown", query("frame % 4611686018427387904")),
        // The chunk table: one entity's rows (an entity filter pushed down), then every
        // row with one component column built (the projection pushed down).
        (
            "chunks /e/7",
            "SELECT count(*) AS n, avg(x[1]) AS mean FROM chunks WHERE entity_path = '/e/7'"
                .to_owned(),
        ),
        (
            "chunks all",
            "SELECT count(*) AS n, avg(x[1]) AS mean FROM chunks".to_owned(),
        ),
    ] {
        if only.as_ref().is_some_and(|only| only != name) {
            continue;
        }
        let runs: Vec<Run> = (0..repeats).map(|_| run(&runtime, &ctx, &sql)).collect();
        report(name, &runs);
    }
    if let Some(path) = parquet {
        let start = Instant::now();
        let stream = store
            .dataframe(&DataframeQuery::new("frame"))
            .expect("the view");
        let summary = write_parquet_file(
            path.as_ref(),
            stream,
            &ParquetOptions::default().with_sorted_by("frame"),
        )
        .expect("written");
        println!(
            "parquet: {} rows, {} row groups, {:.0} MiB, written in {:.1} s to {path}",
            summary.rows,
            summary.row_groups,
            summary.bytes as f64 / f64::from(1 << 20),
            start.elapsed().as_secs_f64()
        );
    }
}
