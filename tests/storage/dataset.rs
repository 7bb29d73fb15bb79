//! A dataset over a prefix: one LIST and one GET per segment to open, its answers the
//! local dataset's, its chunks fetched in part.

use std::path::Path;

use arrow_array::RecordBatch;
use chunkstore::DataframeQuery;
use chunkstore::dataset::{Dataset, DatasetOptions};

use super::{bucket, counted, upload};
use crate::common;

fn table(dataset: &Dataset, query: &DataframeQuery) -> RecordBatch {
    let stream = dataset.dataframe(query).unwrap();
    let schema = stream.schema();
    let batches: Vec<RecordBatch> = stream.map(Result::unwrap).collect();
    arrow_select::concat::concat_batches(&schema, &batches).unwrap()
}

fn upload_dir(dir: &Path, prefix: &str, storage: &chunkstore::storage::StorageOptions) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_str().unwrap().to_owned();
        upload(&path, &format!("{prefix}{name}"), storage);
    }
}

#[test]
fn a_dataset_over_a_prefix_opens_with_one_list_and_one_get_per_segment() {
    let Some((_, storage, prefix, _turn)) = bucket("dataset") else {
        return;
    };
    let dir = common::ScratchDir::new("storage-dataset");
    common::episodes(&dir);
    upload_dir(&dir, &prefix, &storage);
    // Not a segment: only `.rrd` objects directly under the prefix are.
    upload(
        &common::robot_recording().join("a_robot.rrd"),
        &format!("{prefix}nested/a_robot.rrd"),
        &storage,
    );

    let options = DatasetOptions::default().with_storage(storage.clone());
    let (remote, open_cost) = counted(|| Dataset::open(Path::new(&prefix), &options));
    let remote = remote.unwrap();
    assert_eq!((open_cost.lists, open_cost.gets), (1, 3), "{open_cost}");
    let warnings = remote.take_warnings();
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("1 prefixes under it are not read")),
        "{warnings:?}"
    );
    let local = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    let ids = |d: &Dataset| {
        d.segments()
            .iter()
            .map(|s| (s.id.clone(), s.num_rows, s.num_chunks))
            .collect::<Vec<_>>()
    };
    assert_eq!(ids(&remote), ids(&local));
    assert!(
        remote.segments()[0]
            .path
            .to_str()
            .unwrap()
            .starts_with(&prefix)
    );

    let (mut gets, mut bytes_fetched) = (0, 0);
    for query in [
        DataframeQuery::new("frame"),
        DataframeQuery::new("frame").with_fill_latest_at(true),
    ] {
        let (ours, cost) = counted(|| table(&remote, &query));
        common::assert_same_table(&ours, &table(&local, &query), "the dataset's dataframe");
        // The footers were kept from opening: a query fetches chunks, never a footer again:
        // one coalesced GET per segment with rows on `frame` (two of the three), read once
        // (planning keeps what it read for the segments read first, as many as read at once).
        assert_eq!(cost.gets, 2, "{cost}");
        assert_eq!(cost.lists, 0, "{cost}");
        (gets, bytes_fetched) = (gets + cost.gets, bytes_fetched + cost.bytes_fetched);
    }
    // The dataset counts its own requests as the process does; a local one makes none.
    let read = remote.read_stats();
    assert_eq!(
        (read.requests, read.bytes_fetched),
        (gets, bytes_fetched),
        "{read:?}"
    );
    let local_read = local.read_stats();
    assert_eq!((local_read.requests, local_read.bytes_fetched), (0, 0));
    assert!(local_read.chunks_decoded > 0);
}

#[test]
fn an_empty_prefix_is_an_error_naming_it() {
    let Some((_, storage, prefix, _turn)) = bucket("empty") else {
        return;
    };
    let options = DatasetOptions::default().with_storage(storage);
    let error = Dataset::open(Path::new(&prefix), &options).expect_err("no .rrd objects");
    assert!(error.to_string().contains(&prefix), "{error}");
}

