//! The reference workloads of `../shared/bench/WORKLOADS.md`, run on this crate:
//!
//! ```text
//! cargo run --release --example workloads -- <WORKLOAD|all>
//! ```
//!
//! prints one JSON line per timed phase, in the format `../shared/bench/compare` reads
//! beside the reference engine's. Every chunk and every query parameter is built before the
//! first timer starts; only the crate's public API is used, as an embedding application
//! would. A checksum other than the one WORKLOADS.md implies is reported on stderr and
//! makes the exit status 1.
#![allow(
    clippy::cast_precision_loss,
    clippy::cast_possible_truncation,
    clippy::cast_possible_wrap,
    clippy::cast_sign_loss,
    reason = "benchmark arithmetic on small counts and exact small float values"
)]
#![allow(
    clippy::expect_used,
    reason = "a measurement program: its own generated inputs are valid, and a failure should stop it loudly"
)]

#[path = "../benches/common/mod.rs"]
mod common;
#[path = "workloads/concurrent.rs"]
mod concurrent;
#[path = "workloads/scaling.rs"]
mod scaling;

use std::sync::Arc;
use std::time::Instant;

use chunkstore::{
    Chunk, ChunkStore, EntityPath, GcOptions, LatestAtQuery, QueryCell, RangeQuery, StoreConfig,
    TimeRange,
};
use common::{
    FRAME, POSITION3D, RowIds, SCALAR, SplitMix64, TEXT, at, clear_chunk, entities, first_text_len,
    latest_scalar, point_batch_queries, point_batches, points, positions, range_series,
    range_series_queries, scalars, static_chunk, store_with, sum_of_xy, temporal_chunk, texts,
    visit_range_scalars,
};

const IMPL: &str = concat!("chunkstore-", env!("CARGO_PKG_VERSION"));
/// Each timed phase runs this many times; the median is reported.
const RUNS: usize = 5;
/// A phase stops repeating once its runs have taken this long together (at least one run).
const PHASE_BUDGET_NS: f64 = 20e9;

const OFF: StoreConfig = StoreConfig::COMPACTION_OFF;
const DEFAULT: StoreConfig = StoreConfig::DEFAULT;

type Workload = fn() -> bool;

const WORKLOADS: [(&str, Workload); 10] = [
    ("insert_batched", insert_batched),
    ("insert_streaming", insert_streaming),
    ("latest_at_mono", latest_at_mono),
    ("latest_at_batch", latest_at_batch),
    ("range_scalar", range_scalar),
    ("out_of_order", out_of_order),
    ("gc_everything", gc_everything),
    ("gc_half", gc_half),
    ("static_shadow", static_shadow),
    ("clear_recursive", clear_recursive),
];

/// Workloads of this crate's own, outside WORKLOADS.md (so outside `all`, which the
/// comparison with the reference engine runs): named one by one.
const OWN_WORKLOADS: [(&str, Workload); 3] = [
    ("dataframe", dataframe),
    ("concurrent", concurrent::concurrent),
    ("scaling", scaling::scaling),
];

fn main() {
    let arg = std::env::args().nth(1).unwrap_or_default();
    let selected: Vec<_> = WORKLOADS
        .iter()
        .filter(|(name, _)| arg == "all" || arg == *name)
        .chain(OWN_WORKLOADS.iter().filter(|(name, _)| arg == *name))
        .collect();
    if selected.is_empty() {
        eprintln!("usage: workloads <WORKLOAD|all>");
        eprintln!(
            "workloads: {} (and, outside all: {})",
            WORKLOADS.map(|(n, _)| n).join(" "),
            OWN_WORKLOADS.map(|(n, _)| n).join(" ")
        );
        std::process::exit(2);
    }
    let mut all_ok = true;
    for (_, run) in selected {
        all_ok &= run();
    }
    if !all_ok {
        std::process::exit(1);
    }
}

