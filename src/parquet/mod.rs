//! Parquet (feature `parquet`): what `pyarrow`, pandas, Polars, DuckDB and Spark read as
//! they are. [`write_parquet_file`] writes one file (a dataframe view or the raw chunk
//! table, streamed into row groups with statistics and the sort order);
//! [`write_hive_dataset`] a Hive-partitioned directory of them. Both appear whole or not
//! at all.
//!
//! ```no_run
//! use chunkstore::{ChunkStore, DataframeQuery};
//! use chunkstore::parquet::{ParquetOptions, write_parquet_file};
//! # let store = ChunkStore::new();
//! let query = DataframeQuery::new("frame_id").with_fill_latest_at(true);
//! let summary = write_parquet_file(
//!     "robot.parquet".as_ref(),
//!     store.dataframe(&query)?,
//!     &ParquetOptions::default().with_sorted_by("frame_id"),
//! )?;
//! println!("{} rows in {} row groups", summary.rows, summary.row_groups);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#[cfg(feature = "rrd")]
pub mod delta;
#[cfg(feature = "rrd")]
mod delta_types;
mod file;
mod hive;

pub use file::{
    DEFAULT_ROW_GROUP_BYTES, DEFAULT_ROW_GROUP_CELLS, ParquetExportError, ParquetOptions,
    ParquetSummary, write_parquet_file,
};
pub use hive::{
    HiveExportError, HiveLayout, HiveSummary, check_new_dataset, escape_partition_value,
    unescape_partition_value, write_hive_dataset,
};
#[cfg(feature = "rrd")]
pub(crate) use hive::{
    PartFile, bucket_key, bucket_query, check_bucket_width, write_buckets, write_entities,
    write_new_directory,
};
