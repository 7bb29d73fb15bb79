//! Delta Lake tables (features `parquet` and `rrd`): a dataset's Hive copy with a transaction log,
//! `_delta_log/`, that Spark, Databricks, Trino, DuckDB (`delta_scan`), Polars
//! (`scan_delta`) and `deltalake` read as one table, locally or in a bucket
//! (SEMANTICS.md section 15).
//!
//! A table is partitioned by `segment`, then by `entity` or by `<timeline>_bucket`, as the
//! Hive copy is ([`HiveLayout`](super::HiveLayout)); its files hold the same columns, in
//! the Delta types SEMANTICS.md section 15 maps them to. A write is one commit:
//! 1. the files are written to a local staging directory, each under a fresh name
//!    (`part-<uuid>.parquet`, so that no write ever replaces a file another committed);
//! 2. they are moved (a local table) or uploaded (a bucket) to their places, where no
//!    Delta reader sees them until a commit names them;
//! 3. the log entry of the next version is written only if it does not exist yet (a hard
//!    link locally, a conditional PUT, `If-None-Match: *`, in a bucket). A writer that
//!    loses that race reads the entries that won, and commits again at the next version,
//!    unless one of them added a segment it adds too: then it fails and removes its
//!    files. Two writers never both add a segment, and no commit is ever overwritten.
//!
//! A write that fails, or is cancelled, removes the files it placed; a process killed
//! outright leaves files no commit names, which no reader sees (`VACUUM` removes them).
//! Appending reads the log's JSON commits; a table whose log has a checkpoint, or whose
//! protocol asks for more than reader version 1 and writer version 2, is refused.

mod commit;
mod error;
mod local;
pub(crate) mod log;
mod stats;

pub use commit::DeltaCommit;
pub(crate) use commit::{DeltaWrite, write_table};
pub use error::DeltaError;
pub use local::LocalTable;

use std::path::{Path, PathBuf};

use crate::output::UnfinishedOutput;

/// The partition column every Delta table chunkstore writes starts with: the segment
/// (recording id) its rows are of.
pub const SEGMENT_COLUMN: &str = "segment";

/// Where a Delta table lives: a local directory ([`LocalTable`]) or a prefix in a bucket
/// (`chunkstore::storage::object::ObjectTable`, feature `object-store`). Everything a
/// write does to the table goes through this.
pub trait TableStore: Sync {
    /// The table's name in messages: its directory or URL.
    fn name(&self) -> String;

    /// Checks that a new table can be made here: nothing is at the location (and, for a
    /// directory, its parent exists).
    ///
    /// # Errors
    /// [`DeltaError::Exists`], or what the check itself met.
    fn check_new(&self) -> Result<(), DeltaError>;

    /// The names of the files in the table's `_delta_log/` (none when there is no log).
    ///
    /// # Errors
    /// The store's ([`DeltaError::Io`]).
    fn log_files(&self) -> Result<Vec<String>, DeltaError>;

    /// The log file `name`'s bytes.
    ///
    /// # Errors
    /// The store's ([`DeltaError::Io`]).
    fn read_log(&self, name: &str) -> Result<Vec<u8>, DeltaError>;

    /// Writes the log file `name` if, and only if, it does not exist yet, as one atomic
    /// step; `Ok(false)` when it did exist (another writer's commit won).
    ///
    /// # Errors
    /// The store's ([`DeltaError::Io`]).
    fn put_log_if_absent(&self, name: &str, bytes: Vec<u8>) -> Result<bool, DeltaError>;

    /// A new local directory to write the files of a commit in, before they are placed
    /// (removed when dropped).
    ///
    /// # Errors
    /// The file system's ([`DeltaError::Io`]).
    fn staging_dir(&self) -> Result<StagingDir, DeltaError>;

    /// Places the staged file `staged` at `relative` (a `/`-separated path in the table),
    /// where readers see it once a commit names it.
    ///
    /// # Errors
    /// The store's ([`DeltaError::Io`]).
    fn place(&self, staged: &Path, relative: &str) -> Result<(), DeltaError>;

    /// Removes a placed file that no commit named (a failed or cancelled write's), as well
    /// as it can.
    fn remove_placed(&self, relative: &str);

    /// How many files [`TableStore::place`] takes at once (uploads wait on the network).
    fn parallel_places(&self) -> usize {
        1
    }
}

/// A local directory a write stages its files in: registered for
/// [`crate::output::remove_unfinished_outputs`], and removed with what is left in it when
/// dropped.
#[derive(Debug)]
pub struct StagingDir {
    path: PathBuf,
    _registered: UnfinishedOutput,
}

impl StagingDir {
    /// Makes the new directory `path` (its parent must exist).
    ///
    /// # Errors
    /// The file system's ([`DeltaError::Io`]).
    pub fn create(path: PathBuf) -> Result<Self, DeltaError> {
        let (registered, ()) = UnfinishedOutput::create(&path, |p| std::fs::create_dir(p))
            .map_err(|e| DeltaError::io(path.display().to_string(), e))?;
        Ok(Self {
            path,
            _registered: registered,
        })
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for StagingDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
    }
}
