//! A Delta table store whose writers each wait, before their first commit, until all of
//! them are about to commit: they race for one version, every time.

use std::collections::HashSet;
use std::path::Path;
use std::sync::{Barrier, Mutex};
use std::thread::ThreadId;

use chunkstore::parquet::delta::{DeltaError, StagingDir, TableStore};

/// `table`, raced by `writers` threads.
pub struct Racing<T> {
    table: T,
    barrier: Barrier,
    waited: Mutex<HashSet<ThreadId>>,
}

impl<T: TableStore> Racing<T> {
    pub fn new(table: T, writers: usize) -> Self {
        Self {
            table,
            barrier: Barrier::new(writers),
            waited: Mutex::default(),
        }
    }
}

impl<T: TableStore> TableStore for Racing<T> {
    fn name(&self) -> String {
        self.table.name()
    }
    fn check_new(&self) -> Result<(), DeltaError> {
        self.table.check_new()
    }
    fn log_files(&self) -> Result<Vec<String>, DeltaError> {
        self.table.log_files()
    }
    fn read_log(&self, name: &str) -> Result<Vec<u8>, DeltaError> {
        self.table.read_log(name)
    }
    fn put_log_if_absent(&self, name: &str, bytes: Vec<u8>) -> Result<bool, DeltaError> {
        if self
            .waited
            .lock()
            .unwrap()
            .insert(std::thread::current().id())
        {
            self.barrier.wait();
        }
        self.table.put_log_if_absent(name, bytes)
    }
    fn staging_dir(&self) -> Result<StagingDir, DeltaError> {
        self.table.staging_dir()
    }
    fn place(&self, staged: &Path, relative: &str) -> Result<(), DeltaError> {
        self.table.place(staged, relative)
    }
    fn remove_placed(&self, relative: &str) {
        self.table.remove_placed(relative);
    }
    fn parallel_places(&self) -> usize {
        self.table.parallel_places()
    }
}
