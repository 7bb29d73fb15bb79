//! [`LogMsg`]: one message of Rerun's log stream, in the two envelopes it travels in: the
//! gRPC `LogMsg` of Rerun's proxy protocol (what an SDK sends a server) and an `.rrd`
//! frame (what a file stores). The body is the same bytes in both, so a server can persist
//! what it received without re-encoding it and replay a file as it was sent.
//!
//! On the wire (protocol `rerun.sdk_comms.v1alpha1`), `WriteMessagesRequest` and
//! `ReadMessagesResponse` are both `{ LogMsg log_msg = 1; }`, and `LogMsg` is a oneof whose
//! field numbers are the `.rrd` message kinds: `1` `SetStoreInfo`, `2` `ArrowMsg`, `3`
//! `BlueprintActivationCommand`. `docs/SERVER.md` has the bytes.

use arrow_buffer::Buffer;

use super::error::{RrdError, RrdErrorKind};
use super::frames::{
    self, MESSAGE_HEADER_LEN, MessageKind, STREAM_FOOTER_LEN, STREAM_HEADER_LEN, StreamFooter,
    StreamHeader,
};
use super::messages::{ArrowMsg, StoreId, StoreInfo, StoreKind};
use super::payload;
use super::protobuf::{FieldReader, FieldWriter};
use crate::Chunk;

/// Which message a [`LogMsg`] is: the `LogMsg` oneof's field number, which is also the
/// message's kind in an `.rrd` frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LogMsgKind {
    /// A store's description (`SetStoreInfo`).
    SetStoreInfo,
    /// A chunk of a recording or a blueprint (`ArrowMsg`).
    ArrowMsg,
    /// Which blueprint a viewer should show (`BlueprintActivationCommand`).
    BlueprintActivationCommand,
}

impl LogMsgKind {
    fn from_number(number: u64) -> Option<Self> {
        match MessageKind::from_u64(number)? {
            MessageKind::SetStoreInfo => Some(Self::SetStoreInfo),
            MessageKind::ArrowMsg => Some(Self::ArrowMsg),
            MessageKind::BlueprintActivationCommand => Some(Self::BlueprintActivationCommand),
            MessageKind::End => None,
        }
    }

    fn frame_kind(self) -> MessageKind {
        match self {
            Self::SetStoreInfo => MessageKind::SetStoreInfo,
            Self::ArrowMsg => MessageKind::ArrowMsg,
            Self::BlueprintActivationCommand => MessageKind::BlueprintActivationCommand,
        }
    }

    fn number(self) -> u32 {
        match self {
            Self::SetStoreInfo => 1,
            Self::ArrowMsg => 2,
            Self::BlueprintActivationCommand => 3,
        }
    }
}

/// One message of Rerun's log stream: its kind and its encoded body, cheap to clone (the
/// body is a shared buffer).
///
/// ```
/// # use std::sync::Arc;
/// # use arrow_array::{ArrayRef, Float64Array};
/// use chunkstore::*;
/// use chunkstore::rrd::{DecodedLogMsg, LogMsg, StoreId};
/// let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/e")?)
///     .with_row(RowId::new(), [(Timeline::sequence("frame"), 1)],
///               [("x", Arc::new(Float64Array::from(vec![1.0])) as ArrayRef)])
///     .build()?;
/// let store = StoreId::recording("app", "rec");
/// let msg = LogMsg::from_chunk(&store, &chunk, true)?;
/// // What an SDK sends in a `WriteMessagesRequest`, and back.
/// let wire = msg.encode_envelope();
/// let back = LogMsg::decode_envelope(&arrow_buffer::Buffer::from(wire))?;
/// match back.decode()? {
///     DecodedLogMsg::Chunk { store_id, chunk: decoded } => {
///         assert_eq!(store_id, store);
///         assert_eq!(decoded.id(), chunk.id());
///     }
///     other => panic!("{other:?}"),
/// }
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogMsg {
    kind: LogMsgKind,
    body: Buffer,
}

