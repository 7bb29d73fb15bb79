//! The body of the `delta_log` fuzz target: a Delta table's `_delta_log/` written by
//! someone else, which `hive --delta --append` reads before it adds a commit
//! ([`Dataset::write_delta`]). The input is the log: entries separated by a zero byte,
//! named `00000000000000000000.json`, `…01.json` and on, except that an entry starting
//! with `@NAME\n` is named `NAME` (so that a log may skip versions, or hold a checkpoint's
//! marker). The table is in memory ([`TableStore`]); the dataset appended is two small
//! segments, `s0` and `s1`.
//!
//! What must hold (a writer's promise to everyone else who uses the table): no panic; a
//! refused append leaves the log as it was and removes every file it placed; an accepted
//! one adds exactly one entry, the version after the last, naming every file it placed.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use arrow_array::{ArrayRef, Float64Array};
use chunkstore::dataset::{Dataset, DatasetOptions};
use chunkstore::parquet::HiveLayout;
use chunkstore::parquet::delta::{DeltaError, StagingDir, TableStore};
use chunkstore::rrd::{StoreId, StoreInfo, write_rrd_file};
use chunkstore::{ChunkBuilder, ChunkId, EntityPath, RowId, Timeline};

/// A table in memory: its log's files, and the data files placed in it.
#[derive(Default)]
pub struct MemoryTable {
    /// Where staging directories are made.
    scratch: PathBuf,
    /// The log: file name to bytes.
    pub log: Mutex<BTreeMap<String, Vec<u8>>>,
    /// The data files placed and not removed, by path in the table.
    pub placed: Mutex<Vec<String>>,
}

impl MemoryTable {
    /// A table whose log is the input's entries (see the module docs).
    pub fn from_input(bytes: &[u8], scratch: &Path) -> Self {
        let mut log = BTreeMap::new();
        for (version, entry) in bytes.split(|&b| b == 0).enumerate() {
            let (name, text) = match entry.strip_prefix(b"@") {
                Some(named) => {
                    let end = named
                        .iter()
                        .position(|&b| b == b'\n')
                        .unwrap_or(named.len());
                    let name = String::from_utf8_lossy(&named[..end]).into_owned();
                    (name, named.get(end + 1..).unwrap_or_default())
                }
                None => (format!("{version:020}.json"), entry),
            };
            if !name.is_empty() && !name.contains('/') {
                log.insert(name, text.to_vec());
            }
        }
        Self {
            scratch: scratch.to_owned(),
            log: Mutex::new(log),
            placed: Mutex::default(),
        }
    }
}

impl TableStore for MemoryTable {
    fn name(&self) -> String {
        "memory://fuzzed".to_owned()
    }

    fn check_new(&self) -> Result<(), DeltaError> {
        Ok(())
    }

    fn log_files(&self) -> Result<Vec<String>, DeltaError> {
        Ok(self
            .log
            .lock()
            .expect("not poisoned")
            .keys()
            .cloned()
            .collect())
    }

    fn read_log(&self, name: &str) -> Result<Vec<u8>, DeltaError> {
        self.log
            .lock()
            .expect("not poisoned")
            .get(name)
            .cloned()
            .ok_or_else(|| DeltaError::io(name.to_owned(), std::io::ErrorKind::NotFound.into()))
    }

    fn put_log_if_absent(&self, name: &str, bytes: Vec<u8>) -> Result<bool, DeltaError> {
        let mut log = self.log.lock().expect("not poisoned");
        if log.contains_key(name) {
            return Ok(false);
        }
        log.insert(name.to_owned(), bytes);
        Ok(true)
    }

    fn staging_dir(&self) -> Result<StagingDir, DeltaError> {
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        StagingDir::create(
            self.scratch
                .join(format!("staging-{}-{n}", std::process::id())),
        )
    }

    fn place(&self, staged: &Path, relative: &str) -> Result<(), DeltaError> {
        std::fs::remove_file(staged).map_err(|e| DeltaError::io(relative.to_owned(), e))?;
        self.placed
            .lock()
            .expect("not poisoned")
            .push(relative.to_owned());
        Ok(())
    }

    fn remove_placed(&self, relative: &str) {
        self.placed
            .lock()
            .expect("not poisoned")
            .retain(|p| p != relative);
    }
}

/// The dataset every input appends (two segments of one scalar each), and a scratch
/// directory, made once per process.
fn dataset() -> &'static (Dataset, PathBuf) {
    static DATASET: OnceLock<(Dataset, PathBuf)> = OnceLock::new();
    DATASET.get_or_init(|| {
        let dir =
            std::env::temp_dir().join(format!("chunkstore-fuzz-delta-{}", std::process::id()));
        let segments = dir.join("segments");
        std::fs::create_dir_all(&segments).expect("a scratch directory");
        for id in ["s0", "s1"] {
            let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/e").expect("valid"))
                .with_row(
                    RowId::new(),
                    [(Timeline::sequence("frame"), 1)],
                    [("x", Arc::new(Float64Array::from(vec![1.5])) as ArrayRef)],
                )
                .build()
                .expect("a valid chunk");
            let info = StoreInfo::new(StoreId::recording("fuzz", id));
            let path = segments.join(format!("{id}.rrd"));
            write_rrd_file(&path, &info, [Arc::new(chunk)], |_| {}).expect("written");
        }
        let dataset = Dataset::open(&segments, &DatasetOptions::default()).expect("opens");
        (dataset, dir)
    })
}

/// The version a log entry's name says, if it is a commit's.
fn version_of(name: &str) -> Option<u64> {
    let digits = name.strip_suffix(".json")?;
    (digits.len() == 20).then(|| digits.parse().ok())?
}

/// Appends the two segments to the table the input's log describes; checks the promise.
pub fn delta_log(bytes: &[u8]) {
    let (dataset, scratch) = dataset();
    let table = MemoryTable::from_input(bytes, scratch);
    let before = table.log.lock().expect("not poisoned").clone();
    let layout = HiveLayout::ByEntity { timeline: None };
    let result = dataset.write_delta(&table, &layout, true, &|_, _| {});
    let log = table.log.lock().expect("not poisoned").clone();
    let placed = table.placed.lock().expect("not poisoned").clone();
    match result {
        Err(_) => {
            assert_eq!(log, before, "a refused append changed the log");
            assert!(placed.is_empty(), "a refused append left {placed:?}");
        }
        Ok(commit) => {
            let last = before.keys().filter_map(|n| version_of(n)).max();
            assert_eq!(
                Some(commit.version),
                last.map(|v| v + 1),
                "the next version"
            );
            let added: Vec<&String> = log.keys().filter(|n| !before.contains_key(*n)).collect();
            assert_eq!(added, [&format!("{:020}.json", commit.version)]);
            let entry = String::from_utf8_lossy(&log[added[0]]).into_owned();
            assert!(!placed.is_empty());
            for file in &placed {
                // (Its path in the log is escaped: its file's own name is not.)
                let name = file.rsplit('/').next().unwrap_or(file);
                assert!(entry.contains(name), "{file} placed, not committed");
            }
        }
    }
}
