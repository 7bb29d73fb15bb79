//! What a source is, told by its contents (a local file never by its name): an `.rrd`
//! stream, a single Arrow IPC file or stream, or a directory of chunk files. An object
//! named by URL is told by its name, without a request.

use std::io::Read as _;
use std::path::Path;

use super::error::OpenError;

/// The kinds of source a [`Recording`](super::Recording) opens.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceKind {
    /// A Rerun `.rrd` file (one stream or several concatenated).
    Rrd,
    /// A directory of Arrow IPC chunk files (and the `store_info.pb` `convert` writes).
    ChunkDirectory,
    /// One Arrow IPC file or stream of chunks.
    IpcFile,
}

impl SourceKind {
    /// The kind of `path`: a directory, or a file by its first bytes (the `.rrd` stream
    /// header, Arrow IPC's `ARROW1` magic or a stream's continuation marker). An object
    /// named by URL ([`crate::storage`]) is told by its name, without a request: a prefix
    /// (ending in `/`) is a directory of chunk files, an object ending in an Arrow IPC
    /// extension ([`crate::ipc::IPC_EXTENSIONS`]) an IPC file, any other an `.rrd`
    /// (reading it says whether it is one).
    ///
    /// # Errors
    /// [`OpenError::Io`] if `path` cannot be read, [`OpenError::UnknownFormat`] if its
    /// first bytes are none of these.
    pub fn detect(path: &Path) -> Result<Self, OpenError> {
        let io = |source| OpenError::Io {
            path: path.to_owned(),
            source,
        };
        if crate::storage::is_prefix_url(path) {
            return Ok(Self::ChunkDirectory);
        }
        if crate::storage::url_scheme(path).is_some() {
            let is_ipc = path.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                crate::ipc::IPC_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str())
            });
            return Ok(if is_ipc { Self::IpcFile } else { Self::Rrd });
        }
        let path = crate::storage::local_path(path);
        if std::fs::metadata(path).map_err(io)?.is_dir() {
            return Ok(Self::ChunkDirectory);
        }
        let mut head = Vec::with_capacity(8);
        std::fs::File::open(path)
            .map_err(io)?
            .take(8)
            .read_to_end(&mut head)
            .map_err(io)?;
        if crate::rrd::looks_like_rrd(&head) {
            Ok(Self::Rrd)
        } else if head.starts_with(b"ARROW1") || head.starts_with(&[0xff; 4]) {
            Ok(Self::IpcFile)
        } else {
            Err(OpenError::UnknownFormat {
                path: path.to_owned(),
                head,
            })
        }
    }
}
