//! Fuzz target: arbitrary argument lists through the `chunkstore` tool's parser. See the harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    harness::quiet_panic_hook();
    harness::cli_args::cli_args(bytes);
});
