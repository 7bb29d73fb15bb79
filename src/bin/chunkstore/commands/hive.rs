//! `hive`: a Hive-partitioned Parquet dataset of the source (by entity, or by time bucket
//! of a timeline's dataframe; of a dataset, a partition per segment first), which DuckDB,
//! Polars, Spark and pyarrow read as one table. The new directory is checked before the
//! source is read, and appears whole or not at all. With `--delta`, a Delta Lake table,
//! in a directory or a bucket, made or appended to by one commit.

use std::path::Path;

use chunkstore::dataset::{Dataset, DatasetError};
use chunkstore::parquet::{check_new_dataset, write_hive_dataset};

use crate::Failure;
use crate::args::HiveArgs;
use crate::load::{self, Options};
use crate::source::{self, Source};

/// `hive DIR` of `source`.
pub fn run(source: &Source, args: &HiveArgs) -> Result<(), Failure> {
    if chunkstore::storage::url_scheme(&args.dir).is_some() {
        return Err(format!(
            "{}: a Hive copy in a bucket is a Delta table (--delta), which readers see whole \
             once committed; a plain copy is written to a local directory",
            args.dir.display()
        )
        .into());
    }
    check_new_dataset(&args.dir, &hive_layout(args))
        .map_err(|error| hive_failure(&args.dir, error))?;
    match source {
        Source::Recording(recording) => of_recording(&recording.path, args, &recording.options),
        Source::Dataset(dataset) => {
            dataset.with_dataset(false, |dataset| of_dataset(dataset, args))
        }
    }
}

/// A recording's Hive copy, from its loaded store.
fn of_recording(source: &Path, args: &HiveArgs, options: &Options) -> Result<(), Failure> {
    let layout = hive_layout(args);
    let failure = |error| hive_failure(&args.dir, error);
    let loaded = load::load(source, options)?;
    let summary = write_hive_dataset(&loaded.store, &args.dir, &layout).map_err(failure)?;
    eprintln!(
        "wrote {} rows in {} files under {}",
        summary.rows(),
        summary.files.len(),
        args.dir.display()
    );
    Ok(())
}

/// The layout `hive`'s arguments ask for.
pub fn hive_layout(args: &HiveArgs) -> chunkstore::parquet::HiveLayout {
    use chunkstore::parquet::HiveLayout;
    match (&args.index, args.bucket) {
        (Some(index), Some(width)) => HiveLayout::ByTimeBucket {
            timeline: index.as_str().into(),
            width,
            query: None,
        },
        (index, _) => HiveLayout::ByEntity {
            timeline: index.as_deref().map(Into::into),
        },
    }
}

/// A dataset that could not be written, as the tool words it.
pub fn hive_failure(dir: &Path, error: chunkstore::parquet::HiveExportError) -> Failure {
    use chunkstore::parquet::HiveExportError;
    match error {
        HiveExportError::Exists { .. } => format!(
            "{}: already exists (hive writes a new directory)",
            dir.display()
        ),
        HiveExportError::BucketWidth { width } => {
            format!("--bucket {width}: a bucket is at least 1 wide")
        }
        HiveExportError::Table(chunkstore::DataframeError::UnknownIndex(unknown)) => format!(
            "unknown timeline {:?} (the source has: {})",
            unknown.name,
            unknown.known.join(", ")
        ),
        other => crate::about_path(dir, other),
    }
    .into()
}

/// `hive`: the dataset as one Hive-partitioned Parquet dataset, a partition per segment
/// (and in it per entity, or per time bucket), a bar over the segments written.
fn of_dataset(dataset: &Dataset, args: &HiveArgs) -> Result<(), Failure> {
    let bar = load::progress(dataset.segments().len() as u64, "writing", false);
    let summary = dataset
        .write_hive(&args.dir, &hive_layout(args), &|_, _| bar.inc(1))
        .map_err(|error| match error {
            DatasetError::Hive(error) => hive_failure(&args.dir, error),
            other => source::message(&other).into(),
        });
    bar.finish_and_clear();
    let summary = summary?;
    let segments: std::collections::BTreeSet<&std::path::Path> = summary
        .files
        .iter()
        .filter_map(|(file, _)| file.parent()?.parent())
        .collect();
    eprintln!(
        "wrote {} rows in {} files of {} segments under {}",
        summary.rows(),
        summary.files.len(),
        segments.len(),
        args.dir.display()
    );
    Ok(())
}
