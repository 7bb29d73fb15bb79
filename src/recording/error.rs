//! Why a source could not be opened, and the faults a load skips when told to.

use std::fmt;
use std::path::PathBuf;

use crate::ipc::IpcError;
use crate::rrd::RrdError;
use crate::{ChunkId, ConfigError, InsertError};

/// Something in a source that could not be loaded: with
/// [`OpenOptions::skip_bad`](super::OpenOptions::skip_bad) it is passed to
/// [`LoadObserver::skipped`](super::LoadObserver::skipped) and the load goes on; without,
/// it is the load's error ([`OpenError::Fault`]).
///
/// Its `Display` is the warning (`skipped chunk … of …`); as an error it reads as
/// [`OpenError`]'s `Display` says.
#[derive(Debug)]
#[non_exhaustive]
pub enum LoadFault {
    /// The store refused a chunk (it is invalid, or contradicts what the store holds).
    Chunk {
        /// The file that holds it.
        path: PathBuf,
        /// The chunk.
        id: ChunkId,
        /// Its message's byte offset, in an `.rrd`.
        offset: Option<u64>,
        /// Why the store refused it.
        error: InsertError,
    },
    /// A message of an `.rrd` could not be decoded ([`RrdError::is_fatal`]: the rest of the
    /// stream could not be read either).
    Message {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        error: RrdError,
    },
    /// A chunk file of a directory could not be read.
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        error: IpcError,
    },
    /// An `.rrd` read to its end held no chunk that could be loaded (only with
    /// `skip_bad`: without it, the first fault is the error).
    NoChunk {
        /// The file.
        path: PathBuf,
    },
}

/// Arrow's and the store's errors span lines; a warning or an error is one line.
fn one_line(error: &dyn fmt::Display) -> String {
    error.to_string().trim_end().replace(['\n', '\r'], " ")
}

impl fmt::Display for LoadFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Chunk {
                path,
                id,
                offset: Some(offset),
                error,
            } => write!(
                f,
                "skipped chunk {id} of {} at byte {offset}: {}",
                path.display(),
                one_line(error)
            ),
            Self::Chunk {
                path,
                id,
                offset: None,
                error,
            } => write!(f, "skipped {id} of {}: {}", path.display(), one_line(error)),
            Self::Message { path, error } => write!(
                f,
                "{} {}: {}",
                if error.is_fatal() {
                    "stopped reading"
                } else {
                    "skipped a message of"
                },
                path.display(),
                one_line(error)
            ),
            Self::File { path, error } => {
                write!(f, "skipped {}: {}", path.display(), one_line(error))
            }
            Self::NoChunk { path } => {
                write!(f, "{} holds no chunk that could be loaded", path.display())
            }
        }
    }
}

/// Why a source could not be opened or loaded. Every variant names the file.
#[derive(Debug)]
#[non_exhaustive]
pub enum OpenError {
    /// The source could not be read (missing, unreadable).
    Io {
        /// The source.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is neither an `.rrd` nor Arrow IPC.
    UnknownFormat {
        /// The file.
        path: PathBuf,
        /// Its first bytes (at most 8).
        head: Vec<u8>,
    },
    /// A directory holds no Arrow IPC files.
    NoChunkFiles {
        /// The directory.
        dir: PathBuf,
    },
    /// With `skip_bad`, not one file of a directory could be read.
    NoReadableFile {
        /// The directory.
        dir: PathBuf,
        /// What went wrong with the first file.
        first: Box<LoadFault>,
    },
    /// The source holds several recordings and none was asked for, or not the one asked
    /// for ([`RrdError::is_recording_choice`]).
    Recording {
        /// The source.
        path: PathBuf,
        /// Which recordings it holds.
        error: RrdError,
    },
    /// An `.rrd` could not be read at all (its stream header), or its footer is corrupt.
    Rrd {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        error: RrdError,
    },
    /// Opening an `.rrd` lazily failed: its footer (or a stream footer) is corrupt.
    /// Reading it whole, without the footer, may still work.
    Footer {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        error: RrdError,
    },
    /// A single chunk file could not be read.
    Ipc {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        error: IpcError,
    },
    /// A directory's `store_info.pb` is corrupt.
    StoreInfo {
        /// The `store_info.pb` file.
        path: PathBuf,
        /// What is wrong.
        error: RrdError,
    },
    /// A fault that [`OpenOptions::skip_bad`](super::OpenOptions::skip_bad) would have
    /// skipped, loading the rest.
    Fault(Box<LoadFault>),
    /// The store configuration is invalid.
    Config(ConfigError),
}

impl OpenError {
    /// Would [`OpenOptions::skip_bad`](super::OpenOptions::skip_bad) have skipped this and
    /// loaded the rest?
    pub fn is_skippable(&self) -> bool {
        matches!(self, Self::Fault(_))
    }

