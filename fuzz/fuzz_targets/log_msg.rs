//! Fuzz target: arbitrary bytes as the messages a client sends `chunkstore serve`, decoded
//! and ingested by a store hub. See the harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    harness::quiet_panic_hook();
    harness::log_msg::log_msg(bytes);
});
