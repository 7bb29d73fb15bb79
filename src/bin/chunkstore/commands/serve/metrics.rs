//! What the server is doing, as counters and histograms kept with atomics on the paths
//! that do the work, rendered in Prometheus' text format (version 0.0.4) when scraped
//! ([`super::http`] serves them). This module knows nothing of the server: the caller
//! hands it the figures read at scrape time ([`Gauges`]).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use parking_lot::Mutex;

/// Upper bounds (seconds) of the latency histograms' buckets: a sync of a page cache
/// write is under a millisecond, a query over a large recording seconds.
const LATENCY_BOUNDS: [f64; 14] = [
    0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0,
];

/// A latency histogram: a count per bucket (not cumulative: summed when rendered), the
/// total, and the sum in nanoseconds.
#[derive(Default)]
pub struct Histogram {
    buckets: [AtomicU64; LATENCY_BOUNDS.len()],
    count: AtomicU64,
    sum_nanos: AtomicU64,
}

impl Histogram {
    /// Counts one observation of `elapsed`.
    pub fn observe(&self, elapsed: Duration) {
        let seconds = elapsed.as_secs_f64();
        if let Some(i) = LATENCY_BOUNDS.iter().position(|&bound| seconds <= bound) {
            self.buckets[i].fetch_add(1, Ordering::Relaxed);
        }
        self.count.fetch_add(1, Ordering::Relaxed);
        let nanos = u64::try_from(elapsed.as_nanos()).unwrap_or(u64::MAX);
        self.sum_nanos.fetch_add(nanos, Ordering::Relaxed);
    }

    /// Observations so far.
    pub fn count(&self) -> u64 {
        self.count.load(Ordering::Relaxed)
    }

    fn render(&self, out: &mut String, name: &str, help: &str) {
        header(out, name, help, "histogram");
        let mut cumulative = 0;
        for (bound, bucket) in LATENCY_BOUNDS.iter().zip(&self.buckets) {
            cumulative += bucket.load(Ordering::Relaxed);
            let _ = writeln!(out, "{name}_bucket{{le=\"{bound}\"}} {cumulative}");
        }
        let count = self.count();
        let _ = writeln!(out, "{name}_bucket{{le=\"+Inf\"}} {count}");
        #[expect(clippy::cast_precision_loss, reason = "a sum of seconds, for a rate")]
        let sum = self.sum_nanos.load(Ordering::Relaxed) as f64 / 1e9;
        let _ = writeln!(out, "{name}_sum {sum}");
        let _ = writeln!(out, "{name}_count {count}");
    }
}

/// What one store (a recording, or a blueprint) was sent.
#[derive(Clone, Copy, Default)]
struct StoreCounters {
    messages: u64,
    rows: u64,
    bytes: u64,
    refused: u64,
}

/// The server's counters. Cheap to update from any thread.
#[derive(Default)]
pub struct Metrics {
    /// By recording id (`""` for a message too damaged to name one).
    stores: Mutex<BTreeMap<String, StoreCounters>>,
    gc_runs: AtomicU64,
    gc_bytes_freed: AtomicU64,
    gc_chunks_dropped: AtomicU64,
    log_rewrites: AtomicU64,
    retention_removed_chunks: AtomicU64,
    read_streams: AtomicU64,
    queries_failed: AtomicU64,
    sessions_built: AtomicU64,
    /// Queries answered, from the call to the last batch sent.
    pub queries: Histogram,
}

/// Figures read when scraped, from the server's own structures.
pub struct Gauges {
    /// Heap bytes the stores hold.
    pub store_bytes: u64,
    /// What garbage collection keeps them under, if there is a memory limit.
    pub store_budget: Option<u64>,
    /// `--memory-limit`.
    pub memory_limit: Option<u64>,
    /// Recordings held.
    pub recordings: usize,
    /// Log streams open now.
    pub write_streams: usize,
    /// Bytes of the write-ahead log, if there is one.
    pub log_bytes: Option<u64>,
}

/// A read stream while it is open ([`Metrics::read_stream`]).
pub struct ReadStreamGuard<'a>(&'a Metrics);

impl Drop for ReadStreamGuard<'_> {
    fn drop(&mut self) {
        self.0.read_streams.fetch_sub(1, Ordering::Relaxed);
    }
}

impl Metrics {
    /// A message of `bytes` (decoded) with `rows` rows accepted into `recording`.
    pub fn ingested(&self, recording: &str, rows: u64, bytes: u64) {
        let mut stores = self.stores.lock();
        let counters = entry(&mut stores, recording);
        counters.messages += 1;
        counters.rows += rows;
        counters.bytes += bytes;
    }

    /// A message refused (`recording` is `""` when it did not decode far enough to say).
    pub fn refused(&self, recording: &str) {
        entry(&mut self.stores.lock(), recording).refused += 1;
    }

