//! Fuzz target: arbitrary bytes drive `Chunk::try_new` and `ChunkBuilder` → store →
//! queries. See the harness.
#![no_main]

#[path = "../harness/mod.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| harness::chunk_build::chunk_build(bytes));
