//! `chunkstore serve`: Rerun's gRPC log protocol in ([`proxy`]), Arrow Flight SQL out
//! ([`flight`]), on one port ([`listen`]), over a [`StoreHub`]; with `--persist`, an
//! append-only `.rrd` log that every acknowledged message is in ([`persist`]); what it is
//! doing in [`metrics`] and log lines (`tracing`, `RUST_LOG`). `docs/SERVER.md` is the
//! user's page.

mod admission;
mod allocator;
mod args;
mod flight;
mod http;
mod listen;
mod metrics;
mod persist;
mod proxy;
mod recordings;
mod retention;
mod session;
mod statement;
mod web;
mod write;

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use chunkstore::StoreConfig;
use chunkstore::hub::StoreHub;
use chunkstore::rrd::LogMsg;
use clap::Parser;
use tokio::sync::broadcast;

pub use crate::args::parse_bytes;
pub use args::{ReadMode, ServeArgs};

/// The smallest `--memory-limit`: below it, the server's own buffers alone break it.
const MIN_MEMORY_LIMIT: u64 = 16 << 20;

/// The largest message, and the HTTP/2 windows (bytes a client may send ahead, per stream
/// and per connection), for a memory limit: a message is held whole while it is decoded,
/// and every connection may have a window's worth in flight.
fn message_bounds(args: &ServeArgs) -> Result<(usize, u32, u32), String> {
    let Some(limit) = args.memory_limit else {
        let max = args.max_message_bytes.unwrap_or(1 << 30);
        let max = usize::try_from(max)
            .map_err(|_| "--max-message-bytes is too large for this machine".to_owned())?;
        return Ok((max, STREAM_WINDOW, CONNECTION_WINDOW));
    };
    if limit < MIN_MEMORY_LIMIT {
        return Err(format!(
            "--memory-limit {limit} is below 16MiB, less than the server's own buffers take"
        ));
    }
    let max = match args.max_message_bytes {
        Some(max) if max > limit / 2 => {
            return Err(format!(
                "--max-message-bytes {max} is more than half of --memory-limit {limit}: one \
                 such message would break the limit"
            ));
        }
        Some(max) => max,
        None => limit / 8,
    };
    let window = |most: u32| u32::try_from(limit / 64).map_or(most, |w| w.min(most));
    let max = usize::try_from(max).map_err(|_| "--max-message-bytes is too large".to_owned())?;
    Ok((max, window(STREAM_WINDOW), window(CONNECTION_WINDOW)))
}

/// How long a stopping server waits for its calls to finish (a write stream's sync, a
/// history being sent) before it exits anyway.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// How many live messages a reader may fall behind the writers before it is dropped.
const LIVE_BACKLOG: usize = 1024;

/// HTTP/2 flow-control windows: bytes a client may send ahead, per stream and per
/// connection (what the server may hold per client before its store does); smaller under
/// a small `--memory-limit` ([`message_bounds`]).
const STREAM_WINDOW: u32 = 2 << 20;
const CONNECTION_WINDOW: u32 = 8 << 20;

/// The stores' share of `--memory-limit`, which bounds the process: the rest is for the
/// server's working memory (HTTP/2 windows, messages in flight, live readers' backlog,
/// queries' batches, the allocator's slack), which does not grow with the limit. Measured
/// at 130–190 MiB beside the stores with 8 SDK writers and 4 Flight SQL readers
/// (`benches/server_soak.py`), so the rest is a quarter of the limit but at least
/// [`WORKING_MEMORY`], and at most half the limit.
fn store_budget(limit: u64) -> u64 {
    limit - (limit / 4).max(WORKING_MEMORY).min(limit / 2)
}

/// See [`store_budget`].
const WORKING_MEMORY: u64 = 128 << 20;

/// What live readers are told: each accepted message, in order, and when the server
/// dropped messages it could not make durable (a reader that had them must read the
/// history again).
#[derive(Clone)]
pub enum Live {
    Message(u64, LogMsg),
    RolledBack,
}

