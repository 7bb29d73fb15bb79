//! Fuzz target: an Arrow IPC stream and an edited copy, decoded with the library's own batch decoder and with arrow-ipc's alone, must agree. See the harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    // As in `ipc_insert`: a quiet hook, so that panics the library contains on purpose
    // (arrow-ipc's) do not abort; an escaping panic still does.
    static QUIET_HOOK: std::sync::Once = std::sync::Once::new();
    QUIET_HOOK.call_once(|| std::panic::set_hook(Box::new(|_| {})));
    harness::ipc_batch_decoder::ipc_batch_decoder(bytes);
});
