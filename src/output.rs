//! Files that appear whole or not at all: written to a temporary file beside the target,
//! synced, then renamed over it (and the directory synced), so an interrupted write
//! never leaves half a file under the target's name.
//!
//! What is at the target decides how:
//! - nothing, or a regular file: the temporary file and the rename;
//! - a symbolic link: the same at the file it points to (resolved link by link, so a
//!   dangling link gets its target created), never replacing the link itself;
//! - anything else (a character device such as `/dev/stdout` or `/dev/null`, a FIFO):
//!   written through in place, since renaming over a device node or a pipe would replace
//!   it with a regular file (and leave a FIFO's reader waiting forever);
//! - a directory: an error.
//!
//! Every temporary file or directory being written is registered here, so that a program
//! interrupted by a signal can remove them all ([`remove_unfinished_outputs`]) before it
//! exits: the `chunkstore` tool does on SIGINT and SIGTERM. A process killed outright
//! (SIGKILL, a power cut) leaves its temporaries behind, under names that start with `.`
//! and end with `.tmp` or contain `.partial-`: nothing can run at such a death.

use std::path::{Path, PathBuf};

use parking_lot::Mutex;

/// The temporaries being written, and whether the process is going away.
struct Registry {
    /// Set by [`remove_unfinished_outputs`]: no temporary may be created after it.
    closed: bool,
    /// Temporary files and directories in progress.
    paths: Vec<PathBuf>,
}

static REGISTRY: Mutex<Registry> = Mutex::new(Registry {
    closed: false,
    paths: Vec::new(),
});

/// A temporary file or directory in progress, registered for
/// [`remove_unfinished_outputs`] until dropped (dropping does not remove it: the writer
/// renames it into place, or removes it itself on failure).
#[derive(Debug)]
pub struct UnfinishedOutput {
    path: PathBuf,
}

impl UnfinishedOutput {
    /// Creates the temporary `path` with `create` and registers it, as one step: a signal
    /// arriving in between could otherwise find nothing to remove and leave what `create`
    /// then makes.
    ///
    /// # Errors
    /// `create`'s error, or [`std::io::ErrorKind::Interrupted`] once
    /// [`remove_unfinished_outputs`] has run (the process is going away: nothing new is
    /// started).
    pub fn create<T>(
        path: &Path,
        create: impl FnOnce(&Path) -> std::io::Result<T>,
    ) -> std::io::Result<(Self, T)> {
        let mut registry = REGISTRY.lock();
        if registry.closed {
            return Err(std::io::Error::new(
                std::io::ErrorKind::Interrupted,
                "interrupted: no new output is started",
            ));
        }
        let value = create(path)?;
        registry.paths.push(path.to_owned());
        Ok((
            Self {
                path: path.to_owned(),
            },
            value,
        ))
    }

    /// The temporary's path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for UnfinishedOutput {
    fn drop(&mut self) {
        let mut registry = REGISTRY.lock();
        if let Some(i) = registry.paths.iter().position(|p| p == &self.path) {
            registry.paths.swap_remove(i);
        }
    }
}

/// Removes every temporary file and directory an atomic write of this process has in
/// progress, and refuses new ones from then on; returns how many were removed. For a
/// program's SIGINT or SIGTERM handler, right before it exits: the writes in progress
/// then fail (their renames find nothing), and no target is touched.
pub fn remove_unfinished_outputs() -> usize {
    let mut registry = REGISTRY.lock();
    registry.closed = true;
    let mut removed = 0;
    for path in registry.paths.drain(..) {
        let gone = if path.is_dir() {
            // Moved aside first: the writer may still be creating files in it (by its old
            // name, which then fails), and `remove_dir_all` racing a writer can find the
            // directory not empty at its end.
            let mut aside = path.clone().into_os_string();
            aside.push(".removing");
            let aside = PathBuf::from(aside);
            let doomed = if std::fs::rename(&path, &aside).is_ok() {
                aside
            } else {
                path
            };
            std::fs::remove_dir_all(&doomed)
        } else {
            std::fs::remove_file(&path)
        };
        removed += usize::from(gone.is_ok());
    }
    removed
}

/// Where a write to `path` goes.
enum Destination {
    /// A regular file (or nothing yet) at this path, the links resolved: replaced
    /// atomically.
    File(PathBuf),
    /// A device, FIFO or socket: written through.
    Stream,
}

/// What a write to `path` replaces or writes through. Devices and pipes are told apart
/// first, by what `path` finally names: `/dev/stdout` links to `/proc/self/fd/1`, whose
/// own link text (`pipe:[1234]`) names no file to resolve further.
fn destination(path: &Path) -> std::io::Result<Destination> {
    match std::fs::metadata(path) {
        Ok(metadata) if metadata.is_dir() => Err(std::io::Error::new(
            std::io::ErrorKind::IsADirectory,
            "a directory is there",
        )),
        Ok(metadata) if !metadata.is_file() => Ok(Destination::Stream),
        Ok(_) => resolve_links(path).map(Destination::File),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            resolve_links(path).map(Destination::File)
        }
        Err(e) => Err(e),
    }
}

