//! `hive --delta`: the source as a Delta Lake table, in a directory or under a prefix in a
//! bucket: a new table, or with `--append` one commit adding the source's segments to an
//! existing one (`chunkstore::parquet::delta`). A recording is a table of one segment.

use std::path::Path;

use chunkstore::dataset::{Dataset, DatasetError};
use chunkstore::parquet::HiveLayout;
use chunkstore::parquet::delta::{DeltaCommit, DeltaError, StagingDir, TableStore};

use crate::Failure;
use crate::args::HiveArgs;
use crate::source::{self, Source};
use crate::{load, output};

/// `hive DIR --delta [--append]` of `source`.
pub fn run(source: &Source, args: &HiveArgs) -> Result<(), Failure> {
    let layout = &super::hive::hive_layout(args);
    let table = Interruptible(table_store(&args.dir)?);
    let owned;
    let dataset_source = match source {
        Source::Recording(recording) => {
            owned = recording.as_dataset()?;
            &owned
        }
        Source::Dataset(dataset) => dataset,
    };
    dataset_source.with_dataset(false, |dataset| {
        let commit = write(dataset, &table, layout, args.append);
        output::uploads_ended(&format!(
            "nothing was committed to {}, and what was uploaded was deleted",
            table.name()
        ));
        let commit = commit.map_err(|error| failure(&args.dir, error))?;
        let raced = match commit.retries {
            0 => String::new(),
            1 => " (after another writer's commit)".to_owned(),
            n => format!(" (after {n} commits by other writers)"),
        };
        eprintln!(
            "committed version {} of {}: {} rows in {} files of {} segments{raced}",
            commit.version,
            table.name(),
            commit.rows(),
            commit.files.len(),
            commit.segments.len(),
        );
        Ok(())
    })
}

/// The write, a bar over the segments staged.
fn write(
    dataset: &Dataset,
    table: &dyn TableStore,
    layout: &HiveLayout,
    append: bool,
) -> Result<DeltaCommit, DatasetError> {
    let bar = load::progress(dataset.segments().len() as u64, "writing", false);
    let commit = dataset.write_delta(table, layout, append, &|_, _| bar.inc(1));
    bar.finish_and_clear();
    commit
}

/// The table `dir` names: a local directory, or a prefix in a bucket.
fn table_store(dir: &Path) -> Result<Box<dyn TableStore>, Failure> {
    #[cfg(feature = "object-store")]
    let (storage, cancel) = (output::storage().clone(), output::upload_cancel());
    // (A URL is then refused by `delta_table`, naming the feature it needs.)
    #[cfg(not(feature = "object-store"))]
    let (storage, cancel) = (
        chunkstore::storage::StorageOptions::default(),
        std::sync::Arc::default(),
    );
    chunkstore::storage::delta_table(dir, &storage, cancel).map_err(|e| e.to_string().into())
}

/// A write that failed, as the tool words it.
fn failure(dir: &Path, error: DatasetError) -> Failure {
    match error {
        DatasetError::Hive(error) | DatasetError::Delta(DeltaError::Hive(error)) => {
            super::hive::hive_failure(dir, error)
        }
        DatasetError::Delta(error) => crate::about_path(dir, error).into(),
        other => source::message(&other).into(),
    }
}

/// A table whose uploads Ctrl-C cancels (and whose write then deletes what it uploaded)
/// once they start; before, Ctrl-C exits at once and only a staging directory is left to
/// remove, which the exit does.
struct Interruptible(Box<dyn TableStore>);

impl TableStore for Interruptible {
    fn name(&self) -> String {
        self.0.name()
    }

    fn check_new(&self) -> Result<(), DeltaError> {
        self.0.check_new()
    }

    fn log_files(&self) -> Result<Vec<String>, DeltaError> {
        self.0.log_files()
    }

    fn read_log(&self, name: &str) -> Result<Vec<u8>, DeltaError> {
        self.0.read_log(name)
    }

    fn put_log_if_absent(&self, name: &str, bytes: Vec<u8>) -> Result<bool, DeltaError> {
        self.0.put_log_if_absent(name, bytes)
    }

    fn staging_dir(&self) -> Result<StagingDir, DeltaError> {
        self.0.staging_dir()
    }

    fn place(&self, staged: &Path, relative: &str) -> Result<(), DeltaError> {
        output::uploads_started();
        self.0.place(staged, relative)
    }

    fn remove_placed(&self, relative: &str) {
        self.0.remove_placed(relative);
    }

    fn parallel_places(&self) -> usize {
        self.0.parallel_places()
    }
}
