//! [`RrdReader`]: a streaming decoder of `.rrd` files and streams, yielding store infos,
//! chunks and the footer's manifests in stream order.

use std::io::Read;

use arrow_buffer::Buffer;

use super::error::{RrdError, RrdErrorKind};
use super::frames::{
    self, MESSAGE_HEADER_LEN, MessageKind, STREAM_FOOTER_LEN, STREAM_HEADER_LEN, StreamFooter,
    StreamHeader,
};
use super::manifest::{self, Manifest};
use super::messages::{ArrowMsg, StoreId, StoreInfo, StoreKind};
use super::payload;
use crate::{Chunk, ChunkId};

/// How many `ArrowMsg`s of an input buffer are decoded together, a phase at a time.
const RUN_MESSAGES: usize = 64;

/// A message body larger than this is decoded on its own: a run is for small chunks,
/// whose decoding is bound by its code (a large one's by its data), and a run holds all
/// its decoded payloads at once.
const RUN_MESSAGE_BYTES: usize = 64 * 1024;

/// The most decompressed payload bytes (as their messages claim) a run decodes at once.
const RUN_DECODED_BYTES: u64 = 1 << 20;

/// A message of a run between phases: its protobuf with its payload (after LZ4, its IPC
/// stream), `None` for a blueprint's, or the error that ends its decoding.
type RunMessage = Result<Option<(ArrowMsg, Buffer)>, RrdError>;

#[cfg(test)]
thread_local! {
    /// Messages this thread decoded in runs (for tests).
    static RUN_DECODED: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// What an `.rrd` stream holds, item by item.
#[derive(Debug)]
#[non_exhaustive]
#[expect(
    clippy::large_enum_variant,
    reason = "chunks are the common item, and each item is moved once"
)]
pub enum RrdItem {
    /// A store's description.
    StoreInfo(StoreInfo),
    /// A chunk of a recording.
    Chunk {
        /// The recording.
        store_id: StoreId,
        /// The chunk.
        chunk: Chunk,
        /// Where its message's body starts in the input.
        offset: u64,
    },
    /// A message of a blueprint (a viewer layout): skipped, never mixed into the data.
    SkippedBlueprint {
        /// Where the message's body starts.
        offset: u64,
    },
    /// The footer's manifests (one per recording), where the stream has a footer.
    Footer(Vec<Manifest>),
}

/// Where the bytes come from: a reader, or a buffer already in memory (whose payloads are
/// then decoded without a copy).
enum Input<R> {
    Stream(R),
    Buffer(Buffer),
}

/// A message body: a slice of the input buffer (payloads are then shared, not copied), or
/// the reader's scratch vector (reused from message to message: a compressed payload is
/// decompressed straight out of it, so a streamed file allocates once per chunk).
enum Body {
    Shared(Buffer),
    Scratch(Vec<u8>),
}

impl Body {
    fn as_slice(&self) -> &[u8] {
        match self {
            Self::Shared(buffer) => buffer.as_slice(),
            Self::Scratch(bytes) => bytes,
        }
    }
}

/// A streaming `.rrd` decoder.
///
/// Iterating yields [`RrdItem`]s in stream order, each or an [`RrdError`] naming the byte
/// offset of the fault. An error in one message's payload (corrupt LZ4, bad protobuf, a
/// batch that is not a chunk) spoils only that message: iteration goes on with the next
/// (stop at the first error to be strict). An error in the framing (truncation, a bad
/// header) ends the iteration: what follows cannot be found.
///
/// ```
/// # use chunkstore::*;
/// # use chunkstore::rrd::{RrdItem, RrdReader, RrdWriter, StoreId};
/// # use arrow_array::{ArrayRef, Float64Array};
/// # use std::sync::Arc;
/// let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/e").unwrap())
///     .with_row(RowId::new(), [(Timeline::sequence("frame"), 1)],
///               [("x", Arc::new(Float64Array::from(vec![1.0])) as ArrayRef)])
///     .build()?;
/// let mut file = Vec::new();
/// let mut writer = RrdWriter::new(&mut file, StoreId::recording("app", "rec"))?;
/// writer.write_chunk(&Arc::new(chunk))?;
/// writer.finish()?;
///
/// let chunks: Vec<Chunk> = RrdReader::new(file.as_slice())?
///     .filter_map(|item| match item {
///         Ok(RrdItem::Chunk { chunk, .. }) => Some(Ok(chunk)),
///         Ok(_) => None,
///         Err(e) => Some(Err(e)),
///     })
///     .collect::<Result<_, _>>()?;
/// assert_eq!(chunks.len(), 1);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct RrdReader<R> {
    input: Input<R>,
    /// Bytes read back (a peek that was not a stream footer), consumed before the input.
    pushback: Vec<u8>,
    position: u64,
    /// Where the current stream started (offsets in a footer count from there).
    stream_start: u64,
    header: StreamHeader,
    /// Kinds of the stores seen, to tell blueprint chunks from data.
    store_kinds: ahash::HashMap<StoreId, StoreKind>,
    /// The recording chunks of the current stream: id, store (its place in
    /// `seen_stores`), and where the message body starts (from the stream's start), to
    /// check the footer's manifest against.
    seen: Vec<(ChunkId, usize, u64)>,
    /// The distinct stores of `seen` (a stream has one or two: a copy per chunk was a
    /// tenth of reading a small chunk's message).
    seen_stores: Vec<StoreId>,
    /// The vector stream bodies are read into, kept between messages.
    scratch: Vec<u8>,
    /// The last `End` message's body: where it started, and its bytes.
    end_message: Option<(u64, Vec<u8>)>,
    /// What the messages of a run decoded a phase at a time gave, in stream order, not yet
    /// returned (see [`RrdReader::decode_run`]).
    ahead: std::collections::VecDeque<Result<Option<RrdItem>, RrdError>>,
    done: bool,
}

