//! Fuzz target: arbitrary bytes as the messages a client sends `chunkstore serve`, decoded
//! and ingested by a store hub. See the harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    // As in `ipc_insert`: a quiet hook, so that panics the library contains on purpose
    // (arrow-ipc's) do not abort; an escaping panic still does.
    static QUIET_HOOK: std::sync::Once = std::sync::Once::new();
    QUIET_HOOK.call_once(|| std::panic::set_hook(Box::new(|_| {})));
    harness::log_msg::log_msg(bytes);
});
