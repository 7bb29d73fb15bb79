//! A dataset as one Hive-partitioned Parquet dataset (feature `parquet`, SEMANTICS.md
//! sections 13 and 15): a partition per segment, `segment=<id>/`, and under it that
//! segment's partitions in the [`HiveLayout`] asked for:
//! - by entity: `segment=<id>/entity=<path>/part-0.parquet`, the segment's chunk table (the
//!   dataset's `chunks` table, [`DatasetTables::chunks`](super::DatasetTables::chunks));
//! - by time bucket: `segment=<id>/<timeline>_bucket=<k>/part-0.parquet`, the segment's
//!   rows of the dataset's dataframe on the timeline ([`Dataset::dataframe`]).
//!
//! Every file holds the whole table's columns, `rerun_segment_id` first (a column a
//! segment lacks is null in its files), so that DuckDB, Spark, Polars, pyarrow and
//! DataFusion read the directory as one table without merging schemas, and a file read
//! alone still names its segment. The partition keys are `segment` and `entity`, not the
//! columns' own names: Spark refuses a partition key that is also a column of the files.
//! Segments are written on the dataset's threads, each read once, so memory is bounded by
//! a few segments, whatever the dataset's size.

use std::path::Path;
use std::sync::Arc;

use arrow_schema::SchemaRef;

use super::schema::Placed;
use super::stream::PlannedRows;
use super::{Dataset, DatasetError, SegmentInfo};
use crate::DataframeQuery;
use crate::parquet::delta::{DeltaCommit, DeltaWrite, TableStore, write_table};
use crate::parquet::{
    HiveExportError, HiveLayout, HiveSummary, PartFile, bucket_key, bucket_query,
    check_bucket_width, check_new_dataset, escape_partition_value, write_buckets, write_entities,
    write_new_directory,
};

/// The partition key of a segment's directory.
pub const SEGMENT_PARTITION_KEY: &str = crate::parquet::delta::SEGMENT_COLUMN;

impl Dataset {
    /// Writes the dataset as a Hive-partitioned Parquet dataset in the new directory `dir`
    /// (which must not exist; it appears whole or not at all), a partition per segment
    /// laid out inside as `layout` says: see the module docs of `dataset/hive.rs`.
    /// `on_segment` is called once for every segment, from any of the dataset's threads,
    /// when its files are written, with what they hold (nothing, for a segment without
    /// rows).
    ///
    /// With [`HiveLayout::ByEntity`], a segment without the timeline given has its rows
    /// chunk by chunk. With [`HiveLayout::ByTimeBucket`], the query's contents and range
    /// narrow every segment's rows, and a segment without the timeline has no partition.
    ///
    /// ```no_run
    /// use chunkstore::dataset::{Dataset, DatasetOptions};
    /// use chunkstore::parquet::HiveLayout;
    ///
    /// let dataset = Dataset::open("episodes/".as_ref(), &DatasetOptions::default())?;
    /// let layout = HiveLayout::ByTimeBucket { timeline: "frame".into(), width: 100, query: None };
    /// let written = dataset.write_hive("episodes_hive".as_ref(), &layout, &|_, _| {})?;
    /// println!("{} rows in {} files", written.rows(), written.files.len());
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    ///
    /// # Errors
    /// What [`check_new_dataset`] checks ([`DatasetError::Hive`]), a timeline no segment
    /// has, what [`Dataset::dataframe`] refuses, a segment that cannot be read (unless
    /// skipped, [`DatasetOptions::skip_bad`](super::DatasetOptions::skip_bad)), the file
    /// system's and the Parquet writer's errors.
    pub fn write_hive(
        &self,
        dir: &Path,
        layout: &HiveLayout,
        on_segment: &(dyn Fn(&SegmentInfo, &HiveSummary) + Sync),
    ) -> Result<HiveSummary, DatasetError> {
        check_new_dataset(dir, layout)?;
        let plan = self.hive_plan(layout)?;
        write_new_directory(dir, |partial| {
            let written = |info: &SegmentInfo, summary: &HiveSummary| {
                on_segment(info, summary);
                Ok(())
            };
            self.write_partitions(partial, layout, &plan, &PartFile::default(), &written)
        })
    }