// --- Timing ---

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Runs a query phase up to `RUNS` times on the same store; `f` returns `(ops, checksum)`,
/// identical in every run. Returns `(ops, median ns/op, checksum)`.
fn time_query(mut f: impl FnMut() -> (u64, u64)) -> (u64, f64, u64) {
    let mut per_op = Vec::with_capacity(RUNS);
    let mut first = None;
    let mut spent = 0.0;
    while per_op.len() < RUNS && spent < PHASE_BUDGET_NS {
        let start = Instant::now();
        let (ops, checksum) = std::hint::black_box(f());
        let ns = start.elapsed().as_nanos() as f64;
        spent += ns;
        assert_eq!(
            *first.get_or_insert((ops, checksum)),
            (ops, checksum),
            "every run of a query phase gives the same answers"
        );
        per_op.push(ns / ops.max(1) as f64);
    }
    let (ops, checksum) = first.expect("at least one run");
    (ops, median(per_op), checksum)
}

/// Runs an insert phase up to `RUNS` times, each into a fresh store (made and dropped
/// outside the timer); op = one inserted chunk. Returns the last store and the median.
fn time_inserts(config: StoreConfig, chunks: &[Arc<Chunk>]) -> (ChunkStore, f64) {
    let mut per_op = Vec::with_capacity(RUNS);
    let mut last = None;
    let mut spent = 0.0;
    while per_op.len() < RUNS && spent < PHASE_BUDGET_NS {
        drop(last.take());
        let mut store = ChunkStore::with_config(config).expect("a valid config");
        let start = Instant::now();
        for chunk in chunks {
            // The events are what an application hands on; dropped at once.
            drop(store.insert(Arc::clone(chunk)).expect("consistent chunks"));
        }
        let ns = start.elapsed().as_nanos() as f64;
        spent += ns;
        per_op.push(ns / chunks.len() as f64);
        last = Some(store);
    }
    (last.expect("at least one run"), median(per_op))
}

/// Runs `gc(options)` up to `RUNS` times, each on a fresh clone of `base` (cloned outside
/// the timer; the clone shares its chunks, so no payload is freed inside the timer, and the
/// events are dropped after it stops); op = one chunk dropped. Returns the last collected
/// store, the chunks dropped, and the median.
fn time_gc(base: &ChunkStore, options: &GcOptions) -> (ChunkStore, u64, f64) {
    let mut per_op = Vec::with_capacity(RUNS);
    let mut last = None;
    let mut dropped = 0;
    let mut spent = 0.0;
    while per_op.len() < RUNS && spent < PHASE_BUDGET_NS {
        drop(last.take());
        let mut store = base.clone();
        let before = store.num_chunks();
        let start = Instant::now();
        let events = store.gc(options);
        let ns = start.elapsed().as_nanos() as f64;
        drop(events);
        spent += ns;
        dropped = (before - store.num_chunks()) as u64;
        per_op.push(ns / dropped.max(1) as f64);
        last = Some(store);
    }
    (last.expect("at least one run"), dropped, median(per_op))
}

fn latest_at(
    store: &ChunkStore,
    timeline: &Arc<str>,
    t: i64,
    entity: &EntityPath,
    component: &str,
) -> Option<QueryCell> {
    store.latest_at(
        &LatestAtQuery::new(Arc::clone(timeline), at(t)),
        entity,
        component,
    )
}

// --- Reporting ---

struct Report {
    workload: &'static str,
    phase: &'static str,
    ops: u64,
    ns_per_op: f64,
    /// `None` where WORKLOADS.md defines no checksum for the phase.
    checksum: Option<u64>,
    /// What WORKLOADS.md says the checksum must be, or what follows from it.
    expected: Option<u64>,
}

