//! Positioned reads of an `.rrd` input for [`LazyRecording`](super::LazyRecording): every
//! read checked against the input's size before anything is allocated, the stream footers
//! walked from the end (each says where its stream starts), and a recording's store info
//! found without reading its chunks.

use std::io::{Read, Seek, SeekFrom};

use super::error::{RrdError, RrdErrorKind};
use super::frames::{
    self, MESSAGE_HEADER_LEN, MessageKind, STREAM_FOOTER_LEN, STREAM_HEADER_LEN, StreamFooter,
    StreamHeader,
};
use super::manifest::{self, Manifest};
use super::messages::{StoreId, StoreInfo};
/// What a [`LazyRecording`](super::LazyRecording) has read so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LazyStats {
    /// The file's size.
    pub file_bytes: u64,
    /// Bytes read from the file (header, store info, footer, and decoded chunks' messages).
    pub bytes_read: u64,
    /// Chunks the file holds.
    pub chunks_in_file: usize,
    /// Chunks decoded so far.
    pub chunks_decoded: usize,
    /// GET requests made to read it (the open's included); 0 for a local file.
    pub requests: u64,
    /// Bytes those requests brought (0 for a local file). Not `bytes_read`: the open
    /// fetches the object's end in one piece, and ranges close together are fetched in
    /// one GET with the gap between them.
    pub bytes_fetched: u64,
}

/// Reads `out.len()` bytes at `at`, checked against the file's size first.
pub(super) fn read_at<R: Read + Seek>(
    input: &mut R,
    at: u64,
    out: &mut [u8],
    file_bytes: u64,
    what: &'static str,
    stats: &mut LazyStats,
) -> Result<(), RrdError> {
    let len = out.len() as u64;
    if at.checked_add(len).is_none_or(|end| end > file_bytes) {
        return Err(RrdError::new(
            at,
            RrdErrorKind::Truncated {
                what,
                needed: len,
                available: file_bytes.saturating_sub(at),
            },
        ));
    }
    input
        .seek(SeekFrom::Start(at))
        .and_then(|_| input.read_exact(out))
        .map_err(|e| RrdError::new(at, RrdErrorKind::Io(e)))?;
    stats.bytes_read += len;
    Ok(())
}

/// Reads `len` bytes at `at` into a new vector, after checking that the file holds them
/// (so a corrupt manifest never makes us allocate what it claims).
pub(super) fn read_vec<R: Read + Seek>(
    input: &mut R,
    at: u64,
    len: u64,
    file_bytes: u64,
    stats: &mut LazyStats,
) -> Result<Vec<u8>, RrdError> {
    let mut out = Vec::new();
    read_into(input, at, len, file_bytes, stats, &mut out)?;
    Ok(out)
}

/// Reads `len` bytes at `at` into `out` (replacing what it held, and reusing its memory),
/// after checking that the file holds them.
pub(super) fn read_into<R: Read + Seek>(
    input: &mut R,
    at: u64,
    len: u64,
    file_bytes: u64,
    stats: &mut LazyStats,
    out: &mut Vec<u8>,
) -> Result<(), RrdError> {
    let fits = at.checked_add(len).is_some_and(|end| end <= file_bytes);
    let size = usize::try_from(len).ok().filter(|_| fits).ok_or_else(|| {
        RrdError::new(
            at,
            RrdErrorKind::Footer {
                reason: format!("{len} bytes at {at} are outside the {file_bytes}-byte file"),
            },
        )
    })?;
    out.clear();
    out.resize(size, 0);
    read_at(input, at, out, file_bytes, "message", stats)
}

/// One stream of the input, found through its footer.
pub(super) struct Stream {
    /// Where it starts in the input.
    pub(super) start: u64,
    /// Where its `End` message's body starts (the first message not to look at).
    pub(super) end_at: u64,
    /// Its manifests, offsets counted from the start of the input.
    pub(super) manifests: Vec<Manifest>,
}

pub(super) fn read_stream_header<R: Read + Seek>(
    input: &mut R,
    at: u64,
    stats: &mut LazyStats,
) -> Result<StreamHeader, RrdError> {
    let mut header = [0u8; STREAM_HEADER_LEN];
    read_at(
        input,
        at,
        &mut header,
        stats.file_bytes,
        "stream header",
        stats,
    )?;
    StreamHeader::parse(&header).map_err(|kind| RrdError::new(at, kind))
}

