//! Parquet files of dataframes and of the raw chunk table: read back with the `parquet`
//! crate, they equal the in-memory tables; row groups carry min/max statistics on the
//! index and the entity path, the sort order is recorded, and an interrupted write leaves
//! nothing behind.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests fail loudly on unexpected values"
)]

use std::path::Path;
use std::sync::Arc;

use arrow_array::{Array, RecordBatch, RecordBatchIterator, RecordBatchReader};
use arrow_schema::{ArrowError, SchemaRef};
use arrow_select::concat::concat_batches;
use chunkstore::parquet::{ParquetExportError, ParquetOptions, write_parquet_file};
use chunkstore::{ChunkTableQuery, DataframeQuery, TimeInt, TimeRange};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use parquet::file::statistics::Statistics;

#[path = "../common/mod.rs"]
mod common;
use common::ScratchDir;

mod delta;

fn collect(reader: impl RecordBatchReader) -> RecordBatch {
    let schema = reader.schema();
    let batches: Vec<RecordBatch> = reader.map(Result::unwrap).collect();
    concat_batches(&schema, &batches).unwrap()
}

fn read_back(path: &Path) -> (RecordBatch, parquet::file::metadata::ParquetMetaData) {
    let file = std::fs::File::open(path).unwrap();
    let builder = ParquetRecordBatchReaderBuilder::try_new(file).unwrap();
    let metadata = builder.metadata().as_ref().clone();
    (collect(builder.build().unwrap()), metadata)
}

/// Does every row's `index` lie in bucket `bucket` of `width` index values?
fn in_bucket(batch: &RecordBatch, index: &str, width: i64, bucket: i64) -> bool {
    let times = batch
        .column_by_name(index)
        .unwrap()
        .as_any()
        .downcast_ref::<arrow_array::Int64Array>()
        .unwrap();
    times.values().iter().all(|t| t.div_euclid(width) == bucket)
}

/// Min and max of an Int64 column chunk's statistics, per row group.
fn int64_bounds(
    metadata: &parquet::file::metadata::ParquetMetaData,
    column: usize,
) -> Vec<(i64, i64)> {
    metadata
        .row_groups()
        .iter()
        .map(
            |group| match group.column(column).statistics().expect("statistics") {
                Statistics::Int64(s) => (*s.min_opt().unwrap(), *s.max_opt().unwrap()),
                other => panic!("not int64 statistics: {other:?}"),
            },
        )
        .collect()
}

#[test]
fn a_dataframe_reads_back_equal_with_ordered_row_groups_and_statistics() {
    let store = common::robot();
    let scratch = ScratchDir::new("parquet-robot");
    for fill in [false, true] {
        let query = DataframeQuery::new("frame_id")
            .with_fill_latest_at(fill)
            .with_batch_rows(16);
        let expected = collect(store.dataframe(&query).unwrap());
        assert_eq!(expected.num_rows(), 60);
        let path = scratch.join(format!("robot-{fill}.parquet"));
        let options = ParquetOptions::default()
            .with_sorted_by("frame_id")
            .with_row_group_rows(25);
        let summary =
            write_parquet_file(&path, store.dataframe(&query).unwrap(), &options).unwrap();
        assert_eq!((summary.rows, summary.row_groups), (60, 3));
        assert_eq!(summary.bytes, std::fs::metadata(&path).unwrap().len());
        let (back, metadata) = read_back(&path);
        // The Arrow schema travels in the file: names, types and Rerun's field metadata.
        assert_eq!(back.schema(), expected.schema());
        assert_eq!(back, expected);
        // Row groups ascend on the index and say so.
        let frame = expected.schema().index_of("frame_id").unwrap();
        assert_eq!(
            int64_bounds(&metadata, frame),
            [(0, 24), (25, 49), (50, 59)]
        );
        let sorting = metadata.row_group(0).sorting_columns().unwrap();
        assert_eq!(usize::try_from(sorting[0].column_idx).unwrap(), frame);
    }
}

