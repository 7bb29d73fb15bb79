//! A Delta table store with hooks: `before_commit` runs before each commit is written (a
//! barrier there makes writers race for one version), `before_place` before each file is
//! placed (to look at the staging directory then).

use std::path::Path;

use chunkstore::parquet::delta::{DeltaError, StagingDir, TableStore};

/// `table`, with the hooks.
pub struct Hooked<T> {
    pub table: T,
    pub before_commit: Box<dyn Fn() + Sync>,
    pub before_place: Box<dyn Fn(&Path) + Sync>,
}

impl<T> Hooked<T> {
    /// `table`, its commits raced by `writers` threads: each writer's first commit waits
    /// until all of them are about to commit.
    pub fn racing(table: T, writers: usize) -> Self {
        let barrier = std::sync::Barrier::new(writers);
        let waited = std::sync::Mutex::new(std::collections::HashSet::new());
        Self {
            table,
            before_commit: Box::new(move || {
                if waited.lock().unwrap().insert(std::thread::current().id()) {
                    barrier.wait();
                }
            }),
            before_place: Box::new(|_| {}),
        }
    }
}

impl<T: TableStore> TableStore for Hooked<T> {
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
        (self.before_commit)();
        self.table.put_log_if_absent(name, bytes)
    }
    fn staging_dir(&self) -> Result<StagingDir, DeltaError> {
        self.table.staging_dir()
    }
    fn place(&self, staged: &Path, relative: &str) -> Result<(), DeltaError> {
        (self.before_place)(staged);
        self.table.place(staged, relative)
    }
    fn remove_placed(&self, relative: &str) {
        self.table.remove_placed(relative);
    }
    fn parallel_places(&self) -> usize {
        self.table.parallel_places()
    }
}