/// Every stream's footer, from the last stream back to the first, returned in file
/// order; `None` if a stream has no footer. With `check_stream_headers`, each stream's
/// header is read and checked too.
pub(super) fn read_footers<R: Read + Seek>(
    input: &mut R,
    stats: &mut LazyStats,
    check_stream_headers: bool,
) -> Result<Option<Vec<Stream>>, RrdError> {
    let file_bytes = stats.file_bytes;
    let mut streams = Vec::new();
    let mut end = file_bytes;
    while end > 0 {
        if end < (STREAM_HEADER_LEN + STREAM_FOOTER_LEN) as u64 {
            return Ok(None);
        }
        let tail_at = end - STREAM_FOOTER_LEN as u64;
        let mut tail = [0u8; STREAM_FOOTER_LEN];
        read_at(
            input,
            tail_at,
            &mut tail,
            file_bytes,
            "stream footer",
            stats,
        )?;
        let Some(footer) = StreamFooter::parse(&tail) else {
            return Ok(None);
        };
        let footer_bad = |reason: String| RrdError::new(tail_at, RrdErrorKind::Footer { reason });
        // The `End` message's body ends where the stream footer starts; the stream starts
        // `footer_start` bytes before that body.
        let body_at = tail_at.checked_sub(footer.footer_len);
        let start = body_at.and_then(|at| at.checked_sub(footer.footer_start));
        let (Some(body_at), Some(start)) = (body_at, start) else {
            return Err(footer_bad(format!(
                "the footer claims {} bytes at {} of a stream ending at byte {end}: more than \
                 the input holds before it",
                footer.footer_len, footer.footer_start
            )));
        };
        if footer.footer_start < (STREAM_HEADER_LEN + MESSAGE_HEADER_LEN) as u64 {
            return Err(footer_bad(format!(
                "the footer claims to start at byte {} of its stream, inside the headers",
                footer.footer_start
            )));
        }
        if check_stream_headers {
            read_stream_header(input, start, stats)?;
        }
        let body = read_vec(input, body_at, footer.footer_len, file_bytes, stats)?;
        if frames::crc(&body) != footer.crc {
            return Err(footer_bad(format!(
                "checksum {:#x} of the footer at {body_at} is not the {:#x} the stream footer \
                 says",
                frames::crc(&body),
                footer.crc
            )));
        }
        let mut manifests = manifest::decode_footer(&body)
            .map_err(|(at, kind)| RrdError::new(body_at + at as u64, kind))?;
        for manifest in &mut manifests {
            for entry in &mut manifest.entries {
                entry.byte_offset = entry.byte_offset.checked_add(start).ok_or_else(|| {
                    footer_bad(format!(
                        "chunk {} at byte {} of a stream at {start}: past any file",
                        entry.chunk_id, entry.byte_offset
                    ))
                })?;
            }
        }
        streams.push(Stream {
            start,
            end_at: body_at,
            manifests,
        });
        end = start;
    }
    streams.reverse();
    Ok(Some(streams))
}

/// The first store info of `store` in the file: the message headers of the streams that
/// hold it are walked from the start until its first chunk (a store info comes before its
/// store's chunks). Best effort: a file without one still opens.
pub(super) fn find_store_info<R: Read + Seek>(
    input: &mut R,
    streams: &[Stream],
    store: &StoreId,
    stats: &mut LazyStats,
) -> Option<StoreInfo> {
    let file_bytes = stats.file_bytes;
    for stream in streams {
        let Some(manifest) = stream.manifests.iter().find(|m| &m.store_id == store) else {
            continue;
        };
        let first_chunk = manifest
            .entries
            .iter()
            .map(|e| e.byte_offset)
            .min()
            .unwrap_or(stream.end_at);
        let mut at = stream.start + STREAM_HEADER_LEN as u64;
        while at < first_chunk.min(stream.end_at) {
            let mut header = [0u8; MESSAGE_HEADER_LEN];
            read_at(input, at, &mut header, file_bytes, "message header", stats).ok()?;
            let (kind, len) = frames::parse_message_header(&header);
            let body_at = at + MESSAGE_HEADER_LEN as u64;
            if MessageKind::from_u64(kind) == Some(MessageKind::SetStoreInfo) {
                let body = read_vec(input, body_at, len, file_bytes, stats).ok()?;
                if let Ok(info) = StoreInfo::decode_set_store_info(&body)
                    && &info.store_id == store
                {
                    return Some(info);
                }
            }
            at = body_at.checked_add(len)?;
        }
    }
    None
}