#[test]
fn sampled_and_ranged_dataframes_read_back_equal() {
    let store = common::robot();
    let scratch = ScratchDir::new("parquet-queries");
    let t = |v| TimeInt::new(v).unwrap();
    for query in [
        DataframeQuery::new("sim_time").with_range(TimeRange::new(t(0), t(500_000_000))),
        DataframeQuery::new("log_time").with_fill_latest_at(true),
        DataframeQuery::new("frame_id").with_index_values([t(-1), t(30), t(99)]),
        DataframeQuery::new("frame_id").with_range(TimeRange::new(t(1000), t(2000))),
    ] {
        let path = scratch.join("query.parquet");
        write_parquet_file(
            &path,
            store.dataframe(&query).unwrap(),
            &ParquetOptions::default(),
        )
        .unwrap();
        assert_eq!(
            read_back(&path).0,
            collect(store.dataframe(&query).unwrap()),
            "{query:?}"
        );
    }
}

#[test]
fn the_chunk_table_reads_back_equal_and_prunes_on_time_and_entity() {
    let store = common::robot();
    let query = ChunkTableQuery::new()
        .with_index("frame_id")
        .with_batch_rows(50);
    let expected = collect(store.chunk_table(&query).unwrap());
    assert_eq!(expected.num_rows() as u64, store.stats().num_rows());
    let scratch = ScratchDir::new("parquet-chunks");
    let path = scratch.join("chunks.parquet");
    let options = ParquetOptions::default().with_row_group_rows(64);
    let summary = write_parquet_file(&path, store.chunk_table(&query).unwrap(), &options).unwrap();
    assert_eq!(summary.rows, expected.num_rows() as u64);
    let (back, metadata) = read_back(&path);
    assert_eq!(back, expected);
    // Rows without a frame come first, then frames ascend across row groups.
    let frame = expected.schema().index_of("frame_id").unwrap();
    let frames = arrow_array::cast::AsArray::as_primitive::<arrow_array::types::Int64Type>(
        expected.column(frame),
    );
    let with_frame: Vec<i64> = frames.iter().flatten().collect();
    assert!(with_frame.windows(2).all(|w| w[0] <= w[1]));
    assert_eq!(
        frames.iter().take_while(Option::is_none).count(),
        frames.null_count()
    );
    // The entity path has min/max statistics per row group.
    for group in metadata.row_groups() {
        let Statistics::ByteArray(s) = group.column(0).statistics().unwrap() else {
            panic!()
        };
        assert!(s.min_opt().unwrap().as_utf8().unwrap().starts_with('/'));
        assert!(s.max_opt().is_some());
    }
}

#[test]
fn the_chunk_table_holds_every_row_once_with_its_cells() {
    let store = common::robot();
    let table = collect(store.chunk_table(&ChunkTableQuery::new()).unwrap());
    let row_ids = arrow_array::cast::AsArray::as_fixed_size_binary(table.column(2));
    let mut seen: Vec<&[u8]> = row_ids.iter().map(Option::unwrap).collect();
    seen.sort_unstable();
    seen.dedup();
    assert_eq!(seen.len() as u64, store.stats().num_rows());
    // Every cell of every chunk is in the component column of its name.
    for chunk in store.chunks_unordered() {
        for (row, row_id) in chunk.row_ids().iter().enumerate() {
            let at = (0..table.num_rows())
                .find(|&r| row_ids.value(r) == row_id.to_be_bytes())
                .unwrap();
            for column in chunk.components() {
                let ours = table.column_by_name(column.name().as_str()).unwrap();
                assert_eq!(
                    ours.slice(at, 1).to_data(),
                    column.list_array().slice(row, 1).to_data(),
                    "{} row {row}",
                    column.name()
                );
            }
        }
    }
}

/// Yields one good batch, then an error.
struct FailingReader {
    schema: SchemaRef,
    batch: Option<RecordBatch>,
}

impl Iterator for FailingReader {
    type Item = Result<RecordBatch, ArrowError>;
    fn next(&mut self) -> Option<Self::Item> {
        Some(
            self.batch
                .take()
                .ok_or_else(|| ArrowError::ComputeError("interrupted".into())),
        )
    }
}

impl RecordBatchReader for FailingReader {
    fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }
}