/// `path` with its symbolic links followed (at most 40, as the kernel does), to the file
/// they name, which may not exist yet (a dangling link names the file to create).
fn resolve_links(path: &Path) -> std::io::Result<PathBuf> {
    let mut path = path.to_owned();
    for _ in 0..40 {
        match std::fs::symlink_metadata(&path) {
            Ok(metadata) if metadata.file_type().is_symlink() => {
                let target = std::fs::read_link(&path)?;
                path = match path.parent() {
                    Some(parent) if target.is_relative() => parent.join(target),
                    _ => target,
                };
            }
            Ok(_) => return Ok(path),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(path),
            Err(e) => return Err(e),
        }
    }
    Err(std::io::Error::other("too many levels of symbolic links"))
}

/// Runs `write` on a new temporary file beside `path` (or what its symbolic links point
/// to), then syncs it and renames it there; on any failure the temporary file is removed
/// and `path` is untouched. A device or FIFO at `path` is written through instead (see the
/// module docs). `io` turns an I/O error of this function's own into the caller's error
/// type.
pub(crate) fn atomic_write<T, E>(
    path: &Path,
    io: impl Fn(std::io::Error) -> E,
    write: impl FnOnce(std::fs::File) -> Result<(std::fs::File, T), E>,
) -> Result<T, E> {
    let target = match destination(path).map_err(&io)? {
        Destination::File(target) => target,
        Destination::Stream => {
            // Opened as it is: no create, no truncate (a device has nothing to truncate,
            // and a FIFO's reader is waiting for exactly these bytes).
            let file = std::fs::OpenOptions::new()
                .write(true)
                .open(path)
                .map_err(&io)?;
            return write(file).map(|(_, value)| value);
        }
    };
    let temp = temporary_path(&target);
    let (guard, file) = UnfinishedOutput::create(&temp, |temp| {
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(temp)
    })
    .map_err(&io)?;
    let result = write(file).and_then(|(file, value)| {
        file.sync_all().map_err(&io)?;
        drop(file);
        std::fs::rename(&temp, &target).map_err(&io)?;
        // The rename itself is durable once the directory is synced (where that is possible).
        if let Some(dir) = target.parent().filter(|d| !d.as_os_str().is_empty())
            && let Ok(dir) = std::fs::File::open(dir)
        {
            let _ = dir.sync_all();
        }
        Ok(value)
    });
    if result.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    drop(guard);
    result
}

/// A hidden name beside `path` for a temporary copy of it: `.NAME.PID-UNIQUE.tmp`.
pub(crate) fn temporary_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    // A fresh row id is unique within the process, the pid across processes.
    let unique = crate::RowId::new().as_u128();
    path.with_file_name(format!(".{name}.{}-{unique:x}.tmp", std::process::id()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("chunkstore-atomic-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn write_text(path: &Path, text: &str) -> std::io::Result<()> {
        atomic_write(
            path,
            |e| e,
            |mut file| {
                use std::io::Write as _;
                file.write_all(text.as_bytes())?;
                Ok((file, ()))
            },
        )
    }

    /// Issue 32, item 6: a symbolic link keeps being a link; its target gets the bytes.
    #[cfg(unix)]
    #[test]
    fn a_symlink_is_written_through_not_replaced() {
        let dir = scratch("symlink");
        let target = dir.join("target.txt");
        std::fs::write(&target, "old").unwrap();
        let link = dir.join("link.txt");
        std::os::unix::fs::symlink("target.txt", &link).unwrap();
        write_text(&link, "new").unwrap();
        assert!(
            std::fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "new");
        // A dangling link: its target is created.
        let dangling = dir.join("dangling.txt");
        std::os::unix::fs::symlink("created.txt", &dangling).unwrap();
        write_text(&dangling, "fresh").unwrap();
        assert_eq!(
            std::fs::read_to_string(dir.join("created.txt")).unwrap(),
            "fresh"
        );
        assert!(
            std::fs::symlink_metadata(&dangling)
                .unwrap()
                .file_type()
                .is_symlink()
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Issue 32, item 6: a device node is written through, never replaced by a file.
    #[cfg(unix)]
    #[test]
    fn a_device_is_written_through_not_replaced() {
        use std::os::unix::fs::FileTypeExt as _;
        write_text(Path::new("/dev/null"), "nothing").unwrap();
        assert!(
            std::fs::metadata("/dev/null")
                .unwrap()
                .file_type()
                .is_char_device()
        );
        if Path::new("/dev/full").exists() {
            let error = write_text(Path::new("/dev/full"), "too much").unwrap_err();
            assert_eq!(error.kind(), std::io::ErrorKind::StorageFull, "{error}");
            assert!(
                std::fs::metadata("/dev/full")
                    .unwrap()
                    .file_type()
                    .is_char_device()
            );
        }
        let dir = scratch("dir-target");
        let error = write_text(&dir, "x").unwrap_err();
        assert_eq!(error.kind(), std::io::ErrorKind::IsADirectory);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