impl<R: Read> RrdReader<R> {
    /// Reads the stream header.
    ///
    /// # Errors
    /// If the input is not an `.rrd` stream this crate reads.
    pub fn new(reader: R) -> Result<Self, RrdError> {
        Self::start(Input::Stream(reader))
    }
}

impl RrdReader<std::io::Empty> {
    /// A reader over bytes in memory (a file read whole, or any `Buffer`): uncompressed
    /// payloads decode without a copy, their chunks' buffers slices of `bytes`, wherever
    /// the payload's buffers are aligned for their types (arrow-ipc copies the others).
    ///
    /// # Errors
    /// If the input is not an `.rrd` stream this crate reads.
    pub fn from_buffer(bytes: Buffer) -> Result<Self, RrdError> {
        Self::start(Input::Buffer(bytes))
    }
}

impl<R: Read> RrdReader<R> {
    fn start(input: Input<R>) -> Result<Self, RrdError> {
        let mut reader = Self {
            input,
            pushback: Vec::new(),
            position: 0,
            stream_start: 0,
            header: StreamHeader {
                version: [0; 4],
                compressed: false,
            },
            store_kinds: ahash::HashMap::default(),
            seen: Vec::new(),
            seen_stores: Vec::new(),
            scratch: Vec::new(),
            end_message: None,
            ahead: std::collections::VecDeque::new(),
            done: false,
        };
        reader.header = reader.read_stream_header()?;
        Ok(reader)
    }

    /// The stream header (of the first stream, if several were concatenated).
    pub fn header(&self) -> StreamHeader {
        self.header
    }

    /// Bytes consumed so far. A reader over a buffer reads a run of small chunks' messages
    /// at once (they decode a phase at a time), so this may be ahead of the last item
    /// returned by up to 64 such messages.
    pub fn position(&self) -> u64 {
        self.position
    }

    fn read_stream_header(&mut self) -> Result<StreamHeader, RrdError> {
        let at = self.position;
        let mut bytes = [0u8; STREAM_HEADER_LEN];
        let got = self.read_up_to(&mut bytes)?;
        if got < STREAM_HEADER_LEN {
            // A wrong magic says more than a short read.
            if got >= 4 && bytes[..4] != frames::MAGIC {
                let kind = StreamHeader::parse(&bytes)
                    .err()
                    .unwrap_or(RrdErrorKind::NotAnRrd {
                        found: [bytes[0], bytes[1], bytes[2], bytes[3]],
                    });
                return Err(RrdError::new(at, kind));
            }
            return Err(RrdError::new(
                at,
                RrdErrorKind::Truncated {
                    what: "stream header",
                    needed: STREAM_HEADER_LEN as u64,
                    available: got as u64,
                },
            ));
        }
        StreamHeader::parse(&bytes).map_err(|kind| RrdError::new(at, kind))
    }

    /// Fills as much of `out` as the input has; returns how much.
    fn read_up_to(&mut self, out: &mut [u8]) -> Result<usize, RrdError> {
        let mut filled = 0;
        if !self.pushback.is_empty() {
            let n = self.pushback.len().min(out.len());
            out[..n].copy_from_slice(&self.pushback[..n]);
            self.pushback.drain(..n);
            filled = n;
        }
        match &mut self.input {
            Input::Buffer(buffer) => {
                let n = buffer.len().min(out.len() - filled);
                out[filled..filled + n].copy_from_slice(&buffer.as_slice()[..n]);
                *buffer = buffer.slice(n);
                filled += n;
            }
            Input::Stream(reader) => {
                while filled < out.len() {
                    match reader.read(&mut out[filled..]) {
                        Ok(0) => break,
                        Ok(n) => filled += n,
                        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                        Err(e) => return Err(RrdError::new(self.position, RrdErrorKind::Io(e))),
                    }
                }
            }
        }
        self.position += filled as u64;
        Ok(filled)
    }