/// What a [`LogMsg`] says, decoded.
#[derive(Debug)]
#[non_exhaustive]
#[expect(
    clippy::large_enum_variant,
    reason = "chunks are the common message, and each is moved once"
)]
pub enum DecodedLogMsg {
    /// A store's description.
    StoreInfo(StoreInfo),
    /// A chunk of a recording.
    Chunk {
        /// The recording.
        store_id: StoreId,
        /// The chunk, validated.
        chunk: Chunk,
    },
    /// A chunk of a blueprint (a viewer layout), left encoded: never data.
    BlueprintChunk {
        /// The blueprint's store.
        store_id: StoreId,
    },
    /// A `BlueprintActivationCommand`, left encoded.
    BlueprintActivation,
}

impl LogMsg {
    /// A message of `kind` with the encoded `body` (an `.rrd` message body).
    pub fn new(kind: LogMsgKind, body: Buffer) -> Self {
        Self { kind, body }
    }

    /// The message's kind.
    pub fn kind(&self) -> LogMsgKind {
        self.kind
    }

    /// The encoded body: the bytes after an `.rrd` frame header, or inside the gRPC oneof.
    pub fn body(&self) -> &Buffer {
        &self.body
    }

    /// About how many bytes the message holds once decoded: an `ArrowMsg`'s payload
    /// size before compression, as its header claims (at most what LZ4 can expand the
    /// body to, since the claim is the sender's), else the body's length. For a server
    /// that must count what its stores grow by, not what came over the wire.
    ///
    /// ```
    /// # use std::sync::Arc;
    /// # use arrow_array::{ArrayRef, Float64Array};
    /// use chunkstore::*;
    /// use chunkstore::rrd::{LogMsg, StoreId};
    /// let zeros = Arc::new(Float64Array::from(vec![0.0; 10_000])) as ArrayRef;
    /// let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/e")?)
    ///     .with_row(RowId::new(), [(Timeline::sequence("frame"), 1)], [("x", zeros)])
    ///     .build()?;
    /// let msg = LogMsg::from_chunk(&StoreId::recording("app", "rec"), &chunk, true)?;
    /// assert!(msg.decoded_len() > 80_000 && msg.body().len() < 10_000);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn decoded_len(&self) -> u64 {
        let body = self.body.len() as u64;
        if self.kind != LogMsgKind::ArrowMsg {
            return body;
        }
        match ArrowMsg::decode(self.body.as_slice()) {
            // LZ4 expands a byte to at most 255.
            Ok(msg) => msg.uncompressed_size.clamp(body, body.saturating_mul(255)),
            Err(_) => body, // refused when it is ingested
        }
    }

    /// A `SetStoreInfo` for `info`, under a fresh message id.
    pub fn from_store_info(info: &StoreInfo) -> Self {
        let body = info.encode_set_store_info(crate::RowId::new().as_u128());
        Self::new(LogMsgKind::SetStoreInfo, Buffer::from(body))
    }

    /// An `ArrowMsg` carrying `chunk` of `store_id`, its payload LZ4-compressed if
    /// `compress` (as Rerun's SDK sends it).
    ///
    /// # Errors
    /// If the chunk cannot be encoded as Arrow IPC.
    pub fn from_chunk(store_id: &StoreId, chunk: &Chunk, compress: bool) -> Result<Self, RrdError> {
        let (body, _) = payload::encode_arrow_msg(store_id, chunk, compress)
            .map_err(|e| RrdError::new(0, RrdErrorKind::Ipc(e)))?;
        Ok(Self::new(LogMsgKind::ArrowMsg, Buffer::from(body)))
    }

    /// Reads a gRPC `LogMsg` (the oneof itself). The body is a slice of `bytes`, not a
    /// copy. Exactly one of the three fields must be set; unknown fields are refused too,
    /// since a oneof member this crate does not know is a message it cannot honour.
    ///
    /// # Errors
    /// [`RrdErrorKind::Protobuf`] for malformed bytes, [`RrdErrorKind::UnknownMessageKind`]
    /// for a oneof member other than the three, [`RrdErrorKind::MissingField`] for none.
    pub fn decode_protobuf(bytes: &Buffer) -> Result<Self, RrdError> {
        let mut found = None;
        let mut fields = FieldReader::new(bytes.as_slice());
        while let Some(field) = fields.next_field().map_err(at_offset)? {
            let Some(kind) = LogMsgKind::from_number(u64::from(field.number)) else {
                return Err(RrdError::new(
                    0,
                    RrdErrorKind::UnknownMessageKind {
                        kind: u64::from(field.number),
                    },
                ));
            };
            let body = field.bytes("LogMsg").map_err(at_offset)?;
            if found.is_some() {
                return Err(RrdError::new(
                    field.value_start as u64,
                    RrdErrorKind::Protobuf {
                        reason: "LogMsg: more than one member of its oneof is set".to_owned(),
                    },
                ));
            }
            found = Some(Self::new(
                kind,
                bytes.slice_with_length(field.value_start, body.len()),
            ));
        }
        found.ok_or_else(|| {
            RrdError::new(
                0,
                RrdErrorKind::MissingField {
                    message: "LogMsg",
                    field: "msg",
                },
            )
        })
    }

    /// Writes the gRPC `LogMsg` (the oneof itself).
    pub fn encode_protobuf(&self) -> Vec<u8> {
        let mut out = FieldWriter::default();
        out.bytes(self.kind.number(), self.body.as_slice());
        out.bytes
    }

    /// Reads the envelope both `WriteMessagesRequest` and `ReadMessagesResponse` are: `{
    /// LogMsg log_msg = 1; }`. Unknown fields of the envelope are skipped.
    ///
    /// # Errors
    /// As [`LogMsg::decode_protobuf`], and [`RrdErrorKind::MissingField`] for an envelope
    /// without its message.
    pub fn decode_envelope(bytes: &Buffer) -> Result<Self, RrdError> {
        let mut inner = None;
        let mut fields = FieldReader::new(bytes.as_slice());
        while let Some(field) = fields.next_field().map_err(at_offset)? {
            if field.number == 1 {
                let msg = field.bytes("WriteMessagesRequest").map_err(at_offset)?;
                inner = Some(bytes.slice_with_length(field.value_start, msg.len()));
            }
        }
        let inner = inner.ok_or_else(|| {
            RrdError::new(
                0,
                RrdErrorKind::MissingField {
                    message: "WriteMessagesRequest",
                    field: "log_msg",
                },
            )
        })?;
        Self::decode_protobuf(&inner)
    }

    /// Writes the envelope `{ LogMsg log_msg = 1; }` around this message.
    pub fn encode_envelope(&self) -> Vec<u8> {
        let mut out = FieldWriter::default();
        out.bytes(1, &self.encode_protobuf());
        out.bytes
    }

    /// The store this message belongs to, read from its body without decoding a payload;
    /// `None` for a blueprint activation (which names a blueprint, not a data store).
    ///
    /// # Errors
    /// If the body is not the message its kind says.
    pub fn store_id(&self) -> Result<Option<StoreId>, RrdError> {
        let bytes = self.body.as_slice();
        match self.kind {
            LogMsgKind::SetStoreInfo => StoreInfo::decode_set_store_info(bytes)
                .map(|info| Some(info.store_id))
                .map_err(at_offset),
            LogMsgKind::ArrowMsg => ArrowMsg::decode(bytes)
                .map(|msg| Some(msg.store_id))
                .map_err(at_offset),
            LogMsgKind::BlueprintActivationCommand => Ok(None),
        }
    }

    /// Decodes the body: a store info, or a recording's chunk (decompressed, decoded and
    /// validated as a chunk read from a file is); blueprint messages stay encoded.
    ///
    /// # Errors
    /// Whatever a file's message of the same bytes would fail with; offsets count from the
    /// body's start.
    pub fn decode(&self) -> Result<DecodedLogMsg, RrdError> {
        let bytes = self.body.as_slice();
        match self.kind {
            LogMsgKind::SetStoreInfo => StoreInfo::decode_set_store_info(bytes)
                .map(DecodedLogMsg::StoreInfo)
                .map_err(at_offset),
            LogMsgKind::ArrowMsg => {
                let msg = ArrowMsg::decode(bytes).map_err(at_offset)?;
                if msg.store_id.kind != StoreKind::Recording {
                    return Ok(DecodedLogMsg::BlueprintChunk {
                        store_id: msg.store_id,
                    });
                }
                Ok(DecodedLogMsg::Chunk {
                    chunk: self.payload_chunk(&msg)?,
                    store_id: msg.store_id,
                })
            }
            LogMsgKind::BlueprintActivationCommand => Ok(DecodedLogMsg::BlueprintActivation),
        }
    }

    /// The chunk an `ArrowMsg` carries, whatever its store's kind: for a hub that keeps a
    /// blueprint's latest state instead of every message that built it.
    ///
    /// # Errors
    /// As [`LogMsg::decode`]; a message of another kind is a [`RrdErrorKind::Protobuf`].
    pub(crate) fn decode_any_chunk(&self) -> Result<(StoreId, Chunk), RrdError> {
        if self.kind != LogMsgKind::ArrowMsg {
            return Err(RrdError::new(
                0,
                RrdErrorKind::Protobuf {
                    reason: format!("a {:?} message carries no chunk", self.kind),
                },
            ));
        }
        let msg = ArrowMsg::decode(self.body.as_slice()).map_err(at_offset)?;
        Ok((msg.store_id.clone(), self.payload_chunk(&msg)?))
    }

    /// The chunk in the payload of `msg`, this message's `ArrowMsg` header: decompressed,
    /// decoded and validated as a chunk read from a file is.
    fn payload_chunk(&self, msg: &ArrowMsg) -> Result<Chunk, RrdError> {
        let payload = payload::PayloadBytes::Shared(
            self.body
                .slice_with_length(msg.payload.start, msg.payload.len()),
        );
        payload::decode_message_chunk(msg, payload, 0)
    }

    /// The blueprint a `BlueprintActivationCommand` names (its field 1); `None` for any
    /// other message, or a command without a readable id.
    pub(crate) fn activated_blueprint(&self) -> Option<StoreId> {
        if self.kind != LogMsgKind::BlueprintActivationCommand {
            return None;
        }
        let mut fields = FieldReader::new(self.body.as_slice());
        let mut id = None;
        while let Ok(Some(field)) = fields.next_field() {
            if field.number == 1 {
                id = field
                    .nested("BlueprintActivationCommand", StoreId::decode)
                    .ok();
            }
        }
        id
    }

    /// The message as an `.rrd` frame: its 16-byte header, then the body. Appending frames
    /// after a stream header ([`log_stream_header`]) makes an `.rrd` stream without a
    /// footer, which this crate and Rerun's tools read.
    pub fn frame_header(&self) -> [u8; MESSAGE_HEADER_LEN] {
        frames::encode_message_header(self.kind.frame_kind(), self.body.len() as u64)
    }
}

