//! The footer's chunk manifest: one row per chunk of a recording, saying where its message
//! is in the file and what it holds (entity, static or not, time range per timeline and per
//! component), so that a reader can pick chunks without decoding them.
//!
//! Rerun encodes it as an Arrow record batch (inside an `RrdManifest` protobuf, inside the
//! `RrdFooter` that the `End` message carries), with these columns:
//! - `chunk_entity_path`, `chunk_id` (16 bytes, big-endian), `chunk_is_static`,
//!   `chunk_num_rows`, `chunk_byte_offset` and `chunk_byte_size` (the `ArrowMsg` body, after
//!   its message header), `chunk_byte_size_uncompressed` (the IPC payload's size);
//! - `<component>:has_static_data` per component (metadata `rerun:index` = `rerun:static`);
//! - `<timeline>:start` / `<timeline>:end` per timeline (typed like the timeline);
//! - `<timeline>:<component>:start|end|num_rows` per timeline and component (metadata
//!   `rerun:index` names the timeline, `rerun:component` the component).
//!
//! Beside it, the footer carries the recording's *sorbet schema*: one field per index,
//! and per entity and component (`/entity:component`), with Rerun's column metadata.

mod read;
mod write;

pub(crate) use read::decode_footer;
pub(crate) use write::{WrittenChunk, encode_footer};

use crate::{ChunkId, ComponentName, EntityPath, TimeInt, Timeline};

use super::messages::StoreId;

pub(super) const INDEX_KEY: &str = "rerun:index";
pub(super) const STATIC_INDEX: &str = "rerun:static";

/// One timeline's time range in a chunk (of the chunk, or of one component's cells).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ManifestTimeRange {
    /// The timeline.
    pub timeline: Timeline,
    /// Least time.
    pub min: TimeInt,
    /// Greatest time.
    pub max: TimeInt,
}

/// What the manifest says of one component of a chunk.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ManifestComponent {
    /// The component.
    pub name: ComponentName,
    /// Its cells' time range per timeline (empty for static data).
    pub ranges: Vec<ManifestTimeRange>,
}

/// One chunk as the manifest describes it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ManifestEntry {
    /// The chunk's id.
    pub chunk_id: ChunkId,
    /// Its entity.
    pub entity_path: EntityPath,
    /// Does it hold static data?
    pub is_static: bool,
    /// Its rows.
    pub num_rows: u64,
    /// Where its `ArrowMsg` body starts in the file (after the message header).
    pub byte_offset: u64,
    /// The `ArrowMsg` body's length.
    pub byte_size: u64,
    /// The decompressed IPC payload's length.
    pub uncompressed_size: u64,
    /// Time range of the chunk per timeline.
    pub ranges: Vec<ManifestTimeRange>,
    /// Its components.
    pub components: Vec<ManifestComponent>,
}

/// A recording's chunk manifest, from a file's footer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Manifest {
    /// The store it describes.
    pub store_id: StoreId,
    /// One entry per chunk, in file order.
    pub entries: Vec<ManifestEntry>,
}