    /// A garbage collection that freed `bytes` by dropping `chunks`.
    pub fn collected(&self, bytes: u64, chunks: usize) {
        self.gc_runs.fetch_add(1, Ordering::Relaxed);
        self.gc_bytes_freed.fetch_add(bytes, Ordering::Relaxed);
        self.gc_chunks_dropped
            .fetch_add(chunks as u64, Ordering::Relaxed);
    }

    /// Retention removed `chunks` chunks.
    pub fn retained(&self, chunks: usize) {
        self.retention_removed_chunks
            .fetch_add(chunks as u64, Ordering::Relaxed);
    }

    /// A rewrite of the write-ahead log finished.
    pub fn log_rewritten(&self) {
        self.log_rewrites.fetch_add(1, Ordering::Relaxed);
    }

    /// A query that ended in an error (planning or running it).
    pub fn query_failed(&self) {
        self.queries_failed.fetch_add(1, Ordering::Relaxed);
    }

    /// A query context was built (not reused).
    pub fn session_built(&self) {
        self.sessions_built.fetch_add(1, Ordering::Relaxed);
    }

    /// Counts a read stream open until the guard is dropped.
    pub fn read_stream(&self) -> ReadStreamGuard<'_> {
        self.read_streams.fetch_add(1, Ordering::Relaxed);
        ReadStreamGuard(self)
    }

    /// Everything, in Prometheus' text format; `sync` is the log's sync latency.
    pub fn render(&self, gauges: &Gauges, sync: Option<&Histogram>) -> String {
        let mut out = String::new();
        self.render_stores(&mut out);
        self.render_counters(&mut out);
        self.render_gauges(&mut out, gauges);
        if let Some(sync) = sync {
            sync.render(
                &mut out,
                "chunkstore_log_sync_seconds",
                "Time to make the write-ahead log durable (fsync), per sync.",
            );
        }
        self.queries.render(
            &mut out,
            "chunkstore_query_seconds",
            "Flight SQL queries answered, from the call to the last batch sent.",
        );
        out
    }

    fn render_stores(&self, out: &mut String) {
        type Value = fn(&StoreCounters) -> u64;
        let stores = self.stores.lock().clone();
        let per_store: [(&str, &str, Value); 4] = [
            (
                "chunkstore_ingested_messages_total",
                "Messages accepted, by recording (blueprints by their own id).",
                |c| c.messages,
            ),
            (
                "chunkstore_ingested_rows_total",
                "Rows of the chunks accepted, by recording.",
                |c| c.rows,
            ),
            (
                "chunkstore_ingested_bytes_total",
                "Decoded bytes of the messages accepted, by recording.",
                |c| c.bytes,
            ),
            (
                "chunkstore_refused_messages_total",
                "Messages refused (bad bytes, a chunk the store refused), by recording; \
                 recording=\"\" when the message did not name one.",
                |c| c.refused,
            ),
        ];
        for (name, help, value) in per_store {
            header(out, name, help, "counter");
            for (recording, counters) in &stores {
                let _ = writeln!(
                    out,
                    "{name}{{recording=\"{}\"}} {}",
                    escape(recording),
                    value(counters)
                );
            }
        }
    }

    fn render_counters(&self, out: &mut String) {
        let load = |n: &AtomicU64| n.load(Ordering::Relaxed);
        let counters = [
            (
                "chunkstore_gc_runs_total",
                "Garbage collections that dropped data.",
                load(&self.gc_runs),
            ),
            (
                "chunkstore_gc_freed_bytes_total",
                "Heap bytes garbage collection freed.",
                load(&self.gc_bytes_freed),
            ),
            (
                "chunkstore_gc_dropped_chunks_total",
                "Chunks garbage collection dropped.",
                load(&self.gc_chunks_dropped),
            ),
            (
                "chunkstore_retention_removed_chunks_total",
                "Chunks --retention removed (a chunk partly kept counts, replaced by its \
                 kept rows).",
                load(&self.retention_removed_chunks),
            ),
            (
                "chunkstore_log_rewrites_total",
                "Rewrites of the write-ahead log down to what the stores hold.",
                load(&self.log_rewrites),
            ),
            (
                "chunkstore_query_sessions_built_total",
                "Query contexts built over the recordings (one is reused while they do not \
                 change).",
                load(&self.sessions_built),
            ),
            (
                "chunkstore_query_errors_total",
                "Flight SQL queries that failed.",
                load(&self.queries_failed),
            ),
        ];
        for (name, help, value) in counters {
            header(out, name, help, "counter");
            let _ = writeln!(out, "{name} {value}");
        }
    }

    fn render_gauges(&self, out: &mut String, gauges: &Gauges) {
        let mut gauge = |name: &str, help: &str, value: u64| {
            header(out, name, help, "gauge");
            let _ = writeln!(out, "{name} {value}");
        };
        gauge(
            "chunkstore_store_bytes",
            "Heap bytes the stores hold.",
            gauges.store_bytes,
        );
        if let Some(budget) = gauges.store_budget {
            gauge(
                "chunkstore_store_budget_bytes",
                "What garbage collection keeps the stores under (--memory-limit less the \
                 server's working memory).",
                budget,
            );
        }
        if let Some(limit) = gauges.memory_limit {
            gauge(
                "chunkstore_memory_limit_bytes",
                "The server's --memory-limit.",
                limit,
            );
        }
        if let Some(rss) = resident_bytes() {
            gauge(
                "process_resident_memory_bytes",
                "Resident memory of the server's process.",
                rss,
            );
        }
        gauge(
            "chunkstore_recordings",
            "Recordings held.",
            gauges.recordings as u64,
        );
        gauge(
            "chunkstore_write_streams",
            "Log streams (WriteMessages) open now.",
            gauges.write_streams as u64,
        );
        gauge(
            "chunkstore_read_streams",
            "Read streams (ReadMessages) open now.",
            self.read_streams.load(Ordering::Relaxed),
        );
        if let Some(bytes) = gauges.log_bytes {
            gauge(
                "chunkstore_log_bytes",
                "Bytes of the write-ahead log (--persist).",
                bytes,
            );
        }
    }
}

