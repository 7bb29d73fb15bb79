//! Detached indices: the footer a file without one would have, kept in a file of its own
//! (feature `rrd`). An `.rrd` cut short (a recording still being written, a process that
//! died) has no footer, so every use reads it whole; scanned once, its chunks' manifest is
//! written as a small `.rrd` of its own: its header, the recording's store info, and an
//! `End` message whose manifest places each chunk in the data file. Opened with
//! [`LazyRecording::open_indexed`](super::LazyRecording::open_indexed), the data file is
//! then read as lazily as one with a footer. The index is never written beside the data:
//! its caller names where it goes.

use std::io::{BufReader, Read, Write};
use std::path::Path;
use std::sync::Arc;

use super::{RrdError, RrdErrorKind, RrdItem, RrdReader, RrdWriter, StoreInfo, StoreKind};
use crate::Chunk;

/// What a scan of a file without a footer found: its recording's store info and chunks.
#[derive(Debug)]
#[non_exhaustive]
pub struct Scanned {
    /// The recording's store info, if the file has one.
    pub store_info: Option<StoreInfo>,
    /// Its chunks, in file order.
    pub chunks: Vec<Arc<Chunk>>,
}

/// Reads the single-recording `.rrd` at `path` message by message and, if it names its
/// recording (a store info), writes its detached index to `index` (nothing, if it does
/// not), which it gives back. Blueprint messages are skipped, as every reader here skips
/// them. The caller makes the index durable (`atomic_write` syncs and renames it).
///
/// # Errors
/// The file's first fault (a truncated last message included: the index describes a file
/// that reads cleanly), [`RrdErrorKind::SeveralRecordings`] for a file of more than one
/// recording, and the index's write errors (as [`RrdErrorKind::Io`]).
pub fn scan_and_index<W: Write>(path: &Path, index: W) -> Result<(Scanned, W), RrdError> {
    let file = std::fs::File::open(path).map_err(|e| RrdError::new(0, RrdErrorKind::Io(e)))?;
    scan_stream_and_index(BufReader::new(file), index)
}

/// [`scan_and_index`] of a file read once from start to end, as it arrives (an object's
/// body, a pipe): nothing in it is read twice.
///
/// # Errors
/// As [`scan_and_index`].
pub fn scan_stream_and_index<R: Read, W: Write>(
    input: R,
    index: W,
) -> Result<(Scanned, W), RrdError> {
    let mut reader = RrdReader::new(input)?;
    let mut store_info = None;
    let mut chunks = Vec::new();
    let mut placed = Vec::new();
    let mut recordings: Vec<String> = Vec::new();
    while let Some(item) = reader.next() {
        match item? {
            // The recording's own (a blueprint's store info may come first).
            RrdItem::StoreInfo(info)
                if store_info.is_none() && info.store_id.kind == StoreKind::Recording =>
            {
                store_info = Some(info);
            }
            RrdItem::Chunk {
                store_id,
                chunk,
                offset,
            } => {
                let id = store_id.recording_id.to_string();
                if !recordings.contains(&id) {
                    recordings.push(id);
                }
                // A reader of a stream (not of a buffer) reads one message per item: it
                // stops where this chunk's body ends.
                let len = reader.position().checked_sub(offset).ok_or_else(|| {
                    RrdError::new(
                        offset,
                        RrdErrorKind::Footer {
                            reason: "the scan read past a chunk it had not given".to_owned(),
                        },
                    )
                })?;
                placed.push((offset, len));
                chunks.push(Arc::new(chunk));
            }
            _ => {}
        }
    }
    if recordings.len() > 1 {
        return Err(RrdError::new(
            0,
            RrdErrorKind::SeveralRecordings {
                recording_ids: recordings,
            },
        ));
    }
    let index = match &store_info {
        Some(info) => {
            let mut writer = RrdWriter::with_store_info(index, info, true)?;
            for (chunk, &(offset, len)) in chunks.iter().zip(&placed) {
                writer.note_chunk_elsewhere(chunk, offset, len);
            }
            writer.finish()?
        }
        None => index,
    };
    Ok((Scanned { store_info, chunks }, index))
}
