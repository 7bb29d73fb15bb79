//! The library's integration tests that need no optional feature but `ipc` and `rrd` (and
//! `cli` or `parquet` for a few fuzz replays), in one test binary: each links the whole arrow stack, and
//! one binary links it once (as DataFusion's `core_integration` does). Each module is one
//! subject; `cargo test --test core <module>::` runs one.
//!
//! Apart, in binaries of their own: `memory` (it counts allocations with a global
//! allocator), `model` (the long model test), and the feature-gated `cli`, `parquet` and
//! `sql`.

#[path = "../common/mod.rs"]
mod common;
#[path = "../../fuzz/harness/mod.rs"]
#[allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "the harness asserts with expect, like the fuzz target; a replay fails loudly"
)]
mod harness;

mod bad_input;
mod dataframe;
mod dataframe_oracle;
mod dataset;
mod docs;
mod file_size;
mod fuzz_corpus;
mod index_shapes;
mod lifecycle;
mod module_graph;
mod real_data;
mod recording;
mod rrd;
mod seeds;
mod semantics;
mod snapshot;
mod wide_chunks;
