//! The `concurrent` workload (this crate's own; `docs/performance-log.md` describes it): a
//! writer thread streams the `insert_streaming` data into a [`SharedStore`] while a reader
//! thread answers `latest_at_mono`-style queries, each on a fresh snapshot.
//!
//! Phases, in one process: the first half of the rows goes in (untimed); the reader runs
//! alone for as long as the first ingest phase will take (idle latencies; as long, so that
//! the machine's own rare pauses weigh alike in both); the writer inserts the second half in three thirds while the
//! reader runs (latencies under ingest, and the writer's ns/row): publishing after every
//! insert (`shared.insert`), once per frame (a batch of the 100 entities' rows), and once
//! per ten frames (1,000 rows); then garbage collection and on-demand compaction while the
//! reader runs (their pauses). The plain
//! store's ns/row is the same second half inserted into a plain `ChunkStore` holding the
//! first half, with no reader; `writer_ns_per_row_plain_beside_reader` is the per-insert
//! third inserted into a fresh plain store while the reader queries the shared one (what
//! the reader's traffic costs a writer, sharing aside). Reader latency is one fresh
//! snapshot, one latest-at and dropping the snapshot.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use chunkstore::{Chunk, ChunkStore, EntityPath, GcOptions, SharedStore, StoreView};

use super::common::{
    FRAME, RowIds, SCALAR, SplitMix64, entities, latest_scalar, scalars, temporal_chunk,
};
use super::{DEFAULT, IMPL, peak_rss_kib};

const ENTITIES: usize = 100;
const ROWS: usize = 1_000_000;
/// Idle reader queries, and at least this many reader queries per ingest phase.
const IDLE_QUERIES: usize = 300_000;

/// Reader latencies of one phase, in nanoseconds.
struct Latencies(Vec<u64>);

impl Latencies {
    fn percentile(&mut self, p: f64) -> u64 {
        self.0.sort_unstable();
        let last = self.0.len().saturating_sub(1);
        self.0
            .get(((last as f64) * p).round() as usize)
            .copied()
            .unwrap_or(0)
    }

    fn max(&self) -> u64 {
        self.0.iter().copied().max().unwrap_or(0)
    }

    /// How many queries took longer than `ns`.
    fn over(&self, ns: u64) -> usize {
        self.0.iter().filter(|&&latency| latency > ns).count()
    }
}

/// Runs reader queries on fresh snapshots of `shared` until `stop` is set (or `deadline`
/// passes) and at least `min_queries` ran; returns every query's latency.
fn read_until(
    shared: &SharedStore,
    entities: &[EntityPath],
    stop: &AtomicBool,
    deadline: Option<Instant>,
    min_queries: usize,
) -> Latencies {
    let frame: Arc<str> = FRAME.into();
    let mut rng = SplitMix64::new();
    let mut latencies = Vec::with_capacity(min_queries * 2);
    let mut sum = 0.0;
    while latencies.len() < min_queries || !stop.load(Ordering::Acquire) {
        let entity = &entities[rng.uniform_usize(ENTITIES)];
        let t = rng.uniform(11_000) as i64;
        let start = Instant::now();
        let snapshot = shared.snapshot();
        sum += latest_scalar(&snapshot, &frame, t, entity).unwrap_or(0.0);
        drop(snapshot);
        let end = Instant::now();
        latencies.push((end - start).as_nanos() as u64);
        if deadline.is_some_and(|deadline| end >= deadline) && latencies.len() >= min_queries {
            break;
        }
    }
    std::hint::black_box(sum);
    Latencies(latencies)
}

/// Runs `write` on this thread while a reader thread queries `shared`; returns the
/// write's wall time in ns and the reader's latencies.
fn with_reader(
    shared: &SharedStore,
    entities: &[EntityPath],
    write: impl FnOnce(),
) -> (f64, Latencies) {
    let stop = AtomicBool::new(false);
    std::thread::scope(|scope| {
        let reader = scope.spawn(|| read_until(shared, entities, &stop, None, 1));
        let start = Instant::now();
        write();
        let ns = start.elapsed().as_nanos() as f64;
        stop.store(true, Ordering::Release);
        (ns, reader.join().expect("the reader finishes"))
    })
}

/// Inserts `chunks` through `shared`, `rows_per_publication` at a time, each batch one
/// publication.
fn insert_in_batches(shared: &SharedStore, chunks: &[Arc<Chunk>], rows_per_publication: usize) {
    for batch in chunks.chunks(rows_per_publication) {
        drop(
            shared
                .insert_batch(batch.iter().cloned())
                .expect("consistent chunks"),
        );
    }
}