    /// Exactly `len` bytes (a message body), or a truncation error. Never allocates more
    /// than what the input really holds: a buffer is sliced; a stream is read in steps.
    fn read_body(&mut self, len: u64, what: &'static str) -> Result<Body, RrdError> {
        if self.pushback.is_empty() {
            return self.read_input(len, what);
        }
        // Bytes peeked after a footer (at most 32): rare, so a copy is fine.
        let from_pushback = self
            .pushback
            .len()
            .min(usize::try_from(len).unwrap_or(usize::MAX));
        let mut body: Vec<u8> = self.pushback.drain(..from_pushback).collect();
        self.position += from_pushback as u64;
        let rest = self.read_input(len - from_pushback as u64, what)?;
        body.extend_from_slice(rest.as_slice());
        self.recycle(rest);
        Ok(Body::Scratch(body))
    }

    /// Gives a scratch body's vector back for the next message.
    fn recycle(&mut self, body: Body) {
        if let Body::Scratch(mut bytes) = body {
            bytes.clear();
            self.scratch = bytes;
        }
    }

    fn read_input(&mut self, len: u64, what: &'static str) -> Result<Body, RrdError> {
        let at = self.position;
        let truncated = |available: u64| {
            RrdError::new(
                at,
                RrdErrorKind::Truncated {
                    what,
                    needed: len,
                    available,
                },
            )
        };
        match &mut self.input {
            Input::Buffer(buffer) => {
                let available = buffer.len() as u64;
                let n = usize::try_from(len)
                    .ok()
                    .filter(|&n| n <= buffer.len())
                    .ok_or_else(|| truncated(available))?;
                let body = buffer.slice_with_length(0, n);
                *buffer = buffer.slice(n);
                self.position += len;
                Ok(Body::Shared(body))
            }
            Input::Stream(reader) => {
                let mut body = std::mem::take(&mut self.scratch);
                body.clear();
                // Grown as bytes arrive (never to a claimed length), then kept.
                body.reserve(usize::try_from(len.min(1 << 20)).unwrap_or(0));
                let got = reader
                    .by_ref()
                    .take(len)
                    .read_to_end(&mut body)
                    .map_err(|e| RrdError::new(at, RrdErrorKind::Io(e)))?;
                self.position += got as u64;
                if (got as u64) < len {
                    return Err(truncated(got as u64));
                }
                Ok(Body::Scratch(body))
            }
        }
    }

    /// The next item, or `None` at the end of the stream.
    fn next_item(&mut self) -> Option<Result<RrdItem, RrdError>> {
        loop {
            if self.done {
                return None;
            }
            let result = self.step();
            match result {
                Ok(Some(item)) => return Some(Ok(item)),
                Ok(None) => {}
                Err(error) => {
                    if error.is_fatal() {
                        self.done = true;
                    }
                    return Some(Err(error));
                }
            }
        }
    }

    /// Reads one message; `Ok(None)` for one that yields nothing (a stream's end).
    fn step(&mut self) -> Result<Option<RrdItem>, RrdError> {
        if let Some(decoded) = self.ahead.pop_front() {
            return decoded;
        }
        if self.end_message.is_some() {
            return self.after_end();
        }
        let at = self.position;
        let mut header = [0u8; MESSAGE_HEADER_LEN];
        let got = self.read_up_to(&mut header)?;
        if got == 0 {
            self.done = true; // a stream without an `End` message (e.g. cut after a message)
            return Ok(None);
        }
        if got < MESSAGE_HEADER_LEN {
            return Err(RrdError::new(
                at,
                RrdErrorKind::Truncated {
                    what: "message header",
                    needed: MESSAGE_HEADER_LEN as u64,
                    available: got as u64,
                },
            ));
        }
        let (kind, len) = frames::parse_message_header(&header);
        let body_at = self.position;
        let Some(kind) = MessageKind::from_u64(kind) else {
            // From a newer format, perhaps: skipped whole (if its length holds), reported.
            let body = self.read_body(len, "message body")?;
            self.recycle(body);
            return Err(RrdError::new(at, RrdErrorKind::UnknownMessageKind { kind }));
        };
        let body = self.read_body(len, "message body")?;
        if kind == MessageKind::ArrowMsg
            && let Body::Shared(first) = &body
            && first.len() <= RUN_MESSAGE_BYTES
            && let Some(next) = self.take_buffered_arrow_msg()
        {
            let mut run = vec![(first.clone(), body_at), next];
            while run.len() < RUN_MESSAGES
                && let Some(next) = self.take_buffered_arrow_msg()
            {
                run.push(next);
            }
            self.decode_run(&run);
            return self.ahead.pop_front().unwrap_or(Ok(None));
        }
        let item = self.decode_message(kind, &body, body_at);
        self.recycle(body);
        item
    }