/// The 12 bytes that start an `.rrd` stream, as this crate writes them.
pub fn log_stream_header() -> [u8; STREAM_HEADER_LEN] {
    StreamHeader {
        version: frames::WRITTEN_VERSION,
        compressed: true,
    }
    .encode()
}

fn at_offset((offset, kind): (usize, RrdErrorKind)) -> RrdError {
    RrdError::new(offset as u64, kind)
}

/// What [`scan_log`] found in an `.rrd` log: its messages in order, and how far the bytes
/// hold whole messages.
#[derive(Debug)]
#[non_exhaustive]
pub struct LogScan {
    /// Every message of every stream, in order (`End` messages and footers left out).
    pub messages: Vec<LogMsg>,
    /// Bytes that hold whole streams and messages: where the next message belongs. Less
    /// than the input's length when its tail is torn.
    pub valid_len: u64,
    /// The last stream is still open (no `End` message): more messages may follow it
    /// directly. When it is closed, new messages need a new stream header first.
    pub open_stream: bool,
    /// Why the scan stopped before the end: a truncated stream header, message header or
    /// body (a torn tail), or bytes that are not `.rrd` framing.
    pub fault: Option<RrdError>,
    torn_tail: bool,
}

impl LogScan {
    /// The scan stopped at a torn tail (a write cut short), which dropping the bytes past
    /// [`LogScan::valid_len`] repairs.
    ///
    /// A tail is torn only when it can be one: the last frame runs past the end of the
    /// input, its kind is known and what there is of its body is the start of a message of
    /// the length its header claims (or the rest of the input is zeros, space a file
    /// system gave the file but the write never filled). A length damaged in the middle of
    /// a log also runs past the end, but its body is followed by the next frame, which is
    /// not the rest of one message: that, and every other fault, means that bytes past the
    /// fault hold messages, and dropping them would lose them.
    pub fn is_torn_tail(&self) -> bool {
        self.fault.is_some() && self.torn_tail
    }
}

