//! Fuzz target: an Arrow IPC stream and an edited copy, decoded with the library's own batch decoder and with arrow-ipc's alone, must agree. See the harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    harness::quiet_panic_hook();
    harness::ipc_batch_decoder::ipc_batch_decoder(bytes);
});