    /// The next message, taken from the input, if it is an `ArrowMsg` lying whole in an
    /// input buffer, with a body of at most [`RUN_MESSAGE_BYTES`]; else nothing is taken
    /// (`step` reads it, and reports its faults, as any other message).
    fn take_buffered_arrow_msg(&mut self) -> Option<(Buffer, u64)> {
        let Input::Buffer(buffer) = &mut self.input else {
            return None;
        };
        if !self.pushback.is_empty() {
            return None;
        }
        let header: &[u8; MESSAGE_HEADER_LEN] = buffer
            .as_slice()
            .get(..MESSAGE_HEADER_LEN)?
            .try_into()
            .ok()?;
        let (kind, len) = frames::parse_message_header(header);
        let len = usize::try_from(len)
            .ok()
            .filter(|&len| len <= RUN_MESSAGE_BYTES)?;
        if MessageKind::from_u64(kind) != Some(MessageKind::ArrowMsg)
            || buffer.len() - MESSAGE_HEADER_LEN < len
        {
            return None;
        }
        let body = buffer.slice_with_length(MESSAGE_HEADER_LEN, len);
        *buffer = buffer.slice(MESSAGE_HEADER_LEN + len);
        let body_at = self.position + MESSAGE_HEADER_LEN as u64;
        self.position = body_at + len as u64;
        Some((body, body_at))
    }

    /// Decodes a run of `ArrowMsg` bodies (each with where it starts) a phase at a time:
    /// every protobuf, then every payload's LZ4, then each IPC stream into its chunk,
    /// queueing each message's item or error in stream order. Each phase's code then stays
    /// in the instruction cache across the run, where one message at a time ran through
    /// more code than it holds (`docs/PERFORMANCE.md`, "`.rrd` files"). The answers are
    /// those of decoding each message on its own: no phase of one message reads another's.
    fn decode_run(&mut self, run: &[(Buffer, u64)]) {
        #[cfg(test)]
        RUN_DECODED.with(|count| count.set(count.get() + run.len()));
        // Phases past the protobuf go a group at a time, so that the payloads decoded at
        // once stay small whatever the messages claim.
        let mut group = Vec::with_capacity(run.len());
        let mut group_bytes = 0u64;
        for (body, body_at) in run {
            let message = self.arrow_msg_of(body, *body_at);
            let bytes = match &message {
                Ok(Some((msg, _))) => msg.uncompressed_size,
                Ok(None) | Err(_) => 0,
            };
            if !group.is_empty() && group_bytes.saturating_add(bytes) > RUN_DECODED_BYTES {
                self.decode_group(std::mem::take(&mut group));
                group_bytes = 0;
            }
            group_bytes = group_bytes.saturating_add(bytes);
            group.push((message, *body_at));
        }
        self.decode_group(group);
    }

    /// Decodes a group of a run's messages (each decoded as a protobuf, with where its
    /// body starts) a phase at a time: every payload's LZ4, then each IPC stream into its
    /// chunk (apart, the two phases cost more in the allocator than they saved in the
    /// instruction cache), queueing each message's item or error.
    fn decode_group(&mut self, group: Vec<(RunMessage, u64)>) {
        // Each message with its payload's IPC stream in place of the payload.
        let streams: Vec<(RunMessage, u64)> = group
            .into_iter()
            .map(|(message, body_at)| {
                let stream = match message {
                    Ok(Some((msg, payload))) => {
                        let payload = payload::PayloadBytes::Shared(payload);
                        match payload::ipc_stream_of(
                            payload,
                            msg.compression,
                            msg.uncompressed_size,
                        ) {
                            Ok(stream) => Ok(Some((msg, stream))),
                            Err(kind) => {
                                Err(RrdError::new(payload::payload_at(&msg, body_at), kind))
                            }
                        }
                    }
                    other => other,
                };
                (stream, body_at)
            })
            .collect();
        for (stream, body_at) in streams {
            let item = match stream {
                Err(error) => Err(error),
                Ok(None) => Ok(Some(RrdItem::SkippedBlueprint { offset: body_at })),
                Ok(Some((msg, stream))) => {
                    payload::chunk_of_stream(crate::ipc::read_stream_zero_copy(&stream))
                        .map_err(|kind| RrdError::new(payload::payload_at(&msg, body_at), kind))
                        .and_then(|chunk| payload::check_message_chunk(&msg, chunk, body_at))
                        .map(|chunk| Some(self.chunk_item(msg, chunk, body_at)))
                }
            };
            self.ahead.push_back(item);
        }
    }