/// What every RPC handler shares.
pub struct ServerState {
    pub hub: StoreHub,
    pub live: broadcast::Sender<Live>,
    pub persist: Option<Arc<persist::PersistLog>>,
    /// The SOURCEs loaded before serving: loaded again when memory is rebuilt from the
    /// log after a failed write.
    sources: Vec<PathBuf>,
    /// Of the object store URL SOURCEs are in.
    storage: chunkstore::storage::StorageOptions,
    /// Set once the server is stopping: live readers end their streams.
    pub stopping: tokio::sync::watch::Sender<bool>,
    /// Held (shared) while a message is ingested and (exclusively) while memory is rebuilt
    /// after a failed write, so that nothing is ingested in between.
    write_gate: parking_lot::RwLock<()>,
    pub memory_limit: Option<u64>,
    pub read_mode: ReadMode,
    pub admission: Arc<admission::Admission>,
    pub max_message_bytes: usize,
    /// Message bytes ingested since the memory was last measured.
    bytes_since_check: AtomicU64,
    /// A garbage collection is under way.
    collecting: AtomicBool,
    /// A log rewrite is under way.
    rewriting: AtomicBool,
    /// What the server has done, for `--metrics-addr`.
    pub metrics: metrics::Metrics,
    /// `--retention`.
    retention: Vec<retention::Rule>,
    /// The query context Flight SQL reuses while the recordings do not change.
    pub query_sessions: session::QuerySessions,
}

impl ServerState {
    /// After a message of `len` bytes decoded: measure the stores now and then (every
    /// 1/32 of the limit ingested), collect garbage when over the limit, and rewrite the
    /// log once it holds much more than the stores.
    pub fn after_ingest(self: &Arc<Self>, len: u64) {
        let Some(limit) = self.memory_limit else {
            return;
        };
        let since = self
            .bytes_since_check
            .fetch_add(len, Ordering::Relaxed)
            .saturating_add(len);
        if since < (limit / 32).max(1) {
            return;
        }
        self.bytes_since_check.store(0, Ordering::Relaxed);
        // A kept query context holds the chunks compaction has since replaced.
        self.query_sessions.forget();
        // One collection at a time: two streams crossing the limit together would each
        // collect the whole excess. Under the budget, it measures and returns.
        if !self.collecting.swap(true, Ordering::AcqRel) {
            self.collect_garbage(limit);
            self.collecting.store(false, Ordering::Release);
        }
        self.rewrite_log_if_large();
    }

    /// Rewrites the log, on a thread of its own, once it holds much more than the stores
    /// (more than four times the memory limit, or without one, four times what the stores
    /// hold, and at least 64 MiB): garbage collection and retention dropped the rest.
    pub fn rewrite_log_if_large(self: &Arc<Self>) {
        let base = self.memory_limit.unwrap_or_else(|| self.hub.heap_bytes());
        if let Some(log) = &self.persist
            && log.len() > base.saturating_mul(4).max(64 << 20)
            && !self.rewriting.swap(true, Ordering::AcqRel)
        {
            let state = Arc::clone(self);
            let log = Arc::clone(log);
            std::thread::spawn(move || {
                match log.rewrite(&state.hub) {
                    Ok((before, after)) => {
                        state.metrics.log_rewritten();
                        tracing::info!(
                            "rewrote {}: {before} bytes to {after} (what the stores hold)",
                            log.path().display()
                        );
                    }
                    Err(e) => tracing::warn!("rewriting {}: {e}", log.path().display()),
                }
                state.rewriting.store(false, Ordering::Release);
            });
        }
    }
}