    /// Writes the dataset as a Delta Lake table (module docs of [`crate::parquet::delta`]):
    /// a new table, or with `append`, one commit adding the dataset's segments to an
    /// existing one (none of which it may hold already). The files are laid out as
    /// [`Dataset::write_hive`] lays them out, and `on_segment` is called as it calls it.
    ///
    /// ```no_run
    /// use chunkstore::dataset::{Dataset, DatasetOptions};
    /// use chunkstore::parquet::HiveLayout;
    /// use chunkstore::parquet::delta::LocalTable;
    ///
    /// let dataset = Dataset::open("episodes/".as_ref(), &DatasetOptions::default())?;
    /// let layout = HiveLayout::ByEntity { timeline: None };
    /// let table = LocalTable::new("episodes_delta");
    /// let commit = dataset.write_delta(&table, &layout, false, &|_, _| {})?;
    /// println!("version {}: {} rows", commit.version, commit.rows());
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    ///
    /// # Errors
    /// What [`Dataset::write_hive`] refuses (but an existing `table` when appending), and
    /// [`DatasetError::Delta`]: a table there already (or none, to append to), another
    /// partitioning, a segment in it already, a column of another type, a type or name
    /// Delta cannot hold, the store's errors.
    pub fn write_delta(
        &self,
        table: &dyn TableStore,
        layout: &HiveLayout,
        append: bool,
        on_segment: &(dyn Fn(&SegmentInfo, &HiveSummary) + Sync),
    ) -> Result<DeltaCommit, DatasetError> {
        check_bucket_width(layout)?;
        let plan = self.hive_plan(layout)?;
        let partitions = match layout {
            HiveLayout::ByEntity { .. } => vec![("entity".to_owned(), "string")],
            HiveLayout::ByTimeBucket { timeline, .. } => vec![(bucket_key(timeline), "long")],
        };
        let write = DeltaWrite {
            table,
            append,
            partitions,
            segments: self.segments().iter().map(|s| s.id.clone()).collect(),
            schema: Arc::clone(&plan.0),
        };
        write_table(&write, |staging, name, place| {
            let part = PartFile {
                name: name.to_owned(),
                delta: true,
            };
            // Each segment's files are placed as soon as they are written: the staging
            // directory holds a few segments at a time, whatever the table's size.
            let written = |info: &SegmentInfo, summary: &HiveSummary| {
                place(summary)?;
                on_segment(info, summary);
                Ok(())
            };
            self.write_partitions(staging, layout, &plan, &part, &written)
        })
    }

    /// What a copy's files hold (their schema) and, for a time bucket layout, the planned
    /// rows of each segment with data on its timeline.
    fn hive_plan(&self, layout: &HiveLayout) -> Result<PlannedRows, DatasetError> {
        match layout {
            HiveLayout::ByEntity { timeline } => {
                if let Some(timeline) = timeline
                    && self.time_type(timeline).is_none()
                {
                    return Err(self.unknown_index_error(timeline));
                }
                Ok((Arc::clone(&self.tables()?.chunks), Vec::new()))
            }
            HiveLayout::ByTimeBucket {
                timeline, query, ..
            } => match query {
                None => self.default_view(timeline),
                Some(_) => self.plan_dataframe(&bucket_query(timeline, query.as_ref())?),
            },
        }
    }

    /// Writes the copy's files under `dir` as `plan` planned them, telling `on_written`
    /// of each segment's (whose error stops the write).
    fn write_partitions(
        &self,
        dir: &Path,
        layout: &HiveLayout,
        plan: &PlannedRows,
        part: &PartFile,
        on_written: &OnWritten<'_>,
    ) -> Result<HiveSummary, DatasetError> {
        let (schema, segments) = plan;
        match layout {
            HiveLayout::ByEntity { timeline } => {
                self.entities_by_segment(dir, timeline.as_deref(), schema, part, on_written)
            }
            HiveLayout::ByTimeBucket {
                timeline, width, ..
            } => {
                let empty = HiveSummary::default();
                for (number, info) in self.segments().iter().enumerate() {
                    // `segments` is in segment order.
                    if segments
                        .binary_search_by_key(&number, |(n, ..)| *n)
                        .is_err()
                    {
                        on_written(info, &empty)?;
                    }
                }
                super::threads::in_parallel(segments, self.options().threads, |segment| {
                    let (number, query, kept) = segment.clone();
                    let info = &self.segments()[number];
                    let rows =
                        self.stream_segments(Arc::clone(schema), vec![(number, query, kept)], 1);
                    let mut summary = HiveSummary::default();
                    let dir = segment_dir(dir, info);
                    write_buckets(rows, &dir, timeline, *width, part, &mut summary)
                        .map_err(|error| segment_failure(info, error))?;
                    on_written(info, &summary)?;
                    Ok(summary)
                })
                .into_iter()
                .try_fold(HiveSummary::default(), merged)
            }
        }
    }

