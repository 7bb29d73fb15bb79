//! Fuzz target: arbitrary bytes as an `.rrd` stream, read from memory, streamed and opened lazily. See the harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    harness::quiet_panic_hook();
    harness::rrd_decode::rrd_decode(bytes);
});
