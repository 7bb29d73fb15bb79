//! The body of the `damaged_log` fuzz target: a server's `--persist` log, written from a
//! script the input describes, then damaged once, then read back as the server reads it at
//! start ([`scan_log`]). The input: a byte of flags and message count, a byte per message
//! choosing what it is, then the damage: an offset (`u32` LE, taken modulo the log's
//! length), what to do there (flip bits, set a byte, cut the log, zero the rest) and a
//! value.
//!
//! What must hold (the write-ahead log's promise): a cut or zeroed tail is always a torn
//! tail, and every message written wholly before it is read back; a damaged byte anywhere
//! either makes the scan refuse (a fault that is not a torn tail: the server then refuses
//! to start and touches nothing), or loses at most the message it is in: every other
//! message is read back, in order.

use std::sync::Arc;

use arrow_array::{ArrayRef, Float64Array};
use arrow_buffer::Buffer;
use chunkstore::rrd::{LogMsg, RrdWriter, StoreId, StoreInfo, log_stream_header, scan_log};
use chunkstore::{ChunkBuilder, ChunkId, EntityPath, RowId, Timeline};

/// One message the script may write, chosen by `choice`.
fn message(choice: u8, index: usize) -> LogMsg {
    let id = StoreId::recording("app", format!("r{}", choice % 3));
    if choice.is_multiple_of(4) {
        return LogMsg::from_store_info(&StoreInfo::new(id));
    }
    let values: Vec<f64> = (0..u32::from(choice % 16) * 4).map(f64::from).collect();
    let entity = EntityPath::parse(&format!("/e{}", choice % 5)).expect("a valid path");
    let chunk = ChunkBuilder::new(ChunkId::new(), entity)
        .with_row(
            RowId::new(),
            [(
                Timeline::sequence("frame"),
                i64::try_from(index).unwrap_or(0),
            )],
            [("x", Arc::new(Float64Array::from(values)) as ArrayRef)],
        )
        .build()
        .expect("a valid chunk");
    LogMsg::from_chunk(&id, &chunk, choice.is_multiple_of(2)).expect("a chunk encodes")
}

/// A log of `messages`: a closed stream written by the crate's writer first when
/// `closed_first`, then an open stream of frames, as the server appends them. Returns the
/// bytes and each message's frame (header and body) as a byte range.
fn write_log(messages: &[LogMsg], closed_first: bool) -> (Vec<u8>, Vec<std::ops::Range<usize>>) {
    let mut log = Vec::new();
    if closed_first {
        let info = StoreInfo::new(StoreId::recording("app", "file"));
        let writer = RrdWriter::with_store_info(&mut log, &info, true).expect("in memory");
        writer.finish().expect("in memory");
    }
    let mut frames = Vec::new();
    log.extend_from_slice(&log_stream_header());
    for msg in messages {
        let start = log.len();
        log.extend_from_slice(&msg.frame_header());
        log.extend_from_slice(msg.body().as_slice());
        frames.push(start..log.len());
    }
    (log, frames)
}

/// Is `kept` `written` with at most the message at `lost` missing or altered, and no
/// other message missing (a damaged frame may also read as extra messages)?
fn loses_at_most(written: &[LogMsg], kept: &[LogMsg], lost: Option<usize>) -> bool {
    let mut kept = kept.iter();
    written.iter().enumerate().all(|(i, msg)| {
        if Some(i) == lost {
            return true;
        }
        kept.any(|k| k == msg)
    })
}

/// A scripted log and what it was written from.
pub struct ScriptedLog {
    /// The messages appended, in order.
    pub written: Vec<LogMsg>,
    /// The log's bytes.
    pub log: Vec<u8>,
    frames: Vec<std::ops::Range<usize>>,
    /// Messages read before the appended frames (the closed file's).
    before: usize,
}

impl ScriptedLog {
    /// The log `flags` and `choices` describe (as the fuzz input's first bytes do).
    pub fn new(flags: u8, choices: &[u8]) -> Self {
        let written: Vec<LogMsg> = choices
            .iter()
            .enumerate()
            .map(|(i, &c)| message(c, i))
            .collect();
        let (log, frames) = write_log(&written, flags & 8 != 0);
        let base = scan_log(&Buffer::from(log.clone()));
        assert!(
            base.fault.is_none(),
            "an undamaged log reads: {:?}",
            base.fault
        );
        assert!(base.messages.ends_with(&written));
        let before = base.messages.len() - written.len();
        Self {
            written,
            log,
            frames,
            before,
        }
    }

    /// Damages a copy of the log at `at` (`op`: 0 cut, 1 zeros to the end, 2 bits
    /// flipped by `value`, 3 the byte set to `value`) and checks what a scan keeps.
    pub fn check_damage(&self, at: usize, op: u8, value: u8) {
        let (written, frames, before) = (&self.written, &self.frames, self.before);
        let mut log = self.log.clone();
        let first_frame = frames.first().map_or(log.len(), |f| f.start);
        let frame_of = |at: usize| frames.iter().position(|f| f.contains(&at));
        match op % 4 {
            // A cut, or zeros from `at` on: always a torn tail, and every message wholly
            // before `at` is kept.
            cut @ (0 | 1) => {
                if cut == 0 {
                    log.truncate(at);
                } else {
                    log[at..].iter_mut().for_each(|b| *b = 0);
                }
                let scan = scan_log(&Buffer::from(log));
                assert!(
                    scan.fault.is_none() || scan.is_torn_tail(),
                    "a cut at {at} is a torn tail: {:?}",
                    scan.fault
                );
                if at >= first_frame {
                    let whole = frames.iter().filter(|f| f.end <= at).count();
                    assert!(
                        scan.messages.len() >= before + whole,
                        "a cut at {at} kept {}",
                        scan.messages.len()
                    );
                    assert_eq!(&scan.messages[before..before + whole], &written[..whole]);
                }
            }
            // One byte changed: refused, or at most its own message lost.
            set => {
                let new = if set == 2 {
                    log[at] ^ value.max(1)
                } else {
                    value
                };
                if new == log[at] {
                    return;
                }
                log[at] = new;
                let scan = scan_log(&Buffer::from(log));
                if scan.fault.is_some() && !scan.is_torn_tail() {
                    return;
                }
                if at >= first_frame {
                    let kept = &scan.messages[before.min(scan.messages.len())..];
                    assert!(
                        loses_at_most(written, kept, frame_of(at)),
                        "a byte changed at {at} (frame {:?}) lost more than its message",
                        frame_of(at)
                    );
                } else {
                    // Damage before the log's frames (in the file it was appended to, or
                    // its stream header): every frame stays.
                    assert!(
                        loses_at_most(written, &scan.messages, None),
                        "a byte changed at {at}, before the frames, lost one"
                    );
                }
            }
        }
    }
}

pub fn damaged_log(bytes: &[u8]) {
    let [flags, rest @ ..] = bytes else {
        return;
    };
    let count = usize::from(flags & 7) + 1;
    let Some((choices, damage)) = rest.split_at_checked(count) else {
        return;
    };
    let [a, b, c, d, op, value, ..] = *damage else {
        return;
    };
    let scripted = ScriptedLog::new(*flags, choices);
    let at = u32::from_le_bytes([a, b, c, d]) as usize % scripted.log.len();
    scripted.check_damage(at, op, value);
}
