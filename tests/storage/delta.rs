//! Delta tables in a bucket (`ObjectTable`): files uploaded before the commit that names
//! them, commits as conditional PUTs the server refuses to repeat, racing writers of which
//! one wins, and a cancelled write that leaves no object behind.

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use chunkstore::dataset::{Dataset, DatasetError, DatasetOptions};
use chunkstore::parquet::HiveLayout;
use chunkstore::parquet::delta::{DeltaError, TableStore};
use chunkstore::storage::StorageOptions;
use chunkstore::storage::object::{ObjectTable, list_all};
use serde_json::Value;

use super::{bucket, counted};
use crate::common::{self, ScratchDir};

#[path = "../common/hooked_table.rs"]
mod hooked_table;
use hooked_table::Hooked;

const LAYOUT: HiveLayout = HiveLayout::ByEntity { timeline: None };

fn dataset_of(scratch: &ScratchDir, names: &[&str]) -> Dataset {
    let dir = scratch.join("episodes");
    if !dir.exists() {
        std::fs::create_dir(&dir).unwrap();
        common::episodes(&dir);
    }
    let files: Vec<PathBuf> = names.iter().map(|n| dir.join(n)).collect();
    Dataset::open_files(&files, &DatasetOptions::default()).unwrap()
}

fn table(url: &str, storage: &StorageOptions, cancelled: bool) -> ObjectTable {
    ObjectTable::new(url, storage, Arc::new(AtomicBool::new(cancelled))).unwrap()
}

/// The data files the table's log adds (as their keys: the log's paths decoded once).
fn logged_files(table: &ObjectTable) -> BTreeSet<String> {
    let mut names: Vec<String> = table.log_files().unwrap();
    names.sort();
    let mut files = BTreeSet::new();
    for name in names {
        let text = String::from_utf8(table.read_log(&name).unwrap()).unwrap();
        for line in text.lines() {
            let action: Value = serde_json::from_str(line).unwrap();
            if let Some(path) = action.pointer("/add/path").and_then(Value::as_str) {
                files.insert(chunkstore::parquet::unescape_partition_value(path));
            }
        }
    }
    files
}

/// The Parquet objects under the table's prefix.
fn stored_files(url: &str, storage: &StorageOptions) -> BTreeSet<String> {
    list_all(url, storage)
        .unwrap()
        .into_iter()
        .map(|(key, _)| key)
        .filter(|key| key.ends_with(".parquet"))
        .collect()
}

#[test]
fn a_table_in_a_bucket_is_committed_once_appended_to_and_raced_for() {
    let Some((_, storage, prefix, _turn)) = bucket("delta") else {
        return;
    };
    let scratch = ScratchDir::new("storage-delta");
    let url = format!("{prefix}table/");
    let new = table(&url, &storage, false);

    // A new table: its files, then one conditional PUT of the log's first entry.
    let (commit, requests) = counted(|| {
        dataset_of(&scratch, &["first.rrd"])
            .write_delta(&new, &LAYOUT, false, &|_, _| {})
            .unwrap()
    });
    assert_eq!(commit.version, 0);
    assert_eq!(requests.puts, commit.files.len() as u64 + 1, "{requests:?}");
    assert_eq!(requests.gets, 0, "{requests:?}");
    let stored = stored_files(&url, &storage);
    assert_eq!(logged_files(&new), stored);
    assert!(
        stored.iter().all(|key| key.contains("entity=%2Frobot")),
        "the partition's escaped value is the key's: {stored:?}"
    );
    // The server refuses a second first entry: a commit is never overwritten.
    assert!(
        !new.put_log_if_absent("00000000000000000000.json", b"{}\n".to_vec())
            .unwrap()
    );
    let error = dataset_of(&scratch, &["first.rrd"])
        .write_delta(&new, &LAYOUT, false, &|_, _| {})
        .unwrap_err();
    assert!(
        matches!(error, DatasetError::Delta(DeltaError::Exists { .. })),
        "{error}"
    );

    // Two writers adding the same segment at once: one commits, the other deletes its
    // files.
    let racing = Hooked::racing(table(&url, &storage, false), 2);
    let writers = [
        dataset_of(&scratch, &["second.rrd"]),
        dataset_of(&scratch, &["second.rrd"]),
    ];
    let results: Vec<_> = std::thread::scope(|scope| {
        let handles: Vec<_> = writers
            .iter()
            .map(|d| scope.spawn(|| d.write_delta(&racing, &LAYOUT, true, &|_, _| {})))
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let won: Vec<_> = results.iter().filter_map(|r| r.as_ref().ok()).collect();
    assert_eq!(won.len(), 1, "{results:?}");
    assert_eq!(won[0].version, 1);
    let lost = results.iter().find_map(|r| r.as_ref().err()).unwrap();
    assert!(
        matches!(lost, DatasetError::Delta(DeltaError::SegmentExists { segment }) if segment == "rec-a"),
        "{lost}"
    );
    assert_eq!(
        logged_files(&new),
        stored_files(&url, &storage),
        "the loser left nothing"
    );

    // A cancelled write (Ctrl-C in the tool) commits nothing and leaves nothing.
    let before = stored_files(&url, &storage);
    let error = dataset_of(&scratch, &["static_only.rrd"])
        .write_delta(&table(&url, &storage, true), &LAYOUT, true, &|_, _| {})
        .unwrap_err();
    assert!(error.to_string().contains("cancelled"), "{error}");
    assert_eq!(stored_files(&url, &storage), before);
    assert_eq!(new.log_files().unwrap().len(), 2);

    // Then the append lands as the next version.
    let commit = dataset_of(&scratch, &["static_only.rrd"])
        .write_delta(&new, &LAYOUT, true, &|_, _| {})
        .unwrap();
    assert_eq!(commit.version, 2);
    assert_eq!(commit.segments, ["rec-s"]);
    assert_eq!(logged_files(&new), stored_files(&url, &storage));
}
