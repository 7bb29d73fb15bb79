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