#[test]
fn an_interrupted_write_leaves_nothing_and_keeps_an_older_file() {
    let store = common::robot();
    let batch = collect(store.dataframe(&DataframeQuery::new("frame_id")).unwrap());
    let scratch = ScratchDir::new("parquet-interrupted");
    let path = scratch.join("interrupted.parquet");
    let failing = FailingReader {
        schema: batch.schema(),
        batch: Some(batch.clone()),
    };
    let error = write_parquet_file(&path, failing, &ParquetOptions::default()).unwrap_err();
    assert!(matches!(error, ParquetExportError::Arrow(_)), "{error}");
    assert!(!path.exists());
    // Over an existing file: the old one stays whole.
    let good = RecordBatchIterator::new([Ok(batch.clone())], batch.schema());
    write_parquet_file(&path, good, &ParquetOptions::default()).unwrap();
    let failing = FailingReader {
        schema: batch.schema(),
        batch: Some(batch.clone()),
    };
    write_parquet_file(&path, failing, &ParquetOptions::default()).unwrap_err();
    assert_eq!(read_back(&path).0, batch);
    let leftovers: Vec<_> = std::fs::read_dir(path.parent().unwrap())
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .contains("interrupted.parquet.")
        })
        .collect();
    assert!(leftovers.is_empty(), "no temporary file is left");
    let error = write_parquet_file(
        &path,
        RecordBatchIterator::new([Ok(batch.clone())], batch.schema()),
        &ParquetOptions::default().with_sorted_by("nope"),
    )
    .unwrap_err();
    assert!(error.to_string().contains("\"nope\""));
}

/// A Hive dataset by entity: one file per entity, each with the whole chunk table's
/// schema and exactly that entity's rows, which together are the whole table.
#[test]
fn a_hive_dataset_by_entity_holds_each_entity_in_its_own_partition() {
    use chunkstore::parquet::{HiveLayout, escape_partition_value as escape, write_hive_dataset};
    let store = common::robot();
    let scratch = ScratchDir::new("parquet-hive-by-entity");
    let dir = scratch.join("dataset");
    let layout = HiveLayout::ByEntity {
        timeline: Some("frame_id".into()),
    };
    let summary = write_hive_dataset(&store, &dir, &layout).unwrap();
    let whole = collect(store.chunk_table(&ChunkTableQuery::new()).unwrap());
    assert_eq!(summary.rows(), whole.num_rows() as u64);
    let entities = store.entity_paths();
    assert_eq!(summary.files.len(), entities.len());
    for entity in &entities {
        let file = dir
            .join(format!("entity={}", escape(&entity.to_string())))
            .join("part-0.parquet");
        let (batch, _) = read_back(&file);
        assert_eq!(batch.schema().fields(), whole.schema().fields(), "{entity}");
        let paths = batch
            .column_by_name("entity_path")
            .unwrap()
            .as_any()
            .downcast_ref::<arrow_array::StringArray>()
            .unwrap()
            .iter()
            .map(|p| p.unwrap().to_owned())
            .collect::<std::collections::BTreeSet<_>>();
        assert_eq!(
            paths.into_iter().collect::<Vec<_>>(),
            vec![entity.to_string()]
        );
        let expected = store
            .chunks_unordered()
            .filter(|c| c.entity_path() == entity)
            .map(|c| c.num_rows())
            .sum::<usize>();
        assert_eq!(batch.num_rows(), expected, "{entity}");
    }
    // A second write to the same directory is refused, and leaves it as it was.
    let again = write_hive_dataset(&store, &dir, &layout).unwrap_err();
    assert!(
        matches!(again, chunkstore::parquet::HiveExportError::Exists { .. }),
        "{again:?}"
    );
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), entities.len());
}

