//! Fuzz target: a Delta table's log written by someone else, appended to as
//! `hive --delta --append` does. See the harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    harness::quiet_panic_hook();
    harness::delta_log::delta_log(bytes);
});
