//! Fuzz target: an Arrow IPC stream and an edited copy, decoded with and without the cache of parsed schemas, must agree. See the harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    harness::quiet_panic_hook();
    harness::ipc_schema_cache::ipc_schema_cache(bytes);
});