/// The `insert_streaming` checksum: latest-at `scalar` at frame 5,000 of every entity.
fn checksum(view: &StoreView, entities: &[EntityPath]) -> u64 {
    let frame: Arc<str> = FRAME.into();
    entities
        .iter()
        .filter_map(|e| latest_scalar(view, &frame, 5_000, e))
        .map(|v| v as u64)
        .sum()
}

/// Median ns per `snapshot()` over many calls (a store of `shared`'s size; no writer).
fn snapshot_ns(shared: &SharedStore) -> f64 {
    let rounds: Vec<f64> = (0..9)
        .map(|_| {
            let start = Instant::now();
            for _ in 0..100_000 {
                std::hint::black_box(shared.snapshot());
            }
            start.elapsed().as_nanos() as f64 / 100_000.0
        })
        .collect();
    super::median(rounds)
}

#[allow(
    clippy::too_many_lines,
    reason = "the phases read best in order, in one place"
)]
pub fn concurrent() -> bool {
    let entities = entities(ENTITIES, |e| format!("stream/{e:03}"));
    let mut ids = RowIds::new();
    let chunks: Vec<Arc<Chunk>> = (0..ROWS)
        .map(|k| {
            let values = scalars(vec![(k % 1000) as f64]);
            temporal_chunk(
                &mut ids,
                &entities[k % ENTITIES],
                vec![(k / ENTITIES) as i64],
                vec![(SCALAR, values)],
            )
        })
        .collect();
    let (first_half, second_half) = chunks.split_at(ROWS / 2);
    // Thirds of whole ten-frame batches.
    let third = second_half.len() / 3 / (10 * ENTITIES) * (10 * ENTITIES);
    let (each_insert, rest) = second_half.split_at(third);
    let (each_frame, each_ten_frames) = rest.split_at(third);

    // The plain store: the second half into a store holding the first, no reader.
    let mut plain = ChunkStore::with_config(DEFAULT).expect("a valid config");
    for chunk in first_half {
        drop(plain.insert(Arc::clone(chunk)).expect("consistent chunks"));
    }
    let start = Instant::now();
    for chunk in second_half {
        drop(plain.insert(Arc::clone(chunk)).expect("consistent chunks"));
    }
    let plain_ns_per_row = start.elapsed().as_nanos() as f64 / second_half.len() as f64;
    let plain_checksum = checksum(&plain, &entities);
    drop(plain);

    let shared = SharedStore::new(ChunkStore::with_config(DEFAULT).expect("a valid config"));
    shared
        .insert_batch(first_half.iter().cloned())
        .expect("consistent chunks");
    let snapshot_ns = snapshot_ns(&shared);

    // As long as the per-insert phase: the plain store's time for its rows, twice over.
    let idle_for = Duration::from_nanos((plain_ns_per_row * each_insert.len() as f64 * 2.0) as u64);
    let never = AtomicBool::new(false);
    let idle_start = Instant::now();
    let mut idle = read_until(
        &shared,
        &entities,
        &never,
        Some(idle_start + idle_for),
        IDLE_QUERIES,
    );
    let idle_ms = idle_start.elapsed().as_millis();

    // Controls, each about as long: the other thread spins (no memory), or inserts the
    // same rows into a store of its own that the reader never sees. Pauses the reader has
    // here too come from the machine, the allocator or the kernel, not from sharing.
    let (_, spinning) = with_reader(&shared, &entities, || {
        let until = Instant::now() + idle_for / 2;
        let mut spins = 0u64;
        while Instant::now() < until {
            spins = std::hint::black_box(spins + 1);
        }
    });
    let mut elsewhere_store = ChunkStore::with_config(DEFAULT).expect("a valid config");
    let (elsewhere_ns, elsewhere) = with_reader(&shared, &entities, || {
        for chunk in each_insert {
            drop(
                elsewhere_store
                    .insert(Arc::clone(chunk))
                    .expect("consistent chunks"),
            );
        }
    });
    drop(elsewhere_store);
    // The plain store's writer with the reader running beside it (on another store): what
    // the reader's traffic alone costs a writer, apart from sharing.
    let beside_reader_ns_per_row = elsewhere_ns / each_insert.len() as f64;

    // One publication per insert, per frame (the 100 entities' rows), per ten frames.
    let (ingest_ns, mut ingest) = with_reader(&shared, &entities, || {
        for chunk in each_insert {
            drop(shared.insert(Arc::clone(chunk)).expect("consistent chunks"));
        }
    });
    let shared_ns_per_row = ingest_ns / each_insert.len() as f64;
    let (frame_ns, mut per_frame) = with_reader(&shared, &entities, || {
        insert_in_batches(&shared, each_frame, ENTITIES);
    });
    let frame_ns_per_row = frame_ns / each_frame.len() as f64;
    let (ten_frames_ns, mut per_ten_frames) = with_reader(&shared, &entities, || {
        insert_in_batches(&shared, each_ten_frames, 10 * ENTITIES);
    });
    let ten_frames_ns_per_row = ten_frames_ns / each_ten_frames.len() as f64;
    let last = shared.snapshot();
    let checksum = checksum(&last, &entities);

    // Garbage collection and compaction while the reader runs; `last` stays held.
    let (_, mut maintenance) = with_reader(&shared, &entities, || {
        let half = GcOptions::drop_at_least_fraction(0.5).expect("a valid fraction");
        drop(shared.write(|store| store.gc(&half)));
        drop(shared.write(ChunkStore::compact));
    });
    let kept_by_snapshot = last.stats().heap_bytes - shared.snapshot().stats().heap_bytes;
    drop(last);

    println!(
        "{{\"workload\":\"concurrent\",\"impl\":\"{IMPL}\",\"rows\":{ROWS},\
\"snapshot_ns\":{snapshot_ns:.1},\
\"reader_p50_idle_ns\":{},\"reader_p99_idle_ns\":{},\"reader_max_idle_ns\":{},\
\"reader_p50_ingest_ns\":{},\"reader_p99_ingest_ns\":{},\"reader_max_ingest_ns\":{},\
\"reader_p99_per_frame_ns\":{},\"reader_max_per_frame_ns\":{},\
\"reader_p99_per_ten_frames_ns\":{},\"reader_max_per_ten_frames_ns\":{},\
\"reader_p99_gc_compact_ns\":{},\"reader_max_gc_compact_ns\":{},\
\"idle_ms\":{idle_ms},\"ingest_ms\":{},\
\"reader_over_100us_idle\":{},\"reader_over_1ms_idle\":{},\
\"reader_over_100us_ingest\":{},\"reader_over_1ms_ingest\":{},\
\"reader_over_100us_gc_compact\":{},\"reader_over_1ms_gc_compact\":{},\
\"reader_max_control_spin_ns\":{},\"reader_over_1ms_control_spin\":{},\
\"reader_max_control_plain_ns\":{},\"reader_over_1ms_control_plain\":{},\
\"writer_ns_per_row_shared\":{shared_ns_per_row:.1},\
\"writer_ns_per_row_shared_per_frame\":{frame_ns_per_row:.1},\
\"writer_ns_per_row_shared_per_ten_frames\":{ten_frames_ns_per_row:.1},\
\"writer_ns_per_row_plain\":{plain_ns_per_row:.1},\
\"writer_ns_per_row_plain_beside_reader\":{beside_reader_ns_per_row:.1},\
\"reader_queries\":{},\"snapshot_kept_bytes\":{kept_by_snapshot},\
\"checksum\":{checksum},\"peak_rss_kib\":{}}}",
        idle.percentile(0.5),
        idle.percentile(0.99),
        idle.max(),
        ingest.percentile(0.5),
        ingest.percentile(0.99),
        ingest.max(),
        per_frame.percentile(0.99),
        per_frame.max(),
        per_ten_frames.percentile(0.99),
        per_ten_frames.max(),
        maintenance.percentile(0.99),
        maintenance.max(),
        (ingest_ns / 1e6) as u64,
        idle.over(100_000),
        idle.over(1_000_000),
        ingest.over(100_000),
        ingest.over(1_000_000),
        maintenance.over(100_000),
        maintenance.over(1_000_000),
        spinning.max(),
        spinning.over(1_000_000),
        elsewhere.max(),
        elsewhere.over(1_000_000),
        idle.0.len()
            + ingest.0.len()
            + per_frame.0.len()
            + per_ten_frames.0.len()
            + maintenance.0.len()
            + spinning.0.len()
            + elsewhere.0.len(),
        peak_rss_kib(),
    );
    // The insert_streaming checksum (WORKLOADS.md): 0 + 1 + ... + 99.
    let ok = checksum == 4_950 && plain_checksum == 4_950;
    if !ok {
        eprintln!(
            "CHECKSUM MISMATCH concurrent: got {checksum} (plain {plain_checksum}), expected 4950"
        );
    }
    ok
}
