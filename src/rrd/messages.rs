//! The protobuf messages of an `.rrd` stream (Rerun's `rerun.log_msg.v1alpha1`), read and
//! written by hand: `SetStoreInfo`, `ArrowMsg`, and the store ids they carry. Fields this
//! crate does not know are skipped (the format still grows), and fields it does not use are
//! kept as bytes so that a file written back says what the original said.

use std::cell::RefCell;
use std::sync::Arc;

use super::error::RrdErrorKind;
use super::protobuf::{FieldReader, FieldWriter, WireError};
use crate::ChunkId;

/// Whether a store holds a recording's data or a viewer's blueprint.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum StoreKind {
    /// Logged data.
    Recording,
    /// A viewer layout; never mixed into the data.
    Blueprint,
    /// A kind this crate does not know (kept as its number).
    Other(u64),
}

impl StoreKind {
    fn from_u64(value: u64) -> Self {
        match value {
            1 => Self::Recording,
            2 => Self::Blueprint,
            other => Self::Other(other),
        }
    }

    fn as_u64(self) -> u64 {
        match self {
            Self::Recording => 1,
            Self::Blueprint => 2,
            Self::Other(other) => other,
        }
    }
}

/// Which store a message belongs to.
///
/// Every message of a stream names its store, and a reader hands the id out with each
/// chunk: the texts are shared (`Arc<str>`), so a copy costs two reference counts, not
/// two allocations.
///
/// ```
/// # use chunkstore::rrd::StoreId;
/// let id = StoreId::recording("rerun_example_robot", "run-7");
/// assert_eq!(&*id.recording_id, "run-7");
/// assert_eq!(id.clone(), id);
/// ```
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct StoreId {
    /// Recording or blueprint.
    pub kind: StoreKind,
    /// The application that logged it (e.g. `rerun_example_robot_scene`).
    pub application_id: Arc<str>,
    /// The recording's id (often a UUID).
    pub recording_id: Arc<str>,
}

impl StoreId {
    /// A recording store's id.
    pub fn recording(
        application_id: impl Into<Arc<str>>,
        recording_id: impl Into<Arc<str>>,
    ) -> Self {
        Self {
            kind: StoreKind::Recording,
            application_id: application_id.into(),
            recording_id: recording_id.into(),
        }
    }

    /// Decodes a `StoreId` message. Every message of a stream names its store, so the
    /// last one a thread decoded is kept beside its bytes and copied when they repeat
    /// (decoding is a function of the bytes alone).
    pub(crate) fn decode(bytes: &[u8]) -> Result<Self, WireError> {
        thread_local! {
            static LAST: RefCell<Option<(Box<[u8]>, StoreId)>> = const { RefCell::new(None) };
        }
        /// A longer message is decoded every time.
        const MAX_KEPT_BYTES: usize = 512;
        let kept = LAST.with(|last| {
            let last = last.try_borrow().ok()?;
            let (kept_bytes, id) = last.as_ref()?;
            (**kept_bytes == *bytes).then(|| id.clone())
        });
        if let Some(id) = kept {
            return Ok(id);
        }
        let id = Self::decode_fields(bytes)?;
        if bytes.len() <= MAX_KEPT_BYTES {
            LAST.with(|last| {
                if let Ok(mut last) = last.try_borrow_mut() {
                    *last = Some((bytes.into(), id.clone()));
                }
            });
        }
        Ok(id)
    }

    fn decode_fields(bytes: &[u8]) -> Result<Self, WireError> {
        let mut kind = StoreKind::Other(0);
        let mut application_id = None;
        let mut recording_id = None;
        let mut fields = FieldReader::new(bytes);
        while let Some(field) = fields.next_field()? {
            match field.number {
                1 => kind = StoreKind::from_u64(field.varint("StoreId")?),
                2 => recording_id = Some(field.string("StoreId")?),
                3 => {
                    if let Some(app) = field.nested("StoreId", decode_application_id)? {
                        application_id = Some(app);
                    }
                }
                _ => {}
            }
        }
        Ok(Self {
            kind,
            application_id: application_id.unwrap_or_default().into(),
            recording_id: recording_id.unwrap_or_default().into(),
        })
    }

    pub(crate) fn encode(&self, out: &mut FieldWriter) {
        out.varint(1, self.kind.as_u64())
            .bytes(2, self.recording_id.as_bytes())
            .message(3, |app| {
                app.bytes(1, self.application_id.as_bytes());
            });
    }
}

/// A store's description (`SetStoreInfo`): the first message of each store in a stream.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StoreInfo {
    /// The store.
    pub store_id: StoreId,
    /// The encoded `StoreSource` (which SDK or tool logged it), kept verbatim.
    store_source: Option<Vec<u8>>,
    /// The encoded `StoreVersion`, kept verbatim.
    store_version: Option<Vec<u8>>,
}