/// A segment without a footer in a bucket, with an index cache: read once when first
/// opened (streamed in one GET, at the version the open saw) and its index kept in the
/// cache; the next open reads the index, not the object, and a range fetches only the
/// chunks it needs. A rewritten object (another `ETag`) is read again, under a new index.
#[test]
fn a_footerless_object_is_indexed_once_in_the_index_cache() {
    let Some((_, storage, prefix, _turn)) = bucket("footerless") else {
        return;
    };
    let dir = common::ScratchDir::new("storage-footerless");
    let data = dir.join("data");
    std::fs::create_dir(&data).unwrap();
    // Twenty chunks of 2,000 values each (320 KB in all): more than the open's GET of the
    // object's end holds, so reading it whole takes a GET of its own.
    let write = |value: f64| {
        let chunks = (0..20u32)
            .map(|n| {
                let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..10u32)
                    .map(|r| {
                        // Values that do not compress.
                        let row = n * 10 + r;
                        let values = (0..200u32)
                            .map(|k| {
                                let scrambled =
                                    (u64::from(row * 200 + k) * 2_654_435_761) % 1_000_003;
                                value + f64::from(u32::try_from(scrambled).unwrap())
                            })
                            .collect();
                        (i64::from(row), u128::from(row) + 1, Some(values))
                    })
                    .collect();
                common::scalars("/robot/arm", "angle", &rows)
            })
            .collect();
        let path = common::write_without_footer(&data, "cut.rrd", "rec-c", chunks);
        upload(&path, &format!("{prefix}cut.rrd"), &storage);
        std::fs::metadata(&path).unwrap().len()
    };
    let size = write(1.0);
    assert!(size > chunkstore::storage::object::TAIL_GUESS, "{size}");
    let cache = dir.join("cache");
    let options = DatasetOptions::default()
        .with_storage(storage.clone())
        .with_index_cache(cache.clone())
        .with_config(chunkstore::StoreConfig::COMPACTION_OFF);
    let cached = || {
        let mut names: Vec<_> = std::fs::read_dir(&cache)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        names.sort();
        names
    };
    let range = chunkstore::TimeRange::new(
        chunkstore::TimeInt::new(42).unwrap(),
        chunkstore::TimeInt::new(47).unwrap(),
    );
    let queries = [
        DataframeQuery::new("frame"),
        DataframeQuery::new("frame").with_range(range),
    ];

    let (scanned, cost) = counted(|| Dataset::open(Path::new(&prefix), &options));
    let scanned = scanned.unwrap();
    // The end, then the whole object once.
    assert_eq!((cost.lists, cost.gets), (1, 2), "{cost}");
    assert_eq!(
        cost.bytes_fetched,
        chunkstore::storage::object::TAIL_GUESS + size,
        "{cost}"
    );
    let index = scanned.segment("rec-c").unwrap().index_file.clone();
    let index = index.expect("indexed");
    assert_eq!(cached(), vec![index.clone()]);

    // The next open reads the index: the object's end only, and the answers are those of
    // the same file read locally (whole: it has no footer); a range reads the one chunk
    // it needs.
    let (indexed, cost) = counted(|| Dataset::open(Path::new(&prefix), &options));
    let indexed = indexed.unwrap();
    assert_eq!((cost.lists, cost.gets), (1, 1), "{cost}");
    let segment = indexed.segment("rec-c").unwrap();
    assert_eq!(segment.index_file.as_ref(), Some(&index));
    assert_eq!((segment.num_rows, segment.num_chunks), (200, 20));
    let local = Dataset::open(&data, &DatasetOptions::default()).unwrap();
    for query in &queries {
        common::assert_same_table(&table(&indexed, query), &table(&local, query), "indexed");
    }
    let before = indexed.read_stats();
    let (_, cost) = counted(|| table(&indexed, &queries[1]));
    let read = indexed.read_stats().since(&before);
    // The range's chunk, and the first of the column's (planning learns its type from
    // it), in one coalesced GET.
    assert_eq!((read.chunks_decoded, read.requests), (2, 1), "{read:?}");
    assert_eq!(cost.gets, 1, "{cost}");
    assert!(cost.bytes_fetched < size / 4, "{cost}");

    // Rewritten: another version, read again under another index.
    write(2.0);
    let (rewritten, cost) = counted(|| Dataset::open(Path::new(&prefix), &options));
    let rewritten = rewritten.unwrap();
    assert_eq!(cost.gets, 2, "{cost}");
    let new_index = rewritten.segment("rec-c").unwrap().index_file.clone();
    assert!(new_index.is_some() && new_index.as_ref() != Some(&index));
    assert_eq!(cached().len(), 2);
    let local = Dataset::open(&data, &DatasetOptions::default()).unwrap();
    common::assert_same_table(
        &table(&rewritten, &queries[0]),
        &table(&local, &queries[0]),
        "rewritten",
    );
}

/// A footerless object no larger than the open's GET of its end is indexed from what that
/// GET fetched: no second request.
#[test]
fn a_small_footerless_object_is_indexed_from_its_open() {
    let Some((_, storage, prefix, _turn)) = bucket("footerless-small") else {
        return;
    };
    let dir = common::ScratchDir::new("storage-footerless-small");
    let path = common::write_without_footer(
        &dir,
        "small.rrd",
        "rec-s",
        vec![
            common::scalars("/robot/arm", "angle", &[(1, 1, Some(vec![1.0]))]),
            common::scalars("/robot/arm", "angle", &[(2, 2, Some(vec![2.0]))]),
        ],
    );
    upload(&path, &format!("{prefix}small.rrd"), &storage);
    let options = DatasetOptions::default()
        .with_storage(storage)
        .with_index_cache(dir.join("cache"));
    let (opened, cost) = counted(|| Dataset::open(Path::new(&prefix), &options));
    let opened = opened.unwrap();
    assert_eq!((cost.lists, cost.gets), (1, 1), "{cost}");
    assert!(opened.segment("rec-s").unwrap().index_file.is_some());
    let (again, cost) = counted(|| Dataset::open(Path::new(&prefix), &options));
    assert_eq!((cost.lists, cost.gets), (1, 1), "{cost}");
    let local = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    let query = DataframeQuery::new("frame");
    common::assert_same_table(
        &table(&again.unwrap(), &query),
        &table(&local, &query),
        "small",
    );
}
