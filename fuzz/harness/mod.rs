//! The bodies of the fuzz targets, one module each, shared with the corpus replay test
//! (`tests/core/fuzz_corpus.rs`) so that every corpus file and every crash ever found is
//! replayed by `cargo test` through exactly the code the fuzzer ran.
#![allow(dead_code, reason = "each fuzz target uses one of the bodies")]

/// Installs, once per process, a panic hook that prints nothing. libfuzzer-sys's own hook
/// aborts on every panic, even one the library contains on purpose (arrow-ipc's, see
/// `chunkstore::ipc::read_batches`); with this one those are caught, and a panic that
/// escapes still aborts in libfuzzer-sys, so it is still a crash. (Its message is not
/// printed: replay the input with `cargo test`, see `tests/fuzz_crashes/README.md`.)
pub fn quiet_panic_hook() {
    static QUIET_HOOK: std::sync::Once = std::sync::Once::new();
    QUIET_HOOK.call_once(|| std::panic::set_hook(Box::new(|_| {})));
}

#[path = "chunk_build.rs"]
pub mod chunk_build;
#[cfg(feature = "cli")]
#[path = "cli_args.rs"]
pub mod cli_args;
#[path = "damaged_log.rs"]
pub mod damaged_log;
#[cfg(feature = "parquet")]
#[path = "delta_log.rs"]
pub mod delta_log;
#[path = "entity_path.rs"]
pub mod entity_path;
#[path = "ipc_batch_decoder.rs"]
pub mod ipc_batch_decoder;
#[path = "ipc_insert.rs"]
pub mod ipc_insert;
#[path = "ipc_schema_cache.rs"]
pub mod ipc_schema_cache;
#[path = "lifecycle.rs"]
pub mod lifecycle;
#[path = "log_msg.rs"]
pub mod log_msg;
#[path = "rrd_decode.rs"]
pub mod rrd_decode;