impl ServerState {
    /// Drops the recordings of `recording_id` and, with a log, rewrites it without them
    /// before returning, so that a restart does not bring them back. Returns a line
    /// saying what was dropped. Blocking (the rewrite).
    pub fn drop_recording(&self, recording_id: &str) -> Result<String, tonic::Status> {
        let dropped = self.hub.drop_recording(recording_id);
        self.query_sessions.forget();
        if dropped.is_empty() {
            return Err(tonic::Status::not_found(format!(
                "no recording {recording_id:?} here (SELECT rerun_segment_id FROM recordings)"
            )));
        }
        if let Some(log) = &self.persist {
            // One rewrite at a time: wait for one under way.
            while self.rewriting.swap(true, Ordering::AcqRel) {
                std::thread::sleep(Duration::from_millis(20));
            }
            let rewritten = log.rewrite(&self.hub);
            self.rewriting.store(false, Ordering::Release);
            if let Err(e) = rewritten {
                return Err(tonic::Status::unavailable(format!(
                    "dropped {recording_id:?} from memory, but rewriting {} failed ({e}): it \
                     comes back on restart",
                    log.path().display()
                )));
            }
        }
        let line = format!(
            "dropped recording {recording_id:?} ({} stores)",
            dropped.len()
        );
        tracing::info!("{line}");
        Ok(line)
    }

    /// Whether `--retention` was given.
    pub fn has_retention(&self) -> bool {
        !self.retention.is_empty()
    }

    /// Applies `--retention` to every recording (blocking: it rewrites chunks).
    pub fn apply_retention(&self) {
        if self.retention.is_empty() {
            return;
        }
        let removed = self
            .hub
            .retain_recent(|timeline| retention::span_of(&self.retention, timeline));
        if removed > 0 {
            self.query_sessions.forget();
            self.metrics.retained(removed);
            tracing::debug!("retention: removed {removed} chunks of data older than its span");
        }
    }

    /// Brings the stores under their share of `limit`; a pass that dropped data is
    /// counted and leaves a log line.
    fn collect_garbage(&self, limit: u64) {
        let outcome = self.hub.collect_garbage(store_budget(limit));
        if outcome.chunks_dropped > 0 {
            self.query_sessions.forget();
            let freed = outcome.bytes_before.saturating_sub(outcome.bytes_after);
            self.metrics.collected(freed, outcome.chunks_dropped);
            tracing::info!(
                "garbage collection: dropped {} chunks, {freed} bytes; the stores hold {} \
                 bytes of {}",
                outcome.chunks_dropped,
                outcome.bytes_after,
                store_budget(limit)
            );
        }
    }

    /// The metrics, with the figures of this moment.
    pub fn metrics_text(&self) -> String {
        let gauges = metrics::Gauges {
            store_bytes: self.hub.heap_bytes(),
            store_budget: self.memory_limit.map(store_budget),
            memory_limit: self.memory_limit,
            recordings: self.hub.recording_count(),
            write_streams: self.admission.open_streams(),
            log_bytes: self.persist.as_ref().map(|log| log.len()),
        };
        self.metrics
            .render(&gauges, self.persist.as_ref().map(|log| log.sync_latency()))
    }
}

/// The settings [`ServerState::start`] takes from the command line.
pub struct StateOptions {
    pub memory_limit: Option<u64>,
    pub read_mode: ReadMode,
    pub max_write_streams: usize,
    pub max_message_bytes: usize,
    /// Of the object store URL sources are in.
    pub storage: chunkstore::storage::StorageOptions,
    /// `--retention`.
    pub retention: Vec<retention::Rule>,
}