/// `bytes` without the zeros they end with.
fn without_trailing_zeros(bytes: &[u8]) -> &[u8] {
    let end = bytes.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
    &bytes[..end]
}

/// Could `rest` (where a stream header belongs) be one cut short: its magic as far as it
/// goes, then zeros or the end?
fn stream_header_cut_short(rest: &[u8]) -> bool {
    let written = without_trailing_zeros(rest);
    let magic = written.len().min(4);
    written.len() < STREAM_HEADER_LEN && written[..magic] == frames::MAGIC[..magic]
}

/// Could `rest` (fewer bytes than a message header) be one cut short: its kind, if all
/// there, one there is?
fn message_header_cut_short(rest: &[u8]) -> bool {
    rest.get(..8).is_none_or(|kind| {
        let mut le = [0u8; 8];
        le.copy_from_slice(kind);
        MessageKind::from_u64(u64::from_le_bytes(le)).is_some()
    })
}

/// Could `rest` (to the end of the input) be the start of a body of `len` bytes, a
/// message of `kind` cut short? Zeros at the end were never written: what matters is what
/// was.
fn body_cut_short(kind: u64, rest: &[u8], len: u64) -> bool {
    MessageKind::from_u64(kind).is_some()
        && super::protobuf::could_start_message_of(without_trailing_zeros(rest), len)
}