/// A Hive dataset by time bucket: the files, in bucket order, are the dataframe view cut
/// at multiples of the width, and every file's index lies in its bucket.
#[test]
fn a_hive_dataset_by_time_bucket_cuts_the_view_at_bucket_boundaries() {
    use chunkstore::parquet::{HiveExportError, HiveLayout, check_new_dataset, write_hive_dataset};
    let store = common::robot();
    let view = collect(store.dataframe(&DataframeQuery::new("frame_id")).unwrap());
    let scratch = ScratchDir::new("parquet-hive-by-bucket");
    for width in [1, 7, 25, 1_000] {
        let dir = scratch.join(format!("width-{width}"));
        let layout = HiveLayout::ByTimeBucket {
            timeline: "frame_id".into(),
            width,
            query: None,
        };
        let summary = write_hive_dataset(&store, &dir, &layout).unwrap();
        let mut parts = Vec::new();
        for (file, written) in &summary.files {
            let (batch, _) = read_back(file);
            assert_eq!(batch.num_rows() as u64, written.rows);
            let bucket: i64 = file
                .parent()
                .unwrap()
                .file_name()
                .unwrap()
                .to_str()
                .unwrap()
                .strip_prefix("frame_id_bucket=")
                .unwrap()
                .parse()
                .unwrap();
            assert!(in_bucket(&batch, "frame_id", width, bucket), "{width}");
            parts.push(batch);
        }
        let joined = arrow_select::concat::concat_batches(&view.schema(), &parts).unwrap();
        common::assert_same_table(&joined, &view, &format!("buckets of {width}"));
    }
    let zero = HiveLayout::ByTimeBucket {
        timeline: "frame_id".into(),
        width: 0,
        query: None,
    };
    let scratch = ScratchDir::new("parquet-hive-zero");
    let dir = scratch.join("dataset");
    let error = write_hive_dataset(&store, &dir, &zero).unwrap_err();
    assert!(
        matches!(error, HiveExportError::BucketWidth { width: 0 }),
        "{error:?}"
    );
    assert!(!dir.exists(), "nothing is left behind");
    // The same checks before anything is read, for a caller with a source still to load;
    // a missing parent, and an unknown timeline (once the store is there), typed too.
    assert!(matches!(
        check_new_dataset(&dir, &zero),
        Err(HiveExportError::BucketWidth { width: 0 })
    ));
    let orphan = scratch.join("missing/dataset");
    let by_entity = HiveLayout::ByEntity { timeline: None };
    assert!(matches!(
        check_new_dataset(&orphan, &by_entity),
        Err(HiveExportError::NoParent { .. })
    ));
    assert!(check_new_dataset(&dir, &by_entity).is_ok());
    let unknown = HiveLayout::ByTimeBucket {
        timeline: "tick".into(),
        width: 10,
        query: None,
    };
    let error = write_hive_dataset(&store, &dir, &unknown).unwrap_err();
    assert!(
        matches!(
            &error,
            HiveExportError::Table(chunkstore::DataframeError::UnknownIndex(u)) if u.name == "tick"
        ),
        "{error:?}"
    );
    assert!(!dir.exists(), "nothing is left behind");
}

/// A store whose every dataframe row carries a static 5,000-point cell (40 KB) beside
/// 4,000 rows of scalars: a table of about 160 MB whose cell count is small.
fn big_static_cell_store() -> chunkstore::ChunkStore {
    let mut store = chunkstore::ChunkStore::new();
    let points: Vec<f64> = (0..5_000).map(f64::from).collect();
    store
        .insert(
            chunkstore::Chunk::try_new(
                chunkstore::ChunkId::new(),
                common::path("/map"),
                vec![common::rid(1)],
                vec![],
                vec![("points".into(), common::f64_list(&[Some(points)]))],
            )
            .unwrap(),
        )
        .unwrap();
    let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0u16..4_000)
        .map(|i| (i64::from(i), 10 + u128::from(i), Some(vec![f64::from(i)])))
        .collect();
    store.insert(common::scalars("/imu", "x", &rows)).unwrap();
    store
}

/// Issue 32, item 12: batches and row groups are bounded by bytes, not only by cells: a
/// static 5,000-point cell repeated on every row once made batches of gigabytes (a
/// Parquet export of a 4.8 MB recording took 1.09 GB of memory). Every batch of the
/// default query stays near `DEFAULT_BATCH_BYTES`, and the Parquet file is cut into row
/// groups by their encoded bytes (here a 4 MiB bound); the table is the same.
#[test]
fn batches_and_row_groups_are_bounded_by_bytes() {
    let store = big_static_cell_store();
    let query = DataframeQuery::new("frame");
    let stream = store.dataframe(&query).unwrap();
    assert!(stream.batch_rows() < 4_000, "{}", stream.batch_rows());
    let batches: Vec<RecordBatch> = stream.map(Result::unwrap).collect();
    assert!(batches.len() > 1);
    for batch in &batches {
        let bytes = batch.get_array_memory_size();
        assert!(bytes <= 2 * chunkstore::DEFAULT_BATCH_BYTES, "{bytes}");
    }
    let whole = collect(
        store
            .dataframe(&query.clone().with_batch_rows(4_000))
            .unwrap(),
    );
    let schema = batches[0].schema();
    assert_eq!(concat_batches(&schema, &batches).unwrap(), whole);

    let dir = ScratchDir::new("parquet-bytes");
    let path = dir.join("t.parquet");
    let options = ParquetOptions::default().with_row_group_bytes(4 << 20);
    let summary = write_parquet_file(&path, store.dataframe(&query).unwrap(), &options).unwrap();
    assert!(summary.row_groups > 1, "{summary:?}");
    assert_eq!(read_back(&path).0, whole);
}