    /// An `ArrowMsg` body's message and payload; `None` for a blueprint's.
    fn arrow_msg_of(&self, body: &Buffer, body_at: u64) -> RunMessage {
        let msg = ArrowMsg::decode(body.as_slice())
            .map_err(|(offset, kind)| RrdError::new(body_at + offset as u64, kind))?;
        if self.kind_of(&msg.store_id) != StoreKind::Recording {
            return Ok(None);
        }
        let payload = body.slice_with_length(msg.payload.start, msg.payload.len());
        Ok(Some((msg, payload)))
    }

    /// The kind of a store: as its store info said, else as its id says.
    fn kind_of(&self, store_id: &StoreId) -> StoreKind {
        self.store_kinds
            .get(store_id)
            .copied()
            .unwrap_or(store_id.kind)
    }

    /// A decoded chunk's item, its store and place noted for the footer's check.
    fn chunk_item(&mut self, msg: ArrowMsg, chunk: Chunk, body_at: u64) -> RrdItem {
        let store = if let Some(store) = self.seen_stores.iter().position(|s| *s == msg.store_id) {
            store
        } else {
            self.seen_stores.push(msg.store_id.clone());
            self.seen_stores.len() - 1
        };
        self.seen
            .push((chunk.id(), store, body_at - self.stream_start));
        RrdItem::Chunk {
            store_id: msg.store_id,
            chunk,
            offset: body_at,
        }
    }

    fn decode_message(
        &mut self,
        kind: MessageKind,
        body: &Body,
        body_at: u64,
    ) -> Result<Option<RrdItem>, RrdError> {
        let bytes = body.as_slice();
        let within =
            |(offset, kind): (usize, RrdErrorKind)| RrdError::new(body_at + offset as u64, kind);
        match kind {
            MessageKind::SetStoreInfo => {
                let info = StoreInfo::decode_set_store_info(bytes).map_err(within)?;
                self.store_kinds
                    .insert(info.store_id.clone(), info.store_id.kind);
                Ok(Some(RrdItem::StoreInfo(info)))
            }
            MessageKind::ArrowMsg => {
                let msg = ArrowMsg::decode(bytes).map_err(within)?;
                if self.kind_of(&msg.store_id) != StoreKind::Recording {
                    return Ok(Some(RrdItem::SkippedBlueprint { offset: body_at }));
                }
                let payload = match body {
                    Body::Shared(buffer) => payload::PayloadBytes::Shared(
                        buffer.slice_with_length(msg.payload.start, msg.payload.len()),
                    ),
                    Body::Scratch(bytes) => {
                        payload::PayloadBytes::Borrowed(&bytes[msg.payload.clone()])
                    }
                };
                let chunk = payload::decode_message_chunk(&msg, payload, body_at)?;
                Ok(Some(self.chunk_item(msg, chunk, body_at)))
            }
            MessageKind::BlueprintActivationCommand => {
                Ok(Some(RrdItem::SkippedBlueprint { offset: body_at }))
            }
            MessageKind::End => {
                self.end_message = Some((body_at, bytes.to_vec()));
                if bytes.is_empty() {
                    return Ok(None);
                }
                let manifests = manifest::decode_footer(bytes).map_err(within)?;
                let seen = std::mem::take(&mut self.seen);
                let seen_stores = std::mem::take(&mut self.seen_stores);
                check_manifests(&manifests, &seen, &seen_stores)
                    .map_err(|reason| RrdError::new(body_at, RrdErrorKind::Footer { reason }))?;
                Ok(Some(RrdItem::Footer(manifests)))
            }
        }
    }