impl ServerState {
    /// The state of a server about to listen: a hub that appends every accepted message
    /// to `persist` (if any) and tells live readers, holding the `sources` and what the
    /// log held.
    pub fn start(
        persist: Option<Arc<persist::PersistLog>>,
        sources: Vec<PathBuf>,
        options: &StateOptions,
    ) -> Result<Arc<Self>, String> {
        let (live, _) = broadcast::channel(LIVE_BACKLOG);
        let listener_log = persist.clone();
        let listener_live = live.clone();
        let hub = StoreHub::with_listener(
            StoreConfig::DEFAULT,
            Box::new(move |seq, msg: &LogMsg| {
                if let Some(log) = &listener_log {
                    log.append(seq, msg).map_err(|e| e.to_string())?;
                }
                // No reader listening is no error.
                let _ = listener_live.send(Live::Message(seq, msg.clone()));
                Ok(())
            }),
        )
        .map_err(|e| e.to_string())?;
        for source in &sources {
            preload(&hub, source, &options.storage)?;
        }
        if let Some(log) = &persist {
            let report = log.replay_into(&hub);
            if report.messages > 0 || report.skipped > 0 {
                tracing::info!(
                    "read {} messages back from {}{}",
                    report.messages,
                    log.path().display(),
                    if report.skipped > 0 {
                        format!(" ({} skipped)", report.skipped)
                    } else {
                        String::new()
                    }
                );
            }
        }
        let state = Arc::new(Self {
            hub,
            live,
            persist,
            sources,
            storage: options.storage.clone(),
            stopping: tokio::sync::watch::Sender::new(false),
            write_gate: parking_lot::RwLock::new(()),
            memory_limit: options.memory_limit,
            read_mode: options.read_mode,
            admission: admission::Admission::new(options.max_write_streams),
            max_message_bytes: options.max_message_bytes,
            bytes_since_check: AtomicU64::new(0),
            collecting: AtomicBool::new(false),
            rewriting: AtomicBool::new(false),
            metrics: metrics::Metrics::default(),
            retention: options.retention.clone(),
            query_sessions: session::QuerySessions::default(),
        });
        state.apply_retention();
        if let Some(limit) = options.memory_limit {
            state.collect_garbage(limit);
        }
        Ok(state)
    }
}

/// `chunkstore serve ...`: `args` are the whole command line (program name first).
pub fn main(args: &[OsString]) -> ExitCode {
    let mut command_line: Vec<OsString> = vec![OsString::from("chunkstore serve")];
    command_line.extend(args.iter().skip(2).cloned());
    let parsed = match ServeArgs::try_parse_from(&command_line) {
        Ok(parsed) => parsed,
        Err(error) => return crate::usage_error(&error),
    };
    if let Err(message) = start_logging() {
        eprintln!("error: {}", crate::one_line(&message));
        return ExitCode::from(2);
    }
    match run(&parsed) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("error: {}", crate::one_line(&message));
            ExitCode::from(2)
        }
    }
}

fn run(args: &ServeArgs) -> Result<(), String> {
    let (max_message_bytes, stream_window, connection_window) = message_bounds(args)?;
    if args.memory_limit.is_some() {
        allocator::fix_mmap_threshold();
    }
    if args.max_write_streams == 0 {
        return Err("--max-write-streams must be at least 1".to_owned());
    }
    if args.token.as_deref() == Some("") {
        return Err("--token must not be empty".to_owned());
    }
    let tls = match (&args.tls_cert, &args.tls_key) {
        (Some(cert), Some(key)) => {
            let read = |path: &PathBuf| {
                std::fs::read(path).map_err(|e| crate::about_path(path, e.to_string()))
            };
            Some(tonic::transport::Identity::from_pem(
                read(cert)?,
                read(key)?,
            ))
        }
        _ => None,
    };
    let persist = match &args.persist {
        Some(path) => Some(Arc::new(persist::PersistLog::create_or_append(path)?)),
        None => None,
    };
    let state = ServerState::start(
        persist,
        args.sources.clone(),
        &StateOptions {
            memory_limit: args.memory_limit,
            read_mode: args.read_mode,
            max_write_streams: args.max_write_streams,
            max_message_bytes,
            storage: args.storage_options.iter().cloned().collect(),
            retention: args.retention.clone(),
        },
    )?;
    if args.token.is_none() && !args.addr.ip().is_loopback() {
        tracing::warn!(
            "listening on {} without --token: anyone who reaches this address can read and \
             write every recording",
            args.addr
        );
    } else if tls.is_none() && !args.addr.ip().is_loopback() {
        tracing::warn!(
            "listening on {} without TLS: the token and the data cross the network in \
             clear (--tls-cert, --tls-key)",
            args.addr
        );
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| format!("starting the server's runtime: {e}"))?;
    // Queries run on a runtime of their own: DataFusion's operators compute inside a
    // poll for as long as they need (an aggregate over a cross join, minutes), and on the
    // runtime that serves the connections they left it deaf to clients that go away.
    let queries = tokio::runtime::Builder::new_multi_thread()
        .thread_name("query")
        .enable_all()
        .build()
        .map_err(|e| format!("starting the query runtime: {e}"))?;
    let stop = listen::stop_signal()?;
    let listen = listen::Listen {
        addr: args.addr,
        token: args.token.clone(),
        tls,
        windows: (stream_window, connection_window),
        origins: web::AllowedOrigins::new(&args.cors_allow_origins),
        metrics_addr: args.metrics_addr,
    };
    let served = runtime.block_on(listen::serve(state, listen, stop, queries.handle().clone()));
    queries.shutdown_background();
    // A history still being read out on a blocking thread is not waited for.
    runtime.shutdown_timeout(SHUTDOWN_GRACE);
    served
}

