//! [`RrdError`]: what is wrong with an `.rrd` input, and where.

use std::fmt;

use crate::ChunkError;
use crate::ipc::IpcError;

/// A fault in an `.rrd` input: the byte offset from the start of the stream where it was
/// found, and what it is.
#[derive(Debug)]
pub struct RrdError {
    /// Byte offset from the start of the input.
    pub offset: u64,
    /// What is wrong.
    pub kind: RrdErrorKind,
}

/// What is wrong with an `.rrd` input.
#[derive(Debug)]
#[non_exhaustive]
pub enum RrdErrorKind {
    /// Reading or writing failed.
    Io(std::io::Error),
    /// The input does not start with an `RRF2` stream header.
    NotAnRrd {
        /// The first four bytes.
        found: [u8; 4],
    },
    /// An `.rrd` from before the `RRF2` framing (Rerun < 0.23): not supported.
    OldFraming {
        /// The magic found (`RRF0` or `RRF1`).
        found: [u8; 4],
    },
    /// An `.rrd` with a framing newer than `RRF2` (e.g. `RRF3`): not readable by this
    /// version of the crate.
    NewerFraming {
        /// The magic found.
        found: [u8; 4],
    },
    /// The stream was written by a Rerun version whose encoding this crate cannot read
    /// (before 0.23, when the current framing was fixed).
    UnsupportedVersion {
        /// The `major.minor.patch` in the header.
        version: (u8, u8, u8),
    },
    /// The header's encoding options are unknown.
    BadOptions {
        /// What is wrong.
        reason: String,
    },
    /// The input ends in the middle of something.
    Truncated {
        /// What was being read.
        what: &'static str,
        /// Bytes it needs.
        needed: u64,
        /// Bytes there were.
        available: u64,
    },
    /// The rest of the input is zero bytes: space a file system gave a file whose write
    /// was cut short, never written.
    ZeroTail {
        /// How many zero bytes there are.
        len: u64,
    },
    /// A message header names a kind this crate does not know.
    UnknownMessageKind {
        /// The kind.
        kind: u64,
    },
    /// A protobuf message is malformed.
    Protobuf {
        /// What is wrong.
        reason: String,
    },
    /// A message lacks a field it needs.
    MissingField {
        /// The message.
        message: &'static str,
        /// The field.
        field: &'static str,
    },
    /// A payload's compression or encoding is unknown, or its LZ4 block is corrupt.
    Payload {
        /// What is wrong.
        reason: String,
    },
    /// The Arrow IPC payload is not a valid record batch.
    Ipc(IpcError),
    /// The record batch is not a valid chunk.
    Chunk(ChunkError),
    /// The footer (stream footer, `RrdFooter` or manifest) is malformed or disagrees with
    /// the body.
    Footer {
        /// What is wrong.
        reason: String,
    },
    /// Writing: a chunk under an id the writer has written already. The footer's manifest
    /// finds chunks by id, so a recording holds each id once (a reader would find the
    /// footer disagreeing with the body).
    DuplicateChunkId {
        /// The id.
        chunk_id: crate::ChunkId,
    },
    /// The input holds data of more than one recording and none was chosen: a store holds
    /// one recording (see [`super::RecordingSelector`]).
    SeveralRecordings {
        /// The recording ids found, in stream order.
        recording_ids: Vec<String>,
    },
    /// The recording asked for is not in the input.
    NoSuchRecording {
        /// The recording id asked for.
        wanted: String,
        /// The recording ids the input holds, in stream order.
        recording_ids: Vec<String>,
    },
}

impl RrdError {
    pub(crate) fn new(offset: u64, kind: RrdErrorKind) -> Self {
        Self { offset, kind }
    }

    /// Is the error about which recording to read ([`RrdErrorKind::SeveralRecordings`],
    /// [`RrdErrorKind::NoSuchRecording`]) rather than a fault of the input? A caller
    /// answers it by naming a recording, not by repairing a file.
    pub fn is_recording_choice(&self) -> bool {
        matches!(
            self.kind,
            RrdErrorKind::SeveralRecordings { .. } | RrdErrorKind::NoSuchRecording { .. }
        )
    }