impl Report {
    /// Prints the JSON line (`chunks` and `store_bytes` read from `store` now,
    /// `peak_rss_kib` from `/proc/self/status`); false if the checksum is wrong.
    fn emit(self, store: &ChunkStore) -> bool {
        let stats = store.stats();
        let checksum = self
            .checksum
            .map_or_else(|| "null".to_owned(), |c| c.to_string());
        println!(
            "{{\"workload\":\"{}\",\"phase\":\"{}\",\"impl\":\"{IMPL}\",\"ops\":{},\"ns_per_op\":{:.2},\"checksum\":{checksum},\"chunks\":{},\"store_bytes\":{},\"peak_rss_kib\":{}}}",
            self.workload,
            self.phase,
            self.ops,
            self.ns_per_op,
            stats.num_chunks(),
            stats.heap_bytes,
            peak_rss_kib(),
        );
        match self.expected {
            Some(expected) if self.checksum != Some(expected) => {
                eprintln!(
                    "CHECKSUM MISMATCH {}/{}: got {checksum}, expected {expected}",
                    self.workload, self.phase
                );
                false
            }
            _ => true,
        }
    }
}

// --- dataframe (this crate's own) ---

/// A positive whole number from the environment.
fn env_count(name: &str) -> Option<usize> {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|&s| s >= 1)
}

/// `DATAFRAME_SCALE` (default 1): entities = 1,000 / scale, times = 10,000 / scale;
/// `DATAFRAME_TIMES` sets the times alone (a longer table, as many columns).
fn dataframe_shape() -> (usize, usize) {
    let scale = env_count("DATAFRAME_SCALE").unwrap_or(1);
    (
        1_000 / scale,
        env_count("DATAFRAME_TIMES").unwrap_or(10_000 / scale),
    )
}

/// `DATAFRAME_PHASES=filled_all,...` runs only the phases named (for profiling).
fn phase_selected(phase: &str) -> bool {
    std::env::var("DATAFRAME_PHASES")
        .ok()
        .is_none_or(|only| only.split(',').any(|p| p == phase))
}

/// A dataframe view of 1,000 entities × 3 components × 10,000 times (sparse and filled,
/// whole and a 1% range), op = one output row; then the filled table streamed to a
/// Parquet file, with the peak RSS that adds. The checksum counts non-null cells.
fn dataframe() -> bool {
    use chunkstore::DataframeQuery;
    let (num_entities, times) = dataframe_shape();
    let chunks = common::dataframe_chunks(num_entities, times, 1_000);
    if let Some(path) = std::env::var_os("DATAFRAME_RRD") {
        // The same data for another engine (Rerun's Python dataframe reader, in
        // docs/PERFORMANCE.md): written, then the workload runs as usual.
        let info = chunkstore::rrd::StoreInfo::new(chunkstore::rrd::StoreId::recording(
            "dataframe_workload",
            "scale",
        ));
        chunkstore::rrd::write_rrd_file(path.as_ref(), &info, chunks.iter().cloned(), |_| {})
            .expect("a writable path");
    }
    let store = store_with(OFF, &chunks);
    drop(chunks);
    let frames = 3 * times as i64;
    let one_percent = TimeRange::new(at(frames / 2), at(frames / 2 + frames / 100 - 1));
    let mut ok = true;
    for (phase, fill, range) in [
        ("sparse_all", false, TimeRange::EVERYTHING),
        ("filled_all", true, TimeRange::EVERYTHING),
        ("sparse_1pct", false, one_percent),
        ("filled_1pct", true, one_percent),
    ] {
        if !phase_selected(phase) {
            continue;
        }
        let query = DataframeQuery::new(FRAME)
            .with_fill_latest_at(fill)
            .with_range(range);
        let mut cells = 0;
        let (ops, ns_per_op, checksum) = time_query(|| {
            let (rows, columns, non_null) = common::stream_dataframe(&store, &query);
            cells = rows * columns;
            (rows, non_null)
        });
        eprintln!(
            "dataframe/{phase}: {ops} rows, {cells} cells, {checksum} non-null: {:.0} rows/s, {:.0} cells/s",
            1e9 / ns_per_op,
            1e9 / ns_per_op * (cells as f64 / ops.max(1) as f64)
        );
        ok &= Report {
            workload: "dataframe",
            phase,
            ops,
            ns_per_op,
            checksum: Some(checksum),
            expected: None,
        }
        .emit(&store);
    }
    #[cfg(feature = "parquet")]
    if phase_selected("parquet_filled_all") {
        ok &= dataframe_to_parquet(&store, times);
    }
    #[cfg(not(feature = "parquet"))]
    eprintln!("dataframe: the Parquet phase needs --features parquet");
    ok
}

