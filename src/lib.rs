//! # chunkstore
//!
//! A columnar chunk store for spatiotemporal data: immutable Apache Arrow chunks in,
//! exact latest-at and range answers out, fast. Embedded by viewers, telemetry servers and
//! analytics tools; its core does no I/O (the `ipc` and `rrd` features read and write files).
//!
//! ## Concepts
//! - An [`EntityPath`] names a thing in a tree (`world/robot/camera`).
//! - A [`Timeline`] is a named axis of time ([`TimeType`]: sequence, duration, timestamp).
//! - A [`Chunk`] holds rows of one entity: a [`RowId`] column, one time column per
//!   timeline (none: *static* data), and component columns (Arrow `List` arrays, one cell
//!   per row). Chunks convert losslessly to and from Rerun's transport `RecordBatch`.
//! - The [`ChunkStore`] indexes chunks and answers [`LatestAtQuery`] ("value as of `t`")
//!   and [`RangeQuery`] ("every value in `[a, b]`"). Static data shadows temporal data;
//!   Clears (component [`ComponentName::CLEAR_IS_RECURSIVE`]) hide older data at query
//!   time. Inserting rows the store already holds changes nothing. The exact rules are
//!   in `docs/SEMANTICS.md`; `docs/ARCHITECTURE.md` maps the modules.
//! - Every query is a method of [`StoreView`], which the store dereferences to. A
//!   [`Snapshot`] freezes it in O(1) and answers as the store did then, for as long as it is
//!   held; a [`SharedStore`] lets one writer thread mutate the store while readers on other
//!   threads take snapshots without ever waiting (see [Readers that never
//!   wait](#readers-that-never-wait)).
//!
//! ## Example
//! ```
//! use std::sync::Arc;
//! use arrow_array::{ArrayRef, BooleanArray, Float64Array};
//! use chunkstore::*;
//!
//! let frame = Timeline::sequence("frame");
//! let robot = EntityPath::parse("/world/robot").unwrap();
//! let scalar = |v: f64| Arc::new(Float64Array::from(vec![v])) as ArrayRef;
//!
//! // Two rows of a speed reading, at frames 10 and 20.
//! let chunk = ChunkBuilder::new(ChunkId::new(), robot.clone())
//!     .with_row(RowId::new(), [(frame.clone(), 10)], [("speed", scalar(1.5))])
//!     .with_row(RowId::new(), [(frame.clone(), 20)], [("speed", scalar(2.5))])
//!     .build()?;
//! let mut store = ChunkStore::new();
//! store.insert(chunk)?;
//!
//! // Latest-at: the value as of frame 15 is the one logged at frame 10.
//! let at_15 = store.latest_at(&LatestAtQuery::new("frame", TimeInt::new(15).unwrap()), &robot, "speed");
//! assert_eq!(at_15.unwrap().time(), TimeInt::new(10));
//!
//! // Range: both rows, in time order.
//! let all = store.range(&RangeQuery::everything("frame"), &robot, "speed");
//! assert_eq!(all.iter().map(|r| r.time().unwrap().as_i64()).collect::<Vec<_>>(), [10, 20]);
//!
//! // A recursive Clear on `/world` at frame 30 hides the robot's speed from then on.
//! let clear = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/world").unwrap())
//!     .with_row(RowId::new(), [(frame, 30)], [(ComponentName::CLEAR_IS_RECURSIVE, Arc::new(BooleanArray::from(vec![true])) as ArrayRef)])
//!     .build()?;
//! store.insert(clear)?;
//! assert!(store.latest_at(&LatestAtQuery::new("frame", TimeInt::new(30).unwrap()), &robot, "speed").is_none());
//! assert!(store.latest_at(&LatestAtQuery::new("frame", TimeInt::new(29).unwrap()), &robot, "speed").is_some());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! ## Readers that never wait
//! A viewer renders while data streams in; a server answers clients while a robot logs. A
//! [`SharedStore`] is a handle that one writer at a time mutates (insert, batches, GC,
//! compaction, drops); each write publishes a new [`Snapshot`], and readers take the latest
//! one with an atomic load: no lock, no waiting for the writer, whatever it is doing.
//!
//! ```
//! use std::sync::Arc;
//! use arrow_array::{ArrayRef, Float64Array};
//! use chunkstore::*;
//!
//! let robot = EntityPath::parse("/robot").unwrap();
//! let row = |frame: i64| {
//!     let value = Arc::new(Float64Array::from(vec![frame as f64])) as ArrayRef;
//!     ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/robot").unwrap())
//!         .with_row(RowId::new(), [(Timeline::sequence("frame"), frame)], [("speed", value)])
//!         .build()
//!         .unwrap()
//! };
//! let shared = SharedStore::new(ChunkStore::new());
//!
//! let writer = {
//!     let shared = shared.clone();
//!     std::thread::spawn(move || {
//!         for frame in 0..1_000 {
//!             shared.insert(row(frame)).unwrap();
//!         }
//!         shared.write(|store| store.gc(&GcOptions::drop_at_least_fraction(0.5).unwrap()));
//!     })
//! };
//! let reader = std::thread::spawn(move || {
//!     let latest = LatestAtQuery::new("frame", TimeInt::MAX);
//!     let mut seen = 0;
//!     while seen < 999 {
//!         let snapshot = shared.snapshot(); // never blocks
//!         if let Some(cell) = snapshot.latest_at(&latest, &robot, "speed") {
//!             let time = cell.time().unwrap().as_i64();
//!             assert!(time >= seen, "a later snapshot never goes back");
//!             seen = time;
//!         }
//!     }
//! });
//! writer.join().unwrap();
//! reader.join().unwrap();
//! ```
//!
//! ## Crate features
//! - `ipc` (default): [`ipc`], reading chunks from Arrow IPC files and streams and writing
//!   them. Needs `arrow-ipc`.
//! - `rrd` (default): [`rrd`], Rerun `.rrd` files in and out, and lazy opening; and
//!   [`recording`], the one door to a recording of any source; and [`dataset`], many
//!   `.rrd` recordings queried as one table. Needs
//!   `lz4_flex`, `xxhash-rust` and `sha2`.
//! - `parquet`: `parquet`, dataframes and the raw chunk table as Parquet files, and
//!   Hive-partitioned datasets of them. Needs the `parquet` crate (Snappy only).
//! - `datafusion`: `sql`, the store's views as DataFusion tables with filters pushed down
//!   to its indices, the `latest_at` table function and `asof_join`; implies `parquet`.
//!   Needs `datafusion` 54 (a long build), `tokio`, `futures` and `async-trait`.
//! - `cli`: the `chunkstore` command-line tool (`cargo install --features cli`); implies
//!   `rrd` and `parquet`. With `datafusion` too, its `sql` command runs queries.
#![forbid(unsafe_code)]