/// Log lines to stderr, at the level `RUST_LOG` names (`info` without it), with no
/// colours (they often go to a file).
fn start_logging() -> Result<(), String> {
    use tracing_subscriber::EnvFilter;
    let filter = match std::env::var("RUST_LOG") {
        Ok(directives) if !directives.is_empty() => EnvFilter::try_new(&directives)
            .map_err(|e| format!("RUST_LOG={directives:?} is not a log filter: {e}"))?,
        _ => EnvFilter::new("info"),
    };
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(false)
        .with_target(false)
        .try_init()
        .map_err(|e| format!("starting the log: {e}"))
}

/// Loads one SOURCE into the hub: an `.rrd` file message by message (every recording and
/// blueprint it holds), a chunk directory or IPC file as one recording.
fn preload(
    hub: &StoreHub,
    source: &std::path::Path,
    storage: &chunkstore::storage::StorageOptions,
) -> Result<(), String> {
    use chunkstore::recording::{LoadedRecording, OpenOptions, SourceKind};
    let kind = SourceKind::detect(source).map_err(|e| e.to_string())?;
    if kind == SourceKind::Rrd {
        let bytes = chunkstore::storage::read_whole(source, storage)
            .map_err(|e| chunkstore::storage::io_error_text(source, &e))?;
        let scan = chunkstore::rrd::scan_log(&arrow_buffer::Buffer::from(bytes));
        if let Some(fault) = &scan.fault {
            return Err(crate::about_path(source, fault));
        }
        for (i, msg) in scan.messages.into_iter().enumerate() {
            hub.restore(&msg)
                .map_err(|e| crate::about_path(source, format!("message {i}: {e}")))?;
        }
        return Ok(());
    }
    let open = OpenOptions::default().with_storage(storage.clone());
    let loaded =
        LoadedRecording::load(source, &open, &mut ()).map_err(|e| crate::about_path(source, e))?;
    let info = loaded.store_info.clone().unwrap_or_else(|| {
        let name = source
            .file_name()
            .map_or_else(|| "chunks".to_owned(), |n| n.to_string_lossy().into_owned());
        chunkstore::rrd::StoreInfo::new(chunkstore::rrd::StoreId::recording("chunkstore", name))
    });
    hub.adopt(info, loaded.store)
        .map_err(|e| crate::about_path(source, e))
}

#[cfg(test)]
mod tests {
    use super::parse_bytes;

    #[test]
    fn byte_counts_parse_with_units() {
        assert_eq!(parse_bytes("0"), Ok(0));
        assert_eq!(parse_bytes("512MiB"), Ok(512 << 20));
        assert_eq!(parse_bytes("2GB"), Ok(2_000_000_000));
        assert_eq!(parse_bytes("7 kib"), Ok(7 << 10));
        assert!(parse_bytes("MiB").is_err());
        assert!(parse_bytes("5 parsecs").is_err());
        assert!(parse_bytes("99999999999TiB").is_err());
    }

    #[test]
    fn the_stores_get_the_limit_less_the_working_memory() {
        use super::store_budget;
        assert_eq!(store_budget(16 << 20), 8 << 20);
        assert_eq!(store_budget(256 << 20), 128 << 20);
        assert_eq!(store_budget(512 << 20), 384 << 20);
        assert_eq!(store_budget(4 << 30), 3 << 30);
    }
}