/// Streams the filled table to a Parquet file: the time, and the peak RSS it adds to
/// the store's.
#[cfg(feature = "parquet")]
fn dataframe_to_parquet(store: &ChunkStore, times: usize) -> bool {
    use chunkstore::DataframeQuery;
    use chunkstore::parquet::{ParquetOptions, write_parquet_file};
    reset_peak_rss();
    let before = peak_rss_kib();
    let path = std::env::temp_dir().join(format!(
        "chunkstore-dataframe-{}.parquet",
        std::process::id()
    ));
    let query = DataframeQuery::new(FRAME).with_fill_latest_at(true);
    let start = Instant::now();
    let summary = write_parquet_file(
        &path,
        store.dataframe(&query).expect("a known index"),
        &ParquetOptions::default().with_sorted_by(FRAME),
    )
    .expect("a writable temporary directory");
    let ns = start.elapsed().as_nanos() as f64;
    let _ = std::fs::remove_file(&path);
    eprintln!(
        "dataframe/parquet_filled_all: {} rows, {} row groups, {} bytes in {:.2} s; peak RSS {} -> {} KiB",
        summary.rows,
        summary.row_groups,
        summary.bytes,
        ns / 1e9,
        before,
        peak_rss_kib()
    );
    Report {
        workload: "dataframe",
        phase: "parquet_filled_all",
        ops: summary.rows,
        ns_per_op: ns / summary.rows.max(1) as f64,
        checksum: Some(summary.rows),
        expected: Some(3 * times as u64),
    }
    .emit(store)
}

#[cfg(feature = "parquet")]
/// Resets the kernel's peak RSS figure to the current RSS (Linux 4.0 and later), so
/// that a phase's own peak can be read.
fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

fn peak_rss_kib() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or(0)
}

// --- insert_batched / gc_everything ---

fn insert_batched_chunks() -> (EntityPath, Vec<Arc<Chunk>>) {
    let entity = EntityPath::parse("my_entity").expect("a valid path");
    let mut ids = RowIds::new();
    let chunks = (0..10_000usize)
        .map(|i| {
            let frames = (0..1000).map(|j| (i * 1000 + j) as i64).collect();
            let pos = positions(1000, 1, |_, _| [i as f32; 3]);
            temporal_chunk(&mut ids, &entity, frames, vec![(POSITION3D, pos)])
        })
        .collect();
    (entity, chunks)
}

fn insert_batched() -> bool {
    let (entity, chunks) = insert_batched_chunks();
    let (store, ns_per_op) = time_inserts(OFF, &chunks);
    let frame: Arc<str> = FRAME.into();
    let x = latest_at(&store, &frame, 5_000_500, &entity, POSITION3D)
        .and_then(|cell| points(cell.column(), cell.row()).first().copied())
        .map_or(0, |p| p[0] as u64);
    Report {
        workload: "insert_batched",
        phase: "insert",
        ops: chunks.len() as u64,
        ns_per_op,
        checksum: Some(store.num_chunks() as u64 + x),
        expected: Some(15_000),
    }
    .emit(&store)
}

// --- insert_streaming ---

fn insert_streaming() -> bool {
    let entities = entities(100, |e| format!("stream/{e:03}"));
    let mut ids = RowIds::new();
    let chunks: Vec<_> = (0..1_000_000usize)
        .map(|k| {
            let values = scalars(vec![(k % 1000) as f64]);
            temporal_chunk(
                &mut ids,
                &entities[k % 100],
                vec![(k / 100) as i64],
                vec![(SCALAR, values)],
            )
        })
        .collect();
    let (store, ns_per_op) = time_inserts(DEFAULT, &chunks);
    let frame: Arc<str> = FRAME.into();
    let checksum = entities
        .iter()
        .filter_map(|e| latest_scalar(&store, &frame, 5_000, e))
        .map(|v| v as u64)
        .sum();
    // The row at frame 5,000 of entity e is k = 500,000 + e, value e: 0 + ... + 99.
    Report {
        workload: "insert_streaming",
        phase: "insert",
        ops: chunks.len() as u64,
        ns_per_op,
        checksum: Some(checksum),
        expected: Some(4_950),
    }
    .emit(&store)
}