fn entry<'a>(
    stores: &'a mut BTreeMap<String, StoreCounters>,
    recording: &str,
) -> &'a mut StoreCounters {
    if !stores.contains_key(recording) {
        stores.insert(recording.to_owned(), StoreCounters::default());
    }
    stores
        .get_mut(recording)
        .unwrap_or_else(|| unreachable!("inserted above"))
}

fn header(out: &mut String, name: &str, help: &str, kind: &str) {
    let _ = writeln!(out, "# HELP {name} {help}");
    let _ = writeln!(out, "# TYPE {name} {kind}");
}

/// A label value as the text format wants it: `\`, `"` and newlines escaped.
fn escape(value: &str) -> String {
    value
        .replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

/// The process's resident memory, from `/proc` (Linux; `None` elsewhere).
fn resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(text: &str, series: &str) -> Option<f64> {
        text.lines()
            .find_map(|l| l.strip_prefix(series)?.strip_prefix(' ')?.parse().ok())
    }

    #[test]
    fn counters_render_by_recording_with_escaped_labels() {
        let metrics = Metrics::default();
        metrics.ingested("rec \"1\"", 3, 100);
        metrics.ingested("rec \"1\"", 2, 50);
        metrics.refused("");
        let text = metrics.render(
            &Gauges {
                store_bytes: 7,
                store_budget: None,
                memory_limit: None,
                recordings: 1,
                write_streams: 0,
                log_bytes: None,
            },
            None,
        );
        let rows = r#"chunkstore_ingested_rows_total{recording="rec \"1\""}"#;
        assert_eq!(sample(&text, rows), Some(5.0), "{text}");
        let bytes = r#"chunkstore_ingested_bytes_total{recording="rec \"1\""}"#;
        assert_eq!(sample(&text, bytes), Some(150.0));
        let refused = r#"chunkstore_refused_messages_total{recording=""}"#;
        assert_eq!(sample(&text, refused), Some(1.0));
        assert_eq!(sample(&text, "chunkstore_store_bytes"), Some(7.0));
        assert!(!text.contains("chunkstore_log_bytes"));
        // Every series has its HELP and TYPE lines first.
        for line in text.lines().filter(|l| !l.starts_with('#')) {
            let name = line.split(['{', ' ']).next().unwrap_or_default();
            let family = name
                .trim_end_matches("_bucket")
                .trim_end_matches("_sum")
                .trim_end_matches("_count");
            assert!(
                text.contains(&format!("# TYPE {family} ")),
                "{line} has no TYPE line"
            );
        }
    }

    #[test]
    fn histograms_are_cumulative() {
        let histogram = Histogram::default();
        histogram.observe(Duration::from_micros(300));
        histogram.observe(Duration::from_millis(30));
        histogram.observe(Duration::from_mins(1));
        let mut text = String::new();
        histogram.render(&mut text, "h", "help");
        assert_eq!(sample(&text, "h_bucket{le=\"0.0005\"}"), Some(1.0));
        assert_eq!(sample(&text, "h_bucket{le=\"0.025\"}"), Some(1.0));
        assert_eq!(sample(&text, "h_bucket{le=\"0.05\"}"), Some(2.0));
        assert_eq!(sample(&text, "h_bucket{le=\"10\"}"), Some(2.0));
        assert_eq!(sample(&text, "h_bucket{le=\"+Inf\"}"), Some(3.0));
        assert_eq!(sample(&text, "h_count"), Some(3.0));
        let sum = sample(&text, "h_sum").unwrap_or_default();
        assert!((sum - 60.0303).abs() < 1e-6, "{sum}");
    }
}
