//! One file per command, each answering for the SOURCE kinds it reads (a recording, a
//! dataset: `crate::source`). `main.rs` parses the command line and calls one of them;
//! `serve` is a directory of its own (a server: `chunkstore serve [SOURCE]...`).

pub mod convert;
pub mod dataframe;
pub mod hive;
pub mod hive_delta;
pub mod latest_at;
pub mod print;
pub mod range;
#[cfg(feature = "server")]
pub mod serve;
pub mod sql;
pub mod stats;