impl StoreInfo {
    /// A store info for a store this crate writes: source "other" (`chunkstore`), and the
    /// Rerun version whose encoding is written.
    pub fn new(store_id: StoreId) -> Self {
        let mut source = FieldWriter::default();
        source.varint(1, 6).message(2, |extra| {
            extra.bytes(1, b"chunkstore");
        });
        let mut version = FieldWriter::default();
        version.varint(
            1,
            u64::from(u32::from_le_bytes(super::frames::WRITTEN_VERSION)),
        );
        Self {
            store_id,
            store_source: Some(source.bytes),
            store_version: Some(version.bytes),
        }
    }

    /// Decodes a `SetStoreInfo` message body.
    pub(crate) fn decode_set_store_info(bytes: &[u8]) -> Result<Self, WireError> {
        let mut fields = FieldReader::new(bytes);
        while let Some(field) = fields.next_field()? {
            if field.number == 2 {
                return field.nested("SetStoreInfo", Self::decode_info);
            }
        }
        Err((
            0,
            RrdErrorKind::MissingField {
                message: "SetStoreInfo",
                field: "info",
            },
        ))
    }

    fn decode_info(bytes: &[u8]) -> Result<Self, WireError> {
        let mut store_id = None;
        let mut legacy_application_id = None;
        let mut store_source = None;
        let mut store_version = None;
        let mut fields = FieldReader::new(bytes);
        while let Some(field) = fields.next_field()? {
            match field.number {
                // Deprecated `ApplicationId`, from before it moved into the store id.
                1 => legacy_application_id = field.nested("StoreInfo", decode_application_id)?,
                2 => store_id = Some(field.nested("StoreInfo", StoreId::decode)?),
                5 => store_source = Some(field.bytes("StoreInfo")?.to_vec()),
                6 => store_version = Some(field.bytes("StoreInfo")?.to_vec()),
                _ => {}
            }
        }
        let mut store_id = store_id.ok_or((
            0,
            RrdErrorKind::MissingField {
                message: "StoreInfo",
                field: "store_id",
            },
        ))?;
        if store_id.application_id.is_empty()
            && let Some(app) = legacy_application_id
        {
            store_id.application_id = app.into();
        }
        Ok(Self {
            store_id,
            store_source,
            store_version,
        })
    }

    /// Encodes a `SetStoreInfo` message body; `row_id` is the message's own id.
    pub(crate) fn encode_set_store_info(&self, row_id: u128) -> Vec<u8> {
        let mut out = FieldWriter::default();
        out.message(1, |tuid| encode_tuid(tuid, row_id))
            .message(2, |info| {
                info.message(2, |id| self.store_id.encode(id));
                if let Some(source) = &self.store_source {
                    info.bytes(5, source);
                }
                if let Some(version) = &self.store_version {
                    info.bytes(6, version);
                }
            });
        out.bytes
    }
}

/// An `ApplicationId { 1: id }`: its id, if it has one.
fn decode_application_id(bytes: &[u8]) -> Result<Option<String>, WireError> {
    let mut id = None;
    let mut fields = FieldReader::new(bytes);
    while let Some(field) = fields.next_field()? {
        if field.number == 1 {
            id = Some(field.string("ApplicationId")?);
        }
    }
    Ok(id)
}

/// A Tuid is the id's high half (`time_ns`) and low half (`inc`), as fixed64s.
fn encode_tuid(out: &mut FieldWriter, id: u128) {
    let bytes = id.to_be_bytes();
    let half = |b: &[u8]| u64::from_be_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]);
    out.fixed64(1, half(&bytes[..8]))
        .fixed64(2, half(&bytes[8..]));
}

fn decode_tuid(bytes: &[u8]) -> Result<u128, WireError> {
    let (mut high, mut low) = (None, None);
    let mut fields = FieldReader::new(bytes);
    while let Some(field) = fields.next_field()? {
        match field.number {
            1 => high = Some(field.fixed64("Tuid")?),
            2 => low = Some(field.fixed64("Tuid")?),
            _ => {}
        }
    }
    match (high, low) {
        (Some(high), Some(low)) => Ok((u128::from(high) << 64) | u128::from(low)),
        _ => Err((
            0,
            RrdErrorKind::MissingField {
                message: "Tuid",
                field: "time_ns/inc",
            },
        )),
    }
}

/// How an `ArrowMsg`'s payload is compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Compression {
    None,
    Lz4,
}

/// A decoded `ArrowMsg`, its payload still encoded: the range of the message body that
/// holds it, so that the caller can slice it without a copy.
#[derive(Debug, Clone)]
pub(crate) struct ArrowMsg {
    pub(crate) store_id: StoreId,
    pub(crate) chunk_id: Option<ChunkId>,
    pub(crate) compression: Compression,
    pub(crate) uncompressed_size: u64,
    pub(crate) payload: std::ops::Range<usize>,
    pub(crate) is_static: Option<bool>,
}

