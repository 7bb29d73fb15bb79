//! Fuzz target: arbitrary bytes as Arrow IPC → chunks → store → queries. See the harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    // libfuzzer-sys's panic hook aborts on every panic, even one the library contains on
    // purpose (arrow-ipc's, see `chunkstore::ipc::read_batches`). A quiet hook lets those be
    // caught; any panic that escapes still aborts in libfuzzer-sys, so it is still a crash.
    static QUIET_HOOK: std::sync::Once = std::sync::Once::new();
    QUIET_HOOK.call_once(|| std::panic::set_hook(Box::new(|_| {})));
    harness::ipc_insert::ipc_insert(bytes);
});