/// Zeros to the end where a stream or a message should start: never written.
fn zero_tail(data: &[u8], at: usize) -> Option<RrdError> {
    let rest = &data[at..];
    let len = rest.len() as u64;
    rest.iter()
        .all(|&b| b == 0)
        .then(|| RrdError::new(at as u64, RrdErrorKind::ZeroTail { len }))
}

/// Is the whole frame body at `body_at` not a whole message? A damaged length makes it end
/// inside a field or run into the next frame. Unless all from there on is zeros (a write
/// cut short), that is damage: the fault, and whether it is a torn tail.
fn damaged_body(data: &[u8], body_at: usize, body_len: usize) -> Option<(RrdError, bool)> {
    let bad = super::protobuf::whole_message(&data[body_at..body_at + body_len]).err()?;
    let torn = data[body_at + bad..].iter().all(|&b| b == 0);
    let reason = "the message's fields do not end where its frame says it ends: its length \
                  or its fields are damaged"
        .to_owned();
    let fault = RrdError::new((body_at + bad) as u64, RrdErrorKind::Protobuf { reason });
    Some((fault, torn))
}

/// Where the bytes after an `End` message at `at` leave off: past its stream footer if one
/// is there, or `None` when fewer bytes than a footer follow, then zeros or nothing, and
/// not the next stream (a footer cut short).
fn past_stream_end(data: &[u8], mut at: usize) -> Option<usize> {
    if let Some(tail) = data.get(at..at + STREAM_FOOTER_LEN) {
        let mut footer = [0u8; STREAM_FOOTER_LEN];
        footer.copy_from_slice(tail);
        if StreamFooter::parse(&footer).is_some() {
            at += STREAM_FOOTER_LEN;
        }
    }
    let rest = &data[at..];
    let cut_short = !rest.is_empty()
        && !rest.starts_with(&frames::MAGIC)
        && without_trailing_zeros(rest).len() < STREAM_FOOTER_LEN;
    (!cut_short).then_some(at)
}

impl LogScan {
    /// Ends the scan at `fault`, a torn tail or not.
    fn stop(mut self, fault: RrdError, torn_tail: bool) -> Self {
        self.fault = Some(fault);
        self.torn_tail = torn_tail;
        self
    }
}