/// The dataset of `common::episodes` (three recordings of different shapes), opened on
/// `threads` threads.
fn episodes_dataset(scratch: &ScratchDir, threads: usize) -> chunkstore::dataset::Dataset {
    use chunkstore::dataset::{Dataset, DatasetOptions};
    let source = scratch.join("episodes");
    if !source.exists() {
        std::fs::create_dir(&source).unwrap();
        common::episodes(&source);
    }
    let options = DatasetOptions::default().with_threads(threads);
    Dataset::open(&source, &options).unwrap()
}

/// `file`'s partition values under `root`, as (key, value) pairs, outermost first.
fn partition_values(root: &Path, file: &Path) -> Vec<(String, String)> {
    let relative = file.parent().unwrap().strip_prefix(root).unwrap();
    relative
        .iter()
        .map(|part| {
            let (key, value) = part.to_str().unwrap().split_once('=').unwrap();
            (key.to_owned(), value.to_owned())
        })
        .collect()
}

/// `batch`'s column `name` as strings.
fn strings(batch: &RecordBatch, name: &str) -> Vec<String> {
    let column = batch.column_by_name(name).unwrap();
    let column = column
        .as_any()
        .downcast_ref::<arrow_array::StringArray>()
        .unwrap();
    column.iter().map(|v| v.unwrap().to_owned()).collect()
}

/// A dataset's Hive copy by time bucket: a partition per segment, and in it per bucket;
/// every file has the dataset table's columns, its rows are its segment's and its bucket's,
/// and the files in order are the dataset's dataframe, on any number of threads.
#[test]
fn a_dataset_hive_copy_by_time_bucket_is_its_dataframe_cut_by_segment_and_bucket() {
    use chunkstore::parquet::HiveLayout;
    let scratch = ScratchDir::new("parquet-dataset-hive-bucket");
    for threads in [1, 3] {
        let dataset = episodes_dataset(&scratch, threads);
        let expected = collect(dataset.dataframe(&DataframeQuery::new("frame")).unwrap());
        assert_eq!(expected.num_rows(), 6);
        for width in [1, 2, 100] {
            let out = scratch.join(format!("bucket-{width}-{threads}"));
            let layout = HiveLayout::ByTimeBucket {
                timeline: "frame".into(),
                width,
                query: None,
            };
            let seen = std::sync::Mutex::new(Vec::new());
            let summary = dataset
                .write_hive(&out, &layout, &|info, written| {
                    seen.lock().unwrap().push((info.id.clone(), written.rows()));
                })
                .unwrap();
            let context = format!("width {width}, {threads} threads");
            let mut seen = seen.into_inner().unwrap();
            seen.sort();
            // Every segment is reported once; the static-only one wrote nothing.
            assert_eq!(
                seen,
                vec![
                    ("rec-a".to_owned(), 3),
                    ("rec-b".to_owned(), 3),
                    ("rec-s".to_owned(), 0)
                ],
                "{context}"
            );
            let mut parts = Vec::new();
            let mut keys = Vec::new();
            for (file, written) in &summary.files {
                assert!(file.starts_with(&out), "{context}: {}", file.display());
                let (batch, _) = read_back(file);
                assert_eq!(batch.num_rows() as u64, written.rows, "{context}");
                let values = partition_values(&out, file);
                assert_eq!(values[0].0, "segment", "{context}");
                assert_eq!(values[1].0, "frame_bucket", "{context}");
                let bucket: i64 = values[1].1.parse().unwrap();
                assert!(
                    strings(&batch, "rerun_segment_id")
                        .iter()
                        .all(|s| *s == values[0].1),
                    "{context}: a file holds its segment's rows"
                );
                assert!(
                    in_bucket(&batch, "frame", width, bucket),
                    "{context}: a file holds its bucket's rows"
                );
                keys.push((values[0].1.clone(), bucket));
                parts.push(batch);
            }
            let mut sorted = keys.clone();
            sorted.sort();
            sorted.dedup();
            assert_eq!(keys, sorted, "{context}: one file per partition, in order");
            let joined = concat_batches(&expected.schema(), &parts).unwrap();
            common::assert_same_cells(&joined, &expected, &context);
        }
    }
}

