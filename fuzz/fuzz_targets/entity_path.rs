//! Fuzz target: arbitrary text → `EntityPath::parse` and the path's round trips. See the
//! harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| harness::entity_path::entity_path(bytes));