// --- latest_at_mono ---

fn latest_at_mono() -> bool {
    let mut rng = SplitMix64::new();
    let entities = entities(1000, |i| format!("points/{i}"));
    let mut ids = RowIds::new();
    let mut chunks = Vec::new();
    for c in 0..10usize {
        for (i, entity) in entities.iter().enumerate() {
            let frames = (0..100).map(|r| (c * 100 + r) as i64).collect();
            let pos = positions(100, 1, |r, _| [i as f32, (c * 100 + r) as f32, 0.0]);
            chunks.push(temporal_chunk(
                &mut ids,
                entity,
                frames,
                vec![(POSITION3D, pos)],
            ));
        }
    }
    let store = store_with(OFF, &chunks);
    let queries: Vec<(usize, i64)> = (0..100_000)
        .map(|_| {
            let entity = rng.uniform_usize(1000);
            (entity, rng.uniform(1100) as i64)
        })
        .collect();

    let frame: Arc<str> = FRAME.into();
    let (ops, ns_per_op, checksum) = time_query(|| {
        let mut sum = 0u64;
        for &(i, t) in &queries {
            if let Some(cell) = latest_at(&store, &frame, t, &entities[i], POSITION3D)
                && let Some(p) = points(cell.column(), cell.row()).first()
            {
                sum = sum.wrapping_add(p[0] as u64 + p[1] as u64);
            }
        }
        (queries.len() as u64, sum)
    });
    Report {
        workload: "latest_at_mono",
        phase: "query",
        ops,
        ns_per_op,
        checksum: Some(checksum),
        expected: Some(104_506_789),
    }
    .emit(&store)
}

// --- latest_at_batch ---

fn latest_at_batch() -> bool {
    let entity = EntityPath::parse("points").expect("a valid path");
    let chunks = point_batches(&mut RowIds::new(), &entity);
    let store = store_with(OFF, &chunks);
    let queries = point_batch_queries();

    let frame: Arc<str> = FRAME.into();
    let (ops, ns_per_op, checksum) = time_query(|| {
        let mut sum = 0u64;
        for &t in &queries {
            if let Some(cell) = latest_at(&store, &frame, t, &entity, POSITION3D) {
                sum = sum.wrapping_add(sum_of_xy(points(cell.column(), cell.row())));
            }
        }
        (queries.len() as u64, sum)
    });
    Report {
        workload: "latest_at_batch",
        phase: "query",
        ops,
        ns_per_op,
        checksum: Some(checksum),
        expected: Some(22_700_673_843_200_000),
    }
    .emit(&store)
}

// --- range_scalar ---

fn range_scalar() -> bool {
    let entities = entities(10, |e| format!("series/{e}"));
    let store = store_with(OFF, &range_series(&mut RowIds::new(), &entities));
    let queries = range_series_queries();

    let frame: Arc<str> = FRAME.into();
    let (ops, ns_per_op, checksum) = time_query(|| {
        let (mut rows, mut sum) = (0u64, 0u64);
        for &(e, start) in &queries {
            let query = RangeQuery::new(
                Arc::clone(&frame),
                TimeRange::new(at(start), at(start + 9_999)),
            );
            visit_range_scalars(
                &store.range(&query, &entities[e], SCALAR),
                &mut rows,
                &mut sum,
            );
        }
        (rows, sum) // op = one row visited
    });
    Report {
        workload: "range_scalar",
        phase: "query",
        ops,
        ns_per_op,
        checksum: Some(checksum),
        expected: Some(6_328_903_278_687_944_704),
    }
    .emit(&store)
}

// --- out_of_order ---