/// A dataset's Hive copy by entity: a partition per segment, and in it per entity; each
/// file is that segment's chunk table of that entity in the dataset's `chunks` columns
/// (null where the segment lacks a column), its segment id first.
#[test]
fn a_dataset_hive_copy_by_entity_is_each_segments_chunk_table() {
    use chunkstore::parquet::{HiveLayout, escape_partition_value as escape};
    let scratch = ScratchDir::new("parquet-dataset-hive-entity");
    let dataset = episodes_dataset(&scratch, 2);
    let columns = Arc::clone(&dataset.tables().unwrap().chunks);
    let out = scratch.join("by-entity");
    let layout = HiveLayout::ByEntity {
        timeline: Some("frame".into()),
    };
    let summary = dataset.write_hive(&out, &layout, &|_, _| {}).unwrap();
    let mut files = 0;
    for segment in dataset.segments() {
        let store = dataset
            .recording(&segment.id)
            .unwrap()
            .into_store()
            .unwrap();
        let mut entities = store.entity_paths();
        entities.sort();
        for entity in entities {
            let file = out
                .join(format!("segment={}", escape(&segment.id)))
                .join(format!("entity={}", escape(&entity.to_string())))
                .join("part-0.parquet");
            assert_eq!(summary.files[files].0, file);
            files += 1;
            let (batch, _) = read_back(&file);
            let mut query = ChunkTableQuery::new().with_row_entities([entity.clone()]);
            if store.time_type("frame").is_some() {
                query = query.with_index("frame");
            }
            let own = collect(store.chunk_table(&query).unwrap());
            // The segment's own table, placed in the dataset's columns by name.
            let placed: Vec<Arc<dyn Array>> = columns
                .fields()
                .iter()
                .map(|field| match own.column_by_name(field.name()) {
                    Some(column) => Arc::clone(column),
                    None if field.name() == "rerun_segment_id" => {
                        Arc::new(arrow_array::StringArray::from(vec![
                            segment.id.as_str();
                            own.num_rows()
                        ]))
                    }
                    None => arrow_array::new_null_array(field.data_type(), own.num_rows()),
                })
                .collect();
            let expected = RecordBatch::try_new(Arc::clone(&columns), placed).unwrap();
            common::assert_same_cells(&batch, &expected, &format!("{} {entity}", segment.id));
        }
    }
    assert_eq!(files, summary.files.len());
}

