//! Fuzz target: arbitrary bytes as Arrow IPC → chunks → store → queries. See the harness.
#![no_main]

#[path = "../harness/ipc_insert.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| harness::ipc_insert(bytes));
