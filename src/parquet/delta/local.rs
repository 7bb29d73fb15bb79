//! [`LocalTable`]: a Delta table in a local directory.

use std::io::Write;
use std::path::{Path, PathBuf};

use super::log::{LOG_DIR, random_uuid};
use super::{DeltaError, StagingDir, TableStore};
use crate::output::UnfinishedOutput;
use crate::parquet::HiveExportError;

/// A Delta table in the local directory `dir`. A new table's directory must not exist
/// (its parent must); an append's must hold a `_delta_log/`.
#[derive(Clone, Debug)]
pub struct LocalTable {
    dir: PathBuf,
}

impl LocalTable {
    /// The table in `dir`.
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> DeltaError + '_ {
    move |source| DeltaError::io(path.display().to_string(), source)
}

impl TableStore for LocalTable {
    fn name(&self) -> String {
        self.dir.display().to_string()
    }

    fn check_new(&self) -> Result<(), DeltaError> {
        let layout = crate::parquet::HiveLayout::ByEntity { timeline: None };
        match crate::parquet::check_new_dataset(&self.dir, &layout) {
            Ok(()) => Ok(()),
            Err(HiveExportError::Exists { .. }) => Err(DeltaError::Exists { table: self.name() }),
            Err(other) => Err(other.into()),
        }
    }

    fn log_files(&self) -> Result<Vec<String>, DeltaError> {
        let dir = self.dir.join(LOG_DIR);
        let entries = match std::fs::read_dir(&dir) {
            Ok(entries) => entries,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(e) => return Err(io(&dir)(e)),
        };
        let mut names = Vec::new();
        for entry in entries {
            let entry = entry.map_err(io(&dir))?;
            names.push(entry.file_name().to_string_lossy().into_owned());
        }
        Ok(names)
    }

    fn read_log(&self, name: &str) -> Result<Vec<u8>, DeltaError> {
        let path = self.dir.join(LOG_DIR).join(name);
        std::fs::read(&path).map_err(io(&path))
    }

    fn put_log_if_absent(&self, name: &str, bytes: Vec<u8>) -> Result<bool, DeltaError> {
        let dir = self.dir.join(LOG_DIR);
        std::fs::create_dir_all(&dir).map_err(io(&dir))?;
        let target = dir.join(name);
        // Written whole and synced under a temporary name, then linked to its own: a link
        // fails if the name exists, which is the file system's one atomic "create if
        // absent" of a file with content.
        let temp = dir.join(format!(".{name}.{}.tmp", random_uuid()));
        let (_registered, mut file) = UnfinishedOutput::create(&temp, |p| {
            std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(p)
        })
        .map_err(io(&temp))?;
        let linked = file
            .write_all(&bytes)
            .and_then(|()| file.sync_all())
            .and_then(|()| std::fs::hard_link(&temp, &target));
        drop(file);
        let _ = std::fs::remove_file(&temp);
        match linked {
            Ok(()) => {
                if let Ok(dir) = std::fs::File::open(&dir) {
                    let _ = dir.sync_all();
                }
                Ok(true)
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
            Err(e) => Err(io(&target)(e)),
        }
    }

    fn staging_dir(&self) -> Result<StagingDir, DeltaError> {
        // Beside the table, on its file system: placing a file is a rename.
        let name = self
            .dir
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        StagingDir::create(
            self.dir
                .with_file_name(format!(".{name}.partial-{}", random_uuid())),
        )
    }

    fn place(&self, staged: &Path, relative: &str) -> Result<(), DeltaError> {
        let target = self.dir.join(relative);
        if let Some(parent) = target.parent() {
            std::fs::create_dir_all(parent).map_err(io(parent))?;
        }
        std::fs::rename(staged, &target).map_err(io(&target))
    }

    fn remove_placed(&self, relative: &str) {
        let target = self.dir.join(relative);
        let _ = std::fs::remove_file(&target);
        // The partition directories it alone was in, and a new table's own (`remove_dir`
        // keeps a non-empty one; an existing table's holds its log).
        let mut dir = target.parent();
        while let Some(d) = dir.filter(|d| d.starts_with(&self.dir)) {
            if std::fs::remove_dir(d).is_err() {
                break;
            }
            dir = d.parent();
        }
    }
}
