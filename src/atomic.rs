//! Files that appear whole or not at all: written to a temporary file beside the target,
//! synced, then renamed over it (and the directory synced), so an interrupted write
//! never leaves half a file under the target's name.

use std::path::{Path, PathBuf};

/// Runs `write` on a new temporary file beside `path`, then syncs it and renames it to
/// `path`; on any failure the temporary file is removed and `path` is untouched. `io`
/// turns an I/O error of this function's own into the caller's error type.
pub(crate) fn atomic_write<T, E>(
    path: &Path,
    io: impl Fn(std::io::Error) -> E,
    write: impl FnOnce(std::fs::File) -> Result<(std::fs::File, T), E>,
) -> Result<T, E> {
    let temp = temporary_path(path);
    let file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&temp)
        .map_err(&io)?;
    let result = write(file).and_then(|(file, value)| {
        file.sync_all().map_err(&io)?;
        drop(file);
        std::fs::rename(&temp, path).map_err(&io)?;
        // The rename itself is durable once the directory is synced (where that is possible).
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty())
            && let Ok(dir) = std::fs::File::open(dir)
        {
            let _ = dir.sync_all();
        }
        Ok(value)
    });
    if result.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    result
}

fn temporary_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    // A fresh row id is unique within the process, the pid across processes.
    let unique = crate::RowId::new().as_u128();
    path.with_file_name(format!(".{name}.{}-{unique:x}.tmp", std::process::id()))
}
