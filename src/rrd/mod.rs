//! Rerun `.rrd` files (feature `rrd`): a streaming reader ([`RrdReader`], [`read_rrd`]), a
//! writer ([`RrdWriter`], [`write_rrd_file`], atomic), and lazy opening through the
//! footer's chunk manifest ([`LazyRecording`]).
//!
//! The encoding is Rerun 0.41's (`RRF2` framing, protobuf messages, LZ4-compressed Arrow
//! IPC payloads, a footer with a chunk manifest), learnt from Rerun's public sources and
//! from files its SDK wrote; `docs/RRD.md` describes it byte by byte. Files from before
//! the `RRF2` framing (Rerun < 0.23) are refused. Blueprint stores are skipped, never mixed
//! into the data.

mod directory;
mod error;
mod footers;
mod frames;
pub mod index;
mod input;
mod lazy;
mod log_msg;
mod manifest;
mod messages;
mod payload;
pub(crate) mod protobuf;
mod reader;
mod recordings;
mod writer;

pub use directory::{
    STORE_INFO_FILE, choose_directory_recording, decode_directory_store_info,
    read_directory_recording, read_directory_store_info, write_directory_store_info,
};
pub use error::{RrdError, RrdErrorKind};
pub use footers::LazyStats;
pub use frames::StreamHeader;
pub use input::{Fetched, RrdInput};
pub use lazy::LazyRecording;
pub use log_msg::{DecodedLogMsg, LogMsg, LogMsgKind, LogScan, log_stream_header, scan_log};
pub use manifest::{Manifest, ManifestComponent, ManifestEntry, ManifestTimeRange};
pub use messages::{StoreId, StoreInfo, StoreKind};
pub use reader::{RrdContents, RrdItem, RrdReader, read_rrd, read_rrd_from};
pub use recordings::RecordingSelector;
pub use writer::{RrdWriter, write_rrd_file};

/// Does `bytes` (a file's first bytes) look like an `.rrd` stream of any framing?
pub fn looks_like_rrd(bytes: &[u8]) -> bool {
    bytes.len() >= 3 && &bytes[..3] == b"RRF"
}