    /// The default view on `timeline` (every column, no fill) as [`Dataset::tables`]
    /// planned it, and the segments with data on it, each asking for every column: where
    /// [`Dataset::plan_dataframe`] would read every segment whole to plan the columns
    /// (and keep what it read, up to the memory budget), this reads a chunk of each column
    /// once per dataset shape.
    fn default_view(&self, timeline: &str) -> Result<PlannedRows, DatasetError> {
        let tables = self.tables()?;
        let Some(schema) = tables.timelines.get(timeline) else {
            return Err(self.unknown_index_error(timeline));
        };
        let names: Vec<String> = schema
            .fields()
            .iter()
            .skip(1)
            .map(|f| f.name().clone())
            .collect();
        let query = DataframeQuery::new(timeline).with_columns(names);
        let segments = (0..self.segments().len())
            .filter(|&n| self.segments()[n].time_type(timeline).is_some())
            .map(|n| (n, query.clone(), None))
            .collect();
        Ok((Arc::clone(schema), segments))
    }

    /// Every segment's chunk table, a partition per entity under its segment's.
    fn entities_by_segment(
        &self,
        dir: &Path,
        timeline: Option<&str>,
        schema: &SchemaRef,
        part: &PartFile,
        on_written: &OnWritten<'_>,
    ) -> Result<HiveSummary, DatasetError> {
        let numbers: Vec<usize> = (0..self.segments().len()).collect();
        super::threads::in_parallel(&numbers, self.options().threads, |&number| {
            let info = &self.segments()[number];
            // Every chunk, read through the footer where there is one (a copy reads each
            // segment once: nothing is kept for it in the cache).
            let snapshot = match self.segment_chunks(number, |manifest| {
                manifest.entries.iter().map(|e| e.chunk_id).collect()
            }) {
                Ok((snapshot, _)) => snapshot,
                Err(error) if self.options().skip_bad => {
                    self.warn(format!("skipped segment {:?}: {error}", info.id));
                    return Ok(HiveSummary::default());
                }
                Err(error) => return Err(error),
            };
            let mut summary = HiveSummary::default();
            let dir = segment_dir(dir, info);
            let timeline = timeline.filter(|t| snapshot.time_type(t).is_some());
            let id: Arc<str> = info.id.as_str().into();
            let shape = |table| Placed::new(table, Arc::clone(schema), Arc::clone(&id));
            write_entities(&snapshot, &dir, timeline, shape, part, &mut summary)
                .map_err(|error| segment_failure(info, error))?;
            on_written(info, &summary)?;
            Ok(summary)
        })
        .into_iter()
        .try_fold(HiveSummary::default(), merged)
    }
}

/// Told of each segment's files once they are written.
type OnWritten<'a> = dyn Fn(&SegmentInfo, &HiveSummary) -> Result<(), DatasetError> + Sync + 'a;

/// A segment's write that failed: a table it cannot give is the segment's error.
fn segment_failure(info: &SegmentInfo, error: HiveExportError) -> DatasetError {
    match error {
        HiveExportError::Table(error) => DatasetError::Dataframe {
            segment: info.id.clone(),
            error,
        },
        other => other.into(),
    }
}

/// `segment=<id>` under `dir` (made with its first partition's file: a segment without
/// rows has no directory).
fn segment_dir(dir: &Path, info: &SegmentInfo) -> std::path::PathBuf {
    dir.join(format!(
        "{SEGMENT_PARTITION_KEY}={}",
        escape_partition_value(&info.id)
    ))
}

fn merged(
    mut all: HiveSummary,
    one: Result<HiveSummary, DatasetError>,
) -> Result<HiveSummary, DatasetError> {
    all.files.extend(one?.files);
    Ok(all)
}