    /// After an `End` message: the end of the input, a stream footer (checked against the
    /// `End` message), or another concatenated stream.
    fn after_end(&mut self) -> Result<Option<RrdItem>, RrdError> {
        let Some((end_at, end_body)) = self.end_message.take() else {
            return Ok(None);
        };
        let at = self.position;
        let mut tail = [0u8; STREAM_FOOTER_LEN];
        let got = self.read_up_to(&mut tail)?;
        if got == 0 {
            self.done = true;
            return Ok(None);
        }
        if got == STREAM_FOOTER_LEN
            && let Some(footer) = StreamFooter::parse(&tail)
        {
            let expected = StreamFooter::for_footer(end_at - self.stream_start, &end_body);
            if footer != expected {
                self.done = true;
                return Err(RrdError::new(
                    at,
                    RrdErrorKind::Footer {
                        reason: format!(
                            "the stream footer points at {} bytes at {} with checksum {:#x}, \
                             the End message has {} bytes at {} with checksum {:#x}",
                            footer.footer_len,
                            footer.footer_start,
                            footer.crc,
                            expected.footer_len,
                            expected.footer_start,
                            expected.crc
                        ),
                    },
                ));
            }
            // Another stream may follow (concatenated files).
            let mut magic = [0u8; 4];
            let more = self.read_up_to(&mut magic)?;
            if more == 0 {
                self.done = true;
                return Ok(None);
            }
            self.pushback.extend_from_slice(&magic[..more]);
            self.position -= more as u64;
        } else {
            self.pushback.extend_from_slice(&tail[..got]);
            self.position -= got as u64;
        }
        self.stream_start = self.position;
        self.seen.clear();
        self.seen_stores.clear();
        self.read_stream_header()?;
        Ok(None)
    }
}

/// Does each recording's manifest list exactly the chunks the stream held, where it held
/// them? (A chunk that failed to decode still has its row, so a mismatch after a decoding
/// error is not reported twice: only ids seen are checked for their offsets.)
fn check_manifests(
    manifests: &[Manifest],
    seen: &[(ChunkId, usize, u64)],
    seen_stores: &[StoreId],
) -> Result<(), String> {
    for manifest in manifests {
        if manifest.store_id.kind != StoreKind::Recording {
            continue;
        }
        let listed: ahash::HashMap<ChunkId, u64> = manifest
            .entries
            .iter()
            .map(|e| (e.chunk_id, e.byte_offset))
            .collect();
        let Some(this_store) = seen_stores.iter().position(|s| *s == manifest.store_id) else {
            continue;
        };
        let store = &manifest.store_id;
        for (id, _, offset) in seen.iter().filter(|s| s.1 == this_store) {
            match listed.get(id) {
                Some(at) if at == offset => {}
                Some(at) => {
                    return Err(format!(
                        "the manifest puts chunk {id} at byte {at}, the stream has it at {offset} \
                         (store {})",
                        store.recording_id
                    ));
                }
                None => {
                    return Err(format!(
                        "the manifest does not list chunk {id} (at byte {offset})"
                    ));
                }
            }
        }
    }
    Ok(())
}

impl<R: Read> Iterator for RrdReader<R> {
    type Item = Result<RrdItem, RrdError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_item()
    }
}

/// What [`read_rrd`] found in a whole stream.
#[derive(Debug, Default)]
pub struct RrdContents {
    /// The store infos, in stream order.
    pub store_infos: Vec<StoreInfo>,
    /// The recordings' chunks, in stream order, with their store.
    pub chunks: Vec<(StoreId, Chunk)>,
    /// How many blueprint messages were skipped.
    pub skipped_blueprint_messages: usize,
    /// The footer's manifests, if there was a footer.
    pub manifests: Option<Vec<Manifest>>,
    /// The errors met, in order, when told to keep going (see [`read_rrd`]).
    pub errors: Vec<RrdError>,
}

/// Reads a whole `.rrd` stream from bytes in memory.
///
/// With `keep_going`, a message that cannot be decoded is recorded in
/// [`RrdContents::errors`] and skipped, and what was decoded before a framing fault is
/// returned; without it, the first error is returned.
///
/// # Errors
/// The first [`RrdError`], unless `keep_going`; even then, if the stream header is bad.
pub fn read_rrd(bytes: Buffer, keep_going: bool) -> Result<RrdContents, RrdError> {
    collect(RrdReader::from_buffer(bytes)?, keep_going)
}

/// [`read_rrd`] over any reader.
///
/// # Errors
/// As [`read_rrd`].
pub fn read_rrd_from(reader: impl Read, keep_going: bool) -> Result<RrdContents, RrdError> {
    collect(RrdReader::new(reader)?, keep_going)
}