impl ArrowMsg {
    pub(crate) fn decode(bytes: &[u8]) -> Result<Self, WireError> {
        let mut store_id = None;
        let mut chunk_id = None;
        let mut compression = None;
        let mut uncompressed_size = 0;
        let mut encoding = 0;
        let mut payload = None;
        let mut is_static = None;
        let mut fields = FieldReader::new(bytes);
        while let Some(field) = fields.next_field()? {
            let base = field.value_start;
            match field.number {
                1 => {
                    store_id = Some(field.nested("ArrowMsg", StoreId::decode)?);
                }
                2 => {
                    compression = Some(match field.varint("ArrowMsg")? {
                        0 | 1 => Compression::None,
                        2 => Compression::Lz4,
                        other => {
                            return Err((
                                base,
                                RrdErrorKind::Payload {
                                    reason: format!("unknown compression {other}"),
                                },
                            ));
                        }
                    });
                }
                3 => uncompressed_size = field.varint("ArrowMsg")?,
                4 => encoding = field.varint("ArrowMsg")?,
                5 => {
                    let len = field.bytes("ArrowMsg")?.len();
                    payload = Some(base..base + len);
                }
                6 => {
                    let id = field.nested("ArrowMsg", decode_tuid)?;
                    chunk_id = Some(ChunkId::from_u128(id));
                }
                7 => is_static = Some(field.varint("ArrowMsg")? != 0),
                _ => {}
            }
        }
        if encoding != 1 {
            return Err((
                0,
                RrdErrorKind::Payload {
                    reason: format!("unknown payload encoding {encoding} (Arrow IPC is 1)"),
                },
            ));
        }
        let missing = |field| {
            (
                0,
                RrdErrorKind::MissingField {
                    message: "ArrowMsg",
                    field,
                },
            )
        };
        Ok(Self {
            store_id: store_id.ok_or_else(|| missing("store_id"))?,
            chunk_id,
            compression: compression.unwrap_or(Compression::None),
            uncompressed_size,
            payload: payload.ok_or_else(|| missing("payload"))?,
            is_static,
        })
    }

    /// Encodes an `ArrowMsg` body around an already encoded (and maybe compressed) payload.
    pub(crate) fn encode(
        store_id: &StoreId,
        chunk_id: ChunkId,
        is_static: bool,
        compression: Compression,
        uncompressed_size: u64,
        payload: &[u8],
    ) -> Vec<u8> {
        let mut out = FieldWriter::default();
        out.message(1, |id| store_id.encode(id))
            .varint(
                2,
                match compression {
                    Compression::None => 1,
                    Compression::Lz4 => 2,
                },
            )
            .varint(3, uncompressed_size)
            .varint(4, 1)
            .bytes(5, payload)
            .message(6, |tuid| encode_tuid(tuid, chunk_id.as_u128()))
            .varint(7, u64::from(is_static));
        out.bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn store_info_and_arrow_msg_round_trip() {
        let info = StoreInfo::new(StoreId::recording("app", "rec"));
        let bytes = info.encode_set_store_info(42);
        assert_eq!(StoreInfo::decode_set_store_info(&bytes).unwrap(), info);

        let id = ChunkId::new();
        let body = ArrowMsg::encode(&info.store_id, id, true, Compression::Lz4, 9, b"xyz");
        let msg = ArrowMsg::decode(&body).unwrap();
        assert_eq!(msg.store_id, info.store_id);
        assert_eq!(msg.chunk_id, Some(id));
        assert_eq!(msg.compression, Compression::Lz4);
        assert_eq!(msg.uncompressed_size, 9);
        assert_eq!(msg.is_static, Some(true));
        assert_eq!(&body[msg.payload], b"xyz");
    }

    #[test]
    fn store_ids_decode_by_their_own_bytes_whatever_came_before() {
        let encoded = |id: &StoreId| {
            let mut out = FieldWriter::default();
            id.encode(&mut out);
            out.bytes
        };
        let a = StoreId::recording("app", "rec-a");
        let b = StoreId {
            kind: StoreKind::Blueprint,
            ..StoreId::recording("app", "rec-b")
        };
        for id in [&a, &a, &b, &a, &b, &b] {
            assert_eq!(StoreId::decode(&encoded(id)).unwrap(), *id);
        }
        // A message that fails is never the kept one.
        assert!(StoreId::decode(&[0x12, 0x05, b'x']).is_err());
        assert_eq!(StoreId::decode(&encoded(&b)).unwrap(), b);
    }

    #[test]
    fn unknown_fields_are_skipped() {
        let info = StoreInfo::new(StoreId::recording("app", "rec"));
        let mut bytes = info.encode_set_store_info(1);
        let mut extra = FieldWriter::default();
        extra.varint(99, 5).bytes(100, b"future");
        bytes.extend_from_slice(&extra.bytes);
        assert_eq!(StoreInfo::decode_set_store_info(&bytes).unwrap(), info);
    }
}