    /// Does the error end the stream (the framing is lost), or only spoil one message
    /// (its payload), so that a reader told to keep going can go on with the next one?
    pub fn is_fatal(&self) -> bool {
        !matches!(
            self.kind,
            RrdErrorKind::Protobuf { .. }
                | RrdErrorKind::MissingField { .. }
                | RrdErrorKind::Payload { .. }
                | RrdErrorKind::Ipc(_)
                | RrdErrorKind::Chunk(_)
                | RrdErrorKind::UnknownMessageKind { .. }
        )
    }
}

impl fmt::Display for RrdError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Which recordings a file holds is no fault at a place in it, and an I/O error
        // before the first byte (a file that cannot be opened or created) is at none.
        let placeless = self.is_recording_choice()
            || (matches!(self.kind, RrdErrorKind::Io(_)) && self.offset == 0);
        if !placeless {
            write!(f, "at byte {}: ", self.offset)?;
        }
        match &self.kind {
            RrdErrorKind::Io(e) => write!(f, "{e}"),
            RrdErrorKind::NotAnRrd { found } => write!(
                f,
                "not an .rrd file (it starts with {:?}, not \"RRF2\")",
                String::from_utf8_lossy(found)
            ),
            RrdErrorKind::OldFraming { found } => write!(
                f,
                "an .rrd from before Rerun 0.23 ({:?} framing), which this crate does not \
                 read; convert it with a newer `rerun rrd migrate`",
                String::from_utf8_lossy(found)
            ),
            RrdErrorKind::NewerFraming { found } => write!(
                f,
                "an .rrd with a newer framing ({:?}) than this crate reads (\"RRF2\", Rerun \
                 0.23 to 0.41)",
                String::from_utf8_lossy(found)
            ),
            RrdErrorKind::UnsupportedVersion { version: (a, b, c) } => write!(
                f,
                "written by Rerun {a}.{b}.{c}, whose encoding this crate does not read \
                 (0.23 or newer is needed)"
            ),
            RrdErrorKind::BadOptions { reason } => write!(f, "bad stream header: {reason}"),
            RrdErrorKind::Truncated {
                what,
                needed,
                available,
            } => write!(
                f,
                "truncated {what}: needs {needed} bytes, {available} remain"
            ),
            RrdErrorKind::ZeroTail { len } => {
                write!(f, "the last {len} bytes are zeros (space never written)")
            }
            RrdErrorKind::UnknownMessageKind { kind } => {
                write!(f, "unknown message kind {kind}")
            }
            RrdErrorKind::Protobuf { reason } => write!(f, "malformed protobuf: {reason}"),
            RrdErrorKind::MissingField { message, field } => {
                write!(f, "{message} has no {field}")
            }
            RrdErrorKind::Payload { reason } => write!(f, "bad payload: {reason}"),
            RrdErrorKind::Ipc(e) => write!(f, "payload: {e}"),
            RrdErrorKind::Chunk(e) => write!(f, "payload is not a valid chunk: {e}"),
            RrdErrorKind::Footer { reason } => write!(f, "bad footer: {reason}"),
            RrdErrorKind::DuplicateChunkId { chunk_id } => write!(
                f,
                "{chunk_id} was written already: a recording holds each chunk id once"
            ),
            RrdErrorKind::SeveralRecordings { recording_ids } => write!(
                f,
                "data of more than one recording ({}): choose one by its recording id",
                quoted(recording_ids)
            ),
            RrdErrorKind::NoSuchRecording {
                wanted,
                recording_ids,
            } => write!(
                f,
                "no recording {wanted:?} (the recordings: {})",
                if recording_ids.is_empty() {
                    "none".to_owned()
                } else {
                    quoted(recording_ids)
                }
            ),
        }
    }
}

/// `"a", "b"`.
fn quoted(ids: &[String]) -> String {
    ids.iter()
        .map(|id| format!("{id:?}"))
        .collect::<Vec<_>>()
        .join(", ")
}

impl std::error::Error for RrdError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match &self.kind {
            RrdErrorKind::Io(e) => Some(e),
            RrdErrorKind::Ipc(e) => Some(e),
            RrdErrorKind::Chunk(e) => Some(e),
            _ => None,
        }
    }
}