/// What a dataset's Hive copy refuses, each a typed error that leaves nothing behind: an
/// existing directory, a bucket narrower than one, a timeline no segment has; a corrupt
/// segment is named, or with `skip_bad` skipped with a warning while the rest is written.
#[test]
fn a_dataset_hive_copy_refuses_bad_requests_and_names_bad_segments() {
    use chunkstore::dataset::{Dataset, DatasetError, DatasetOptions};
    use chunkstore::parquet::{HiveExportError, HiveLayout};
    let scratch = ScratchDir::new("parquet-dataset-hive-bad");
    let dataset = episodes_dataset(&scratch, 2);
    let bucket = |timeline: &str, width| HiveLayout::ByTimeBucket {
        timeline: timeline.into(),
        width,
        query: None,
    };
    let existing = scratch.join("existing");
    std::fs::create_dir(&existing).unwrap();
    let error = dataset
        .write_hive(&existing, &bucket("frame", 10), &|_, _| {})
        .unwrap_err();
    assert!(
        matches!(error, DatasetError::Hive(HiveExportError::Exists { .. })),
        "{error:?}"
    );
    let out = scratch.join("out");
    let error = dataset
        .write_hive(&out, &bucket("frame", 0), &|_, _| {})
        .unwrap_err();
    assert!(
        matches!(
            error,
            DatasetError::Hive(HiveExportError::BucketWidth { width: 0 })
        ),
        "{error:?}"
    );
    for layout in [
        bucket("tick", 10),
        HiveLayout::ByEntity {
            timeline: Some("tick".into()),
        },
    ] {
        let error = dataset.write_hive(&out, &layout, &|_, _| {}).unwrap_err();
        assert!(
            matches!(&error, DatasetError::UnknownIndex(u) if u.name == "tick"),
            "{error:?}"
        );
        assert!(error.to_string().contains("frame"), "{error}");
    }
    assert!(!out.exists(), "nothing is left behind");

    // A segment whose file is cut short after opening: named, and nothing is written.
    let source = scratch.join("corrupt");
    std::fs::create_dir(&source).unwrap();
    common::episodes(&source);
    let opened = Dataset::open(&source, &DatasetOptions::default()).unwrap();
    let victim = source.join("second.rrd");
    let bytes = std::fs::read(&victim).unwrap();
    std::fs::write(&victim, &bytes[..bytes.len() / 2]).unwrap();
    for layout in [bucket("frame", 10), HiveLayout::ByEntity { timeline: None }] {
        let error = opened.write_hive(&out, &layout, &|_, _| {}).unwrap_err();
        assert!(error.to_string().contains("second.rrd"), "{error}");
        assert!(!out.exists(), "nothing is left behind");
    }
    // With skip_bad, what cannot be read of it is skipped with a warning, and the others
    // are written.
    let skipping = Dataset::open(&source, &DatasetOptions::default().with_skip_bad(true)).unwrap();
    let mut warnings = skipping.take_warnings();
    let summary = skipping
        .write_hive(&out, &bucket("frame", 10), &|_, _| {})
        .unwrap();
    warnings.extend(skipping.take_warnings());
    let segments: Vec<String> = summary
        .files
        .iter()
        .map(|(file, _)| partition_values(&out, file)[0].1.clone())
        .collect();
    assert!(segments.contains(&"rec-b".to_owned()), "{segments:?}");
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("second.rrd") || w.contains("rec-a")),
        "{warnings:?}"
    );
}

/// Batches of byte lists (images) go to the writer in slices, copied where they hold
/// bytes: a batch of 24 MB of them, with a column of scalars beside, reads back equal,
/// each slice's rows in place.
#[test]
fn a_batch_of_images_is_written_in_slices_and_reads_back_equal() {
    use arrow_array::builder::{Float64Builder, ListBuilder, UInt8Builder};

    let rows: u8 = 24;
    let mut images = ListBuilder::new(ListBuilder::new(UInt8Builder::new()));
    let mut scalars = ListBuilder::new(Float64Builder::new());
    for row in 0..rows {
        let image = images.values();
        for byte in 0..(1u32 << 20) {
            let value = (byte * 31 + u32::from(row) * 7) % 251;
            image.values().append_value(u8::try_from(value).unwrap());
        }
        image.append(true);
        images.append(row % 5 != 3); // a few null cells
        scalars.values().append_value(f64::from(row));
        scalars.append(true);
    }
    let images = Arc::new(images.finish()) as arrow_array::ArrayRef;
    let scalars = Arc::new(scalars.finish()) as arrow_array::ArrayRef;
    let batch =
        RecordBatch::try_from_iter([("/camera:buffer", images), ("/x:scalar", scalars)]).unwrap();
    // Written as a slice of a larger batch too: the slices' offsets start past zero.
    let dir = ScratchDir::new("parquet-image-slices");
    for (name, written) in [("whole", batch.clone()), ("sliced", batch.slice(5, 17))] {
        let path = dir.join(format!("{name}.parquet"));
        let reader = RecordBatchIterator::new([Ok(written.clone())], written.schema());
        write_parquet_file(&path, reader, &ParquetOptions::default()).unwrap();
        let (back, _) = read_back(&path);
        common::assert_same_table(&back, &written, name);
    }
}