    /// Is this the source holding several recordings, or not the one asked for?
    pub fn is_recording_choice(&self) -> bool {
        matches!(self, Self::Recording { .. })
    }

    /// An `.rrd` error of `path`: a recording choice or another fault.
    pub(crate) fn rrd(path: &std::path::Path, error: RrdError) -> Self {
        if error.is_recording_choice() {
            Self::Recording {
                path: path.to_owned(),
                error,
            }
        } else {
            Self::Rrd {
                path: path.to_owned(),
                error,
            }
        }
    }
}

impl fmt::Display for OpenError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io { path, source } => {
                write!(f, "{}", crate::storage::io_error_text(path, source))
            }
            Self::UnknownFormat { path, head } if head.is_empty() => write!(
                f,
                "{}: the file is empty (neither an .rrd file nor Arrow IPC)",
                path.display()
            ),
            Self::UnknownFormat { path, head } => write!(
                f,
                "{}: neither an .rrd file nor Arrow IPC (it starts with {:?})",
                path.display(),
                String::from_utf8_lossy(head)
            ),
            Self::NoChunkFiles { dir } => write!(
                f,
                "{}: no Arrow IPC files (.{}) for a recording, and no .rrd files for a dataset",
                dir.display(),
                crate::ipc::IPC_EXTENSIONS.join(", .")
            ),
            Self::NoReadableFile { dir, first } => {
                // The first fault as the warning would name it, less its verb.
                let first = first.to_string();
                let first = first.strip_prefix("skipped ").unwrap_or(&first);
                write!(
                    f,
                    "{}: none of its files could be read (the first: {first})",
                    dir.display()
                )
            }
            Self::Recording { path, error }
            | Self::Rrd { path, error }
            | Self::Footer { path, error }
            | Self::StoreInfo { path, error } => write!(f, "{}: {error}", path.display()),
            Self::Ipc { path, error } => write!(f, "{}: {error}", path.display()),
            Self::Fault(fault) => match &**fault {
                LoadFault::Chunk {
                    path,
                    id,
                    offset: Some(offset),
                    error,
                } => write!(
                    f,
                    "{}: chunk {id} at byte {offset}: {error}",
                    path.display()
                ),
                LoadFault::Chunk {
                    path,
                    offset: None,
                    error,
                    ..
                } => write!(f, "{}: {error}", path.display()),
                LoadFault::Message { path, error } => write!(f, "{}: {error}", path.display()),
                LoadFault::File { path, error } => write!(f, "{}: {error}", path.display()),
                LoadFault::NoChunk { .. } => write!(f, "{fault}"),
            },
            Self::Config(error) => write!(f, "{error}"),
        }
    }
}

impl std::error::Error for OpenError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io { source, .. } => Some(source),
            Self::Recording { error, .. }
            | Self::Rrd { error, .. }
            | Self::Footer { error, .. }
            | Self::StoreInfo { error, .. } => Some(error),
            Self::Ipc { error, .. } => Some(error),
            Self::Config(error) => Some(error),
            Self::Fault(fault) => match &**fault {
                LoadFault::Chunk { error, .. } => Some(error),
                LoadFault::Message { error, .. } => Some(error),
                LoadFault::File { error, .. } => Some(error),
                LoadFault::NoChunk { .. } => None,
            },
            Self::UnknownFormat { .. }
            | Self::NoChunkFiles { .. }
            | Self::NoReadableFile { .. } => None,
        }
    }
}
