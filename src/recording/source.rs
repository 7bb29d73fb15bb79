//! What a source is, told by its contents (never its name): an `.rrd` stream, a single Arrow
//! IPC file or stream, or a directory of chunk files.

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
    /// named by URL ([`crate::storage`]) is an `.rrd` (without a request: reading it
    /// says whether it is one).
    ///
    /// # Errors
    /// [`OpenError::Io`] if `path` cannot be read, [`OpenError::UnknownFormat`] if its
    /// first bytes are none of these.
    pub fn detect(path: &Path) -> Result<Self, OpenError> {
        let io = |source| OpenError::Io {
            path: path.to_owned(),
            source,
        };
        if crate::storage::url_scheme(path).is_some() {
            return Ok(Self::Rrd);
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