/// Splits `.rrd` bytes into their messages without decoding any body: one or several
/// concatenated streams, each with or without an `End` message and stream footer (a log
/// appended to as messages arrive has neither). Never allocates more than the input
/// holds; bodies are slices of `bytes`. [`LogScan::is_torn_tail`] tells a write cut short
/// from damage.
pub fn scan_log(bytes: &Buffer) -> LogScan {
    let mut scan = LogScan {
        messages: Vec::new(),
        valid_len: 0,
        open_stream: false,
        fault: None,
        torn_tail: false,
    };
    let data = bytes.as_slice();
    let len = data.len();
    let mut at = 0usize;
    let truncated = |at: usize, what: &'static str, needed: u64| {
        let available = (len - at) as u64;
        RrdError::new(
            at as u64,
            RrdErrorKind::Truncated {
                what,
                needed,
                available,
            },
        )
    };
    'streams: while at < len {
        if let Some(fault) = zero_tail(data, at) {
            return scan.stop(fault, true);
        }
        let Some(header) = data.get(at..at + STREAM_HEADER_LEN) else {
            let fault = truncated(at, "stream header", STREAM_HEADER_LEN as u64);
            return scan.stop(fault, stream_header_cut_short(&data[at..]));
        };
        let mut header_bytes = [0u8; STREAM_HEADER_LEN];
        header_bytes.copy_from_slice(header);
        if let Err(kind) = StreamHeader::parse(&header_bytes) {
            let torn = stream_header_cut_short(&data[at..]);
            return scan.stop(RrdError::new(at as u64, kind), torn);
        }
        at += STREAM_HEADER_LEN;
        scan.valid_len = at as u64;
        scan.open_stream = true;
        while at < len {
            if let Some(fault) = zero_tail(data, at) {
                return scan.stop(fault, true);
            }
            let Some(header) = data.get(at..at + MESSAGE_HEADER_LEN) else {
                let fault = truncated(at, "message header", MESSAGE_HEADER_LEN as u64);
                return scan.stop(fault, message_header_cut_short(&data[at..]));
            };
            let mut header_bytes = [0u8; MESSAGE_HEADER_LEN];
            header_bytes.copy_from_slice(header);
            let (kind, body_len) = frames::parse_message_header(&header_bytes);
            let body_at = at + MESSAGE_HEADER_LEN;
            let Some(body_len) = usize::try_from(body_len)
                .ok()
                .filter(|&n| n <= len - body_at)
            else {
                let torn = body_cut_short(kind, &data[body_at..], body_len);
                return scan.stop(truncated(body_at, "message body", body_len), torn);
            };
            if let Some((fault, torn)) = damaged_body(data, body_at, body_len) {
                return scan.stop(fault, torn);
            }
            at = body_at + body_len;
            let kind = match MessageKind::from_u64(kind) {
                Some(MessageKind::End) => {
                    scan.open_stream = false;
                    let Some(past) = past_stream_end(data, at) else {
                        scan.valid_len = at as u64;
                        let fault = truncated(at, "stream footer", STREAM_FOOTER_LEN as u64);
                        return scan.stop(fault, true);
                    };
                    at = past;
                    scan.valid_len = at as u64;
                    continue 'streams;
                }
                Some(MessageKind::SetStoreInfo) => LogMsgKind::SetStoreInfo,
                Some(MessageKind::ArrowMsg) => LogMsgKind::ArrowMsg,
                Some(MessageKind::BlueprintActivationCommand) => {
                    LogMsgKind::BlueprintActivationCommand
                }
                None => {
                    let at = (body_at - MESSAGE_HEADER_LEN) as u64;
                    return scan.stop(
                        RrdError::new(at, RrdErrorKind::UnknownMessageKind { kind }),
                        false,
                    );
                }
            };
            scan.messages.push(LogMsg::new(
                kind,
                bytes.slice_with_length(body_at, body_len),
            ));
            scan.valid_len = at as u64;
        }
    }
    scan
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;

    #[test]
    fn envelope_round_trips_and_hostile_envelopes_are_errors() {
        let info = StoreInfo::new(StoreId::recording("app", "rec"));
        let msg = LogMsg::from_store_info(&info);
        let wire = Buffer::from(msg.encode_envelope());
        let back = LogMsg::decode_envelope(&wire).unwrap();
        assert_eq!(back, msg);
        assert!(matches!(back.decode().unwrap(), DecodedLogMsg::StoreInfo(i) if i == info));

        // An empty envelope, an unknown oneof member, two members.
        let empty = LogMsg::decode_envelope(&Buffer::from(Vec::<u8>::new())).unwrap_err();
        assert!(
            matches!(empty.kind, RrdErrorKind::MissingField { .. }),
            "{empty}"
        );
        let mut unknown = FieldWriter::default();
        unknown.message(1, |m| {
            m.bytes(9, b"x");
        });
        let err = LogMsg::decode_envelope(&Buffer::from(unknown.bytes)).unwrap_err();
        assert!(
            matches!(err.kind, RrdErrorKind::UnknownMessageKind { kind: 9 }),
            "{err}"
        );
        let mut two = FieldWriter::default();
        two.message(1, |m| {
            m.bytes(1, b"").bytes(3, b"");
        });
        let err = LogMsg::decode_envelope(&Buffer::from(two.bytes)).unwrap_err();
        assert!(err.to_string().contains("more than one"), "{err}");
        // A length past the end.
        let err = LogMsg::decode_envelope(&Buffer::from(vec![0x0a, 0x7f, 0x0a])).unwrap_err();
        assert!(matches!(err.kind, RrdErrorKind::Protobuf { .. }), "{err}");
    }

    #[test]
    fn scan_splits_streams_and_finds_a_torn_tail() {
        let info = StoreInfo::new(StoreId::recording("app", "rec"));
        let msg = LogMsg::from_store_info(&info);
        let mut log = log_stream_header().to_vec();
        for _ in 0..3 {
            log.extend_from_slice(&msg.frame_header());
            log.extend_from_slice(msg.body().as_slice());
        }
        let whole = log.len();
        let scan = scan_log(&Buffer::from(log.clone()));
        assert_eq!(scan.messages.len(), 3);
        assert_eq!(scan.valid_len, whole as u64);
        assert!(scan.open_stream && scan.fault.is_none());

        // Every cut inside the last message keeps the first two and says where to cut.
        let last_start = whole - msg.body().len() - MESSAGE_HEADER_LEN;
        for cut in last_start + 1..whole {
            let scan = scan_log(&Buffer::from(log[..cut].to_vec()));
            assert_eq!(scan.messages.len(), 2, "cut at {cut}");
            assert_eq!(scan.valid_len, last_start as u64);
            assert!(scan.is_torn_tail(), "cut at {cut}");
        }

        // A file written by the crate's writer (End message and footer), then a log
        // appended after it: both streams' messages, in order.
        let mut file = Vec::new();
        let writer = crate::rrd::RrdWriter::with_store_info(&mut file, &info, true).unwrap();
        writer.finish().unwrap();
        let closed = scan_log(&Buffer::from(file.clone()));
        assert!(!closed.open_stream && closed.fault.is_none());
        assert_eq!(closed.valid_len, file.len() as u64);
        // Its footer cut short is a torn tail, not garbage.
        let cut = scan_log(&Buffer::from(file[..file.len() - 5].to_vec()));
        assert!(cut.is_torn_tail(), "{:?}", cut.fault);
        assert_eq!(cut.valid_len, (file.len() - STREAM_FOOTER_LEN) as u64);
        assert!(!cut.open_stream);
        file.extend_from_slice(&log);
        let both = scan_log(&Buffer::from(file.clone()));
        assert_eq!(both.messages.len(), closed.messages.len() + 3);
        assert!(both.open_stream && both.fault.is_none());

        // Garbage is not a torn tail.
        let scan = scan_log(&Buffer::from(b"not an rrd file at all".to_vec()));
        assert!(scan.fault.is_some() && !scan.is_torn_tail());
        assert_eq!(scan.valid_len, 0);
    }

    #[test]
    fn chunk_messages_decode_and_blueprints_stay_encoded() {
        use arrow_array::{ArrayRef, Float64Array};
        let chunk = crate::ChunkBuilder::new(
            crate::ChunkId::new(),
            crate::EntityPath::parse("/e").unwrap(),
        )
        .with_row(
            crate::RowId::new(),
            [(crate::Timeline::sequence("frame"), 1)],
            [("x", Arc::new(Float64Array::from(vec![1.0])) as ArrayRef)],
        )
        .build()
        .unwrap();
        let mut blueprint = StoreId::recording("app", "bp");
        blueprint.kind = StoreKind::Blueprint;
        let msg = LogMsg::from_chunk(&blueprint, &chunk, false).unwrap();
        assert!(matches!(
            msg.decode().unwrap(),
            DecodedLogMsg::BlueprintChunk { .. }
        ));
        assert_eq!(msg.store_id().unwrap(), Some(blueprint));

        // A corrupted payload is an error of that message.
        let msg = LogMsg::from_chunk(&StoreId::recording("a", "r"), &chunk, true).unwrap();
        let mut bytes = msg.body().as_slice().to_vec();
        let n = bytes.len();
        bytes[n - 30..n - 20].fill(0xff);
        let bad = LogMsg::new(LogMsgKind::ArrowMsg, Buffer::from(bytes));
        assert!(bad.decode().is_err());
    }
}