fn out_of_order() -> bool {
    let mut rng = SplitMix64::new();
    let frames = rng.permutation(100_000);
    let queries: Vec<i64> = (0..100_000).map(|_| rng.uniform(100_000) as i64).collect();
    let entity = EntityPath::parse("ooo").expect("a valid path");
    let mut ids = RowIds::new();
    let chunks: Vec<_> = frames
        .iter()
        .map(|&f| {
            temporal_chunk(
                &mut ids,
                &entity,
                vec![f],
                vec![(SCALAR, scalars(vec![f as f64]))],
            )
        })
        .collect();

    let (store, ns_per_op) = time_inserts(DEFAULT, &chunks);
    // WORKLOADS.md defines no checksum for this insert phase.
    let ok = Report {
        workload: "out_of_order",
        phase: "insert",
        ops: chunks.len() as u64,
        ns_per_op,
        checksum: None,
        expected: None,
    }
    .emit(&store);

    let frame: Arc<str> = FRAME.into();
    let (ops, ns_per_op, checksum) = time_query(|| {
        let mut sum = 0u64;
        for &t in &queries {
            if let Some(v) = latest_scalar(&store, &frame, t, &entity) {
                sum = sum.wrapping_add(v as u64);
            }
        }
        (queries.len() as u64, sum)
    });
    ok & Report {
        workload: "out_of_order",
        phase: "query",
        ops,
        ns_per_op,
        checksum: Some(checksum),
        expected: Some(5_023_302_507),
    }
    .emit(&store)
}

// --- gc_everything / gc_half ---

fn gc_everything() -> bool {
    let (_, chunks) = insert_batched_chunks();
    let base = store_with(OFF, &chunks);
    let (store, ops, ns_per_op) = time_gc(&base, &GcOptions::everything());
    Report {
        workload: "gc_everything",
        phase: "gc",
        ops,
        ns_per_op,
        checksum: Some(store.num_chunks() as u64), // chunks left
        expected: Some(0),
    }
    .emit(&store)
}

fn gc_half() -> bool {
    let entities = entities(100, |e| format!("gc/{e}"));
    let mut ids = RowIds::new();
    let mut chunks = Vec::new();
    for c in 0..100usize {
        for entity in &entities {
            let frames: Vec<i64> = (0..100).map(|r| (c * 100 + r) as i64).collect();
            let values = frames.iter().map(|&f| (f % 1000) as f64).collect();
            chunks.push(temporal_chunk(
                &mut ids,
                entity,
                frames,
                vec![(SCALAR, scalars(values))],
            ));
        }
    }
    let base = store_with(OFF, &chunks);
    // Oldest rows first (the default order), keeping the latest chunk of every entity.
    let options = GcOptions::drop_at_least_fraction(0.5).expect("0.5 is a valid fraction");
    let (store, ops, ns_per_op) = time_gc(&base, &options);

    let frame: Arc<str> = FRAME.into();
    let values: Vec<f64> = entities
        .iter()
        .filter_map(|e| latest_scalar(&store, &frame, 9_999, e))
        .collect();
    let checksum = values.len() as u64 + values.iter().map(|&v| v as u64).sum::<u64>();
    // All 100 entities answer 9,999 % 1000 = 999.
    Report {
        workload: "gc_half",
        phase: "gc",
        ops,
        ns_per_op,
        checksum: Some(checksum),
        expected: Some(100_000),
    }
    .emit(&store)
}

// --- static_shadow ---

