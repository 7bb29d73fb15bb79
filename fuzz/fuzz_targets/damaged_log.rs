//! Fuzz target: a server's `--persist` log written from a script, damaged once (a byte
//! changed, a cut, a zeroed tail), read back as the server reads it at start. See the
//! harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    harness::quiet_panic_hook();
    harness::damaged_log::damaged_log(bytes);
});
