//! Fuzz target: arbitrary bytes as Arrow IPC → chunks → store → queries. See the harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    harness::quiet_panic_hook();
    harness::ipc_insert::ipc_insert(bytes);
});