fn static_shadow() -> bool {
    let mut rng = SplitMix64::new();
    let entities = entities(10_000, |i| format!("props/{i}"));
    let mut ids = RowIds::new();
    let mut chunks = Vec::new();
    for (i, entity) in entities.iter().enumerate() {
        chunks.push(static_chunk(
            &mut ids,
            entity,
            vec![(TEXT, texts(vec![format!("name-{i}")]))],
        ));
        let frames: Vec<i64> = (0..10).collect();
        let temporal_texts = texts(frames.iter().map(|f| format!("t-{i}-{f}")).collect());
        let values = scalars(frames.iter().map(|&f| f as f64).collect());
        chunks.push(temporal_chunk(
            &mut ids,
            entity,
            frames,
            vec![(TEXT, temporal_texts), (SCALAR, values)],
        ));
    }
    let store = store_with(OFF, &chunks);
    let queries: Vec<(usize, i64)> = (0..100_000)
        .map(|_| {
            let entity = rng.uniform_usize(10_000);
            (entity, rng.uniform(20) as i64)
        })
        .collect();

    // op = one of the 100,000 queries (two latest-at lookups, `text` and `scalar`).
    let frame: Arc<str> = FRAME.into();
    let (ops, ns_per_op, checksum) =
        time_query(|| static_shadow_queries(&store, &frame, &entities, &queries));
    Report {
        workload: "static_shadow",
        phase: "query",
        ops,
        ns_per_op,
        checksum: Some(checksum),
        expected: Some(1_566_231),
    }
    .emit(&store)
}

/// `static_shadow`'s query phase, once: `(ops, checksum)`. Its own function (never
/// inlined) so that a profiler can count the phase alone (`--toggle-collect`).
#[inline(never)]
fn static_shadow_queries(
    store: &ChunkStore,
    frame: &Arc<str>,
    entities: &[EntityPath],
    queries: &[(usize, i64)],
) -> (u64, u64) {
    let mut sum = 0u64;
    for &(i, t) in queries {
        if let Some(cell) = latest_at(store, frame, t, &entities[i], TEXT)
            && let Some(len) = first_text_len(cell.column().list_array(), cell.row())
        {
            sum = sum.wrapping_add(len as u64);
        }
        if let Some(v) = latest_scalar(store, frame, t, &entities[i]) {
            sum = sum.wrapping_add(v as u64);
        }
    }
    (queries.len() as u64, sum)
}

// --- clear_recursive ---

fn clear_recursive() -> bool {
    let mut entities = Vec::new();
    for a in 0..10 {
        entities.push(format!("tree/{a}"));
        for b in 0..10 {
            entities.push(format!("tree/{a}/{b}"));
            for c in 0..10 {
                entities.push(format!("tree/{a}/{b}/{c}"));
            }
        }
    }
    let entities: Vec<EntityPath> = entities
        .iter()
        .map(|p| EntityPath::parse(p).expect("a valid path"))
        .collect();
    let mut ids = RowIds::new();
    let mut chunks: Vec<_> = entities
        .iter()
        .map(|e| {
            let frames: Vec<i64> = (0..50).collect();
            let values = scalars(frames.iter().map(|&f| f as f64).collect());
            temporal_chunk(&mut ids, e, frames, vec![(SCALAR, values)])
        })
        .collect();
    for a in 0..10 {
        let (path, recursive) = if a % 2 == 0 {
            (format!("tree/{a}"), true)
        } else {
            (format!("tree/{a}/0"), false)
        };
        let entity = EntityPath::parse(&path).expect("a valid path");
        chunks.push(clear_chunk(&mut ids, &entity, 50, recursive));
    }
    let store = store_with(OFF, &chunks);

    let frame: Arc<str> = FRAME.into();
    let (ops, ns_per_op, checksum) = time_query(|| {
        let (mut ops, mut sum) = (0u64, 0u64);
        for _ in 0..100 {
            for t in [25, 75] {
                for entity in &entities {
                    ops += 1;
                    if let Some(v) = latest_scalar(&store, &frame, t, entity) {
                        sum = sum.wrapping_add(v as u64 + 1000);
                    }
                }
            }
        }
        (ops, sum)
    });
    // Per repetition: frame 25, all 1,110 answer 25; frame 75, the 555 entities under even
    // roots and the 5 `tree/{odd}/0` are cleared, the other 550 answer 49.
    Report {
        workload: "clear_recursive",
        phase: "query",
        ops,
        ns_per_op,
        checksum: Some(checksum),
        expected: Some(100 * (1_110 * 1_025 + 550 * 1_049)),
    }
    .emit(&store)
}
