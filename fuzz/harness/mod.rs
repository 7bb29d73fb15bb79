//! The bodies of the fuzz targets, one module each, shared with the corpus replay test
//! (`tests/core/fuzz_corpus.rs`) so that every corpus file and every crash ever found is
//! replayed by `cargo test` through exactly the code the fuzzer ran.
#![allow(dead_code, reason = "each fuzz target uses one of the bodies")]

#[path = "chunk_build.rs"]
pub mod chunk_build;
#[cfg(feature = "cli")]
#[path = "cli_args.rs"]
pub mod cli_args;
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