mod chunk;
mod clear;
mod compaction;
mod component;
mod dataframe;
#[cfg(feature = "rrd")]
pub mod dataset;
mod dedup;
mod drop;
mod entity_path;
mod export;
mod gc;
#[cfg(feature = "rrd")]
pub mod hub;
mod ids;
mod index;
mod insert;
mod interner;
#[cfg(feature = "ipc")]
pub mod ipc;
mod ordered;
#[cfg(any(feature = "ipc", feature = "parquet"))]
pub mod output;
#[cfg(feature = "parquet")]
pub mod parquet;
mod query;
#[cfg(feature = "rrd")]
pub mod recording;
#[cfg(feature = "rrd")]
pub mod rrd;
mod sanity;
mod small_map;
mod snapshot;
#[cfg(feature = "datafusion")]
pub mod sql;
mod stats;
#[cfg(feature = "rrd")]
pub mod storage;
mod store;
mod text;
mod time;
mod time_text;

pub use chunk::{Chunk, ChunkBuilder, ChunkError, ComponentColumn, TimeColumn};
pub use compaction::{CompactionGroup, CompactionPlan, CompactionReason};
pub use component::{ComponentDescriptor, ComponentName};
pub use dataframe::{
    ChunkTableQuery, ChunkTableStream, DEFAULT_BATCH_BYTES, DEFAULT_BATCH_CELLS, DataframeError,
    DataframeQuery, DataframeStream, EntityPathFilter, EntityPathFilterError, SEGMENT_ID_COLUMN,
};
pub use entity_path::{EntityPath, EntityPathError};
pub use gc::{GcFraction, GcOptions, GcOptionsError, GcOrder, GcPlan, GcTarget};
pub use ids::{ChunkId, ParseChunkIdError, RowId};
pub use insert::InsertError;
pub use query::{LatestAtQuery, QueryCell, RangeQuery, RangeResult, RangeRow, RangeRun, RunRows};
pub use sanity::{SanityError, Structure};
pub use snapshot::{SharedStore, Snapshot};
pub use stats::{EntityStats, StoreStats};
pub use store::{ChunkStore, ConfigError, DeletionReason, StoreConfig, StoreEvent, StoreView};
pub use time::{TimeInt, TimeRange, TimeType, Timeline, UnknownTimeline};
pub use time_text::TimeParseError;

/// The README's example, compiled and run as a doctest so it cannot go stale.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