fn collect<R: Read>(reader: RrdReader<R>, keep_going: bool) -> Result<RrdContents, RrdError> {
    let mut contents = RrdContents::default();
    for item in reader {
        match item {
            Ok(RrdItem::StoreInfo(info)) => contents.store_infos.push(info),
            Ok(RrdItem::Chunk {
                store_id, chunk, ..
            }) => contents.chunks.push((store_id, chunk)),
            Ok(RrdItem::SkippedBlueprint { .. }) => contents.skipped_blueprint_messages += 1,
            Ok(RrdItem::Footer(manifests)) => {
                contents
                    .manifests
                    .get_or_insert_with(Vec::new)
                    .extend(manifests);
            }
            Err(error) if keep_going => contents.errors.push(error),
            Err(error) => return Err(error),
        }
    }
    Ok(contents)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::{ArrayRef, Int64Array, RecordBatch};

    use super::*;
    use crate::rrd::frames::{WRITTEN_VERSION, encode_message_header};
    use crate::rrd::messages::Compression;

    /// A stream: header, a store info, then `(kind, body)` messages, no footer.
    fn stream(messages: &[(MessageKind, Vec<u8>)]) -> Vec<u8> {
        let store = StoreId::recording("app", "rec");
        let mut out = StreamHeader {
            version: WRITTEN_VERSION,
            compressed: false,
        }
        .encode()
        .to_vec();
        let info = StoreInfo::new(store).encode_set_store_info(1);
        let all =
            std::iter::once((MessageKind::SetStoreInfo, info)).chain(messages.iter().cloned());
        for (kind, body) in all {
            out.extend_from_slice(&encode_message_header(kind, body.len() as u64));
            out.extend_from_slice(&body);
        }
        out
    }

    fn errors(bytes: Vec<u8>) -> Vec<RrdError> {
        read_rrd(Buffer::from_vec(bytes), true).unwrap().errors
    }

    #[test]
    fn a_payload_that_is_not_a_chunk_is_named_and_skipped() {
        let plain =
            RecordBatch::try_from_iter([("x", Arc::new(Int64Array::from(vec![1, 2])) as ArrayRef)])
                .unwrap();
        let mut ipc = Vec::new();
        let mut writer =
            arrow_ipc::writer::StreamWriter::try_new(&mut ipc, &plain.schema()).unwrap();
        writer.write(&plain).unwrap();
        writer.finish().unwrap();
        drop(writer);
        let store = StoreId::recording("app", "rec");
        let body = ArrowMsg::encode(
            &store,
            ChunkId::new(),
            false,
            Compression::None,
            ipc.len() as u64,
            &ipc,
        );
        let bytes = stream(&[(MessageKind::ArrowMsg, body)]);
        let errors = errors(bytes);
        assert_eq!(errors.len(), 1);
        assert!(
            matches!(errors[0].kind, RrdErrorKind::Chunk(_)),
            "{}",
            errors[0]
        );
        assert!(!errors[0].is_fatal());
    }

    #[test]
    fn garbage_protobuf_and_unknown_kinds_are_named_and_skipped() {
        let garbage = vec![0x0f, 0xff, 0xff];
        let bytes = stream(&[(MessageKind::ArrowMsg, garbage)]);
        let errors = errors(bytes);
        assert!(
            matches!(errors[0].kind, RrdErrorKind::Protobuf { .. }),
            "{}",
            errors[0]
        );

        // An unknown kind with a length that holds: skipped, reported, the rest read.
        let mut bytes = stream(&[]);
        bytes.extend_from_slice(&99u64.to_le_bytes());
        bytes.extend_from_slice(&3u64.to_le_bytes());
        bytes.extend_from_slice(b"abc");
        let contents = read_rrd(Buffer::from_vec(bytes), true).unwrap();
        assert!(matches!(
            contents.errors[0].kind,
            RrdErrorKind::UnknownMessageKind { kind: 99 }
        ));
        assert_eq!(contents.store_infos.len(), 1);
    }

    /// A small chunk of entity `/e{i}`.
    fn small_chunk(i: u32) -> Chunk {
        let value = Arc::new(arrow_array::Float64Array::from(vec![f64::from(i)])) as ArrayRef;
        crate::ChunkBuilder::new(
            ChunkId::new(),
            crate::EntityPath::parse(&format!("/e{}", i % 3)).unwrap(),
        )
        .with_row(
            crate::RowId::new(),
            [(crate::Timeline::sequence("frame"), i64::from(i))],
            [("x", value)],
        )
        .build()
        .unwrap()
    }

    /// A one-row chunk whose cell holds `len` zeros.
    fn zeros_chunk(len: usize) -> Chunk {
        let values = arrow_array::Float64Array::from(vec![0.0; len]);
        let cell = Arc::new(arrow_array::ListArray::new(
            Arc::new(arrow_schema::Field::new(
                "item",
                arrow_schema::DataType::Float64,
                true,
            )),
            arrow_buffer::OffsetBuffer::from_lengths([len]),
            Arc::new(values),
            None,
        )) as ArrayRef;
        crate::ChunkBuilder::new(ChunkId::new(), crate::EntityPath::parse("/zeros").unwrap())
            .with_row(
                crate::RowId::new(),
                [(crate::Timeline::sequence("frame"), 0)],
                [("x", cell)],
            )
            .build()
            .unwrap()
    }

    /// What a read gave, to compare: chunk ids with their stores, errors with their
    /// offsets and messages, store infos, blueprint messages skipped.
    fn outcome(contents: &RrdContents) -> (Vec<(String, ChunkId)>, Vec<String>, usize, usize) {
        (
            contents
                .chunks
                .iter()
                .map(|(store, chunk)| (store.recording_id.to_string(), chunk.id()))
                .collect(),
            contents
                .errors
                .iter()
                .map(|e| format!("{} {e}", e.offset))
                .collect(),
            contents.store_infos.len(),
            contents.skipped_blueprint_messages,
        )
    }

    /// A buffer's runs of `ArrowMsg`s are decoded a phase at a time; each message gives
    /// what it gives read alone (as a streamed reader reads it), in stream order: chunks,
    /// errors inside a run (a bad protobuf, corrupt LZ4, a payload that is not a chunk, an
    /// id the payload contradicts), blueprint chunks, a second store, and a store info
    /// between runs that makes a recording's later chunks a blueprint's.
    #[test]
    fn runs_decode_as_their_messages_do_one_at_a_time() {
        let store = StoreId::recording("app", "rec");
        let other = StoreId::recording("app", "other");
        let blueprint = StoreId {
            kind: StoreKind::Blueprint,
            ..StoreId::recording("app", "blueprint")
        };
        let mut messages = Vec::new();
        for i in 0..150 {
            let id = match i % 7 {
                3 => &other,
                5 if i > 60 => &blueprint,
                _ => &store,
            };
            // A few payloads of 1.6 MB that compress to a few kilobytes: a run decodes
            // them in groups of their own.
            let zeros = (40..43).contains(&i);
            let chunk = if zeros {
                zeros_chunk(200_000)
            } else {
                small_chunk(i)
            };
            let (mut body, _) = payload::encode_arrow_msg(id, &chunk, zeros || i % 2 == 0).unwrap();
            match i {
                // Garbage for a protobuf, a payload's bytes flipped (corrupt LZ4 or IPC).
                10 => body = vec![0x0f, 0xff, 0xff],
                20 | 21 => {
                    let at = body.len() - 30;
                    body[at] ^= 0xff;
                    body[at + 1] ^= 0x55;
                }
                // The message names another chunk than its payload holds.
                30 => {
                    let (claimed, _) =
                        payload::encode_arrow_msg(id, &small_chunk(i), true).unwrap();
                    let msg = ArrowMsg::decode(&body).unwrap();
                    let other_id = ArrowMsg::decode(&claimed).unwrap().chunk_id.unwrap();
                    body = ArrowMsg::encode(
                        &msg.store_id,
                        other_id,
                        false,
                        msg.compression,
                        msg.uncompressed_size,
                        &body[msg.payload.clone()],
                    );
                }
                _ => {}
            }
            messages.push((MessageKind::ArrowMsg, body));
            if i == 100 {
                // From here on, "other" is a blueprint.
                let mut info = StoreInfo::new(other.clone());
                info.store_id.kind = StoreKind::Blueprint;
                messages.push((MessageKind::SetStoreInfo, info.encode_set_store_info(2)));
            }
            if i == 120 {
                messages.push((MessageKind::BlueprintActivationCommand, Vec::new()));
            }
        }
        let bytes = stream(&messages);
        let before = RUN_DECODED.with(std::cell::Cell::get);
        let in_runs = read_rrd(Buffer::from(bytes.clone()), true).unwrap();
        // All but the messages that end a run early (after a store info or a blueprint
        // activation, each of which is read on its own).
        assert!(RUN_DECODED.with(std::cell::Cell::get) - before > 140);
        assert!(
            in_runs
                .chunks
                .iter()
                .any(|(_, c)| c.entity_path().to_string() == "/zeros")
        );
        let one_at_a_time = read_rrd_from(bytes.as_slice(), true).unwrap();
        assert_eq!(outcome(&in_runs), outcome(&one_at_a_time));
        let (chunks, errors, infos, skipped) = outcome(&in_runs);
        assert!(chunks.len() > 120, "{}", chunks.len());
        assert!(errors.len() >= 4, "{errors:?}");
        assert_eq!(infos, 2);
        assert!(skipped > 10, "{skipped}");
        assert!(chunks.iter().any(|(store, _)| store == "other"));
        // Without keep-going, the first error stops both at the same message.
        let strict = read_rrd(Buffer::from(bytes.clone()), false).unwrap_err();
        let strict_streamed = read_rrd_from(bytes.as_slice(), false).unwrap_err();
        assert_eq!(strict.to_string(), strict_streamed.to_string());
        assert_eq!(strict.offset, strict_streamed.offset);
    }
}
