//! The binary framing of an `.rrd` stream (Rerun's `RRF2`): a 12-byte stream header, then
//! messages each behind a 16-byte header (kind, length), the last one (`End`) carrying the
//! footer, then a 32-byte stream footer that points back at it.
//!
//! ```text
//! "RRF2" | version [major, minor, patch, meta] | options [compression, serializer, 0, 0]
//! kind: u64 LE | len: u64 LE | len bytes of protobuf        (repeated)
//! 0 (End)      | len         | RrdFooter protobuf
//! footer start: u64 LE | footer len: u64 LE | xxh32(footer, seed): u32 LE | "RRF2" "FOOT" | 1u32 LE
//! ```

use super::error::RrdErrorKind;

/// The magic of the current framing.
pub(crate) const MAGIC: [u8; 4] = *b"RRF2";
/// Magics of framings before Rerun 0.23, refused.
const OLD_MAGICS: [[u8; 4]; 2] = [*b"RRF0", *b"RRF1"];
/// The identifier after the magic in a stream footer.
pub(crate) const FOOTER_ID: [u8; 4] = *b"FOOT";
/// Seed of the xxh32 checksum of the footer message ("RERUN" in base 26).
pub(crate) const FOOTER_CRC_SEED: u32 = 7_850_921;

pub(crate) const STREAM_HEADER_LEN: usize = 12;
pub(crate) const MESSAGE_HEADER_LEN: usize = 16;
pub(crate) const STREAM_FOOTER_LEN: usize = 32;

/// The Rerun version this crate writes into headers and store infos: the format it was
/// checked against.
pub(crate) const WRITTEN_VERSION: [u8; 4] = [0, 41, 0, 0];

/// The kinds of messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum MessageKind {
    /// The last message of a stream; its body is the `RrdFooter` (possibly empty).
    End,
    SetStoreInfo,
    ArrowMsg,
    BlueprintActivationCommand,
}

impl MessageKind {
    pub(crate) fn from_u64(kind: u64) -> Option<Self> {
        Some(match kind {
            0 => Self::End,
            1 => Self::SetStoreInfo,
            2 => Self::ArrowMsg,
            3 => Self::BlueprintActivationCommand,
            _ => return None,
        })
    }

    pub(crate) fn as_u64(self) -> u64 {
        match self {
            Self::End => 0,
            Self::SetStoreInfo => 1,
            Self::ArrowMsg => 2,
            Self::BlueprintActivationCommand => 3,
        }
    }
}

/// The stream header's contents.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamHeader {
    /// The Rerun version that wrote the stream: `[major, minor, patch, meta]`.
    pub version: [u8; 4],
    /// Whether payloads are LZ4-compressed (each message also says so itself).
    pub compressed: bool,
}

impl StreamHeader {
    pub(crate) fn parse(bytes: &[u8; STREAM_HEADER_LEN]) -> Result<Self, RrdErrorKind> {
        let magic = [bytes[0], bytes[1], bytes[2], bytes[3]];
        if OLD_MAGICS.contains(&magic) {
            return Err(RrdErrorKind::OldFraming { found: magic });
        }
        if magic[..3] == MAGIC[..3] && magic[3] > MAGIC[3] {
            return Err(RrdErrorKind::NewerFraming { found: magic });
        }
        if magic != MAGIC {
            return Err(RrdErrorKind::NotAnRrd { found: magic });
        }
        let version = [bytes[4], bytes[5], bytes[6], bytes[7]];
        // Rerun stopped breaking the encoding at 0.23; [0, 0, 0, 0] was 0.2.
        if version[0] == 0 && version[1] < 23 {
            return Err(RrdErrorKind::UnsupportedVersion {
                version: (version[0], version[1], version[2]),
            });
        }
        let compressed = match bytes[8] {
            0 => false,
            1 => true,
            other => {
                return Err(RrdErrorKind::BadOptions {
                    reason: format!("unknown compression {other}"),
                });
            }
        };
        match bytes[9] {
            2 => {}
            1 => {
                return Err(RrdErrorKind::BadOptions {
                    reason: "MsgPack serializer (removed in Rerun 0.23)".to_owned(),
                });
            }
            other => {
                return Err(RrdErrorKind::BadOptions {
                    reason: format!("unknown serializer {other}"),
                });
            }
        }
        if bytes[10..12] != [0, 0] {
            return Err(RrdErrorKind::BadOptions {
                reason: "reserved option bytes are not zero".to_owned(),
            });
        }
        Ok(Self {
            version,
            compressed,
        })
    }

    /// Was the stream written by a Rerun newer than the one whose encoding this crate was
    /// checked against (0.41)? Such a file is read (unknown fields are skipped), but a tool
    /// may want to say so.
    pub fn is_newer_than_known(&self) -> bool {
        self.version[..3] > WRITTEN_VERSION[..3]
    }

    /// The version as `major.minor.patch`.
    pub fn version_text(&self) -> String {
        format!(
            "{}.{}.{}",
            self.version[0], self.version[1], self.version[2]
        )
    }

    pub(crate) fn encode(self) -> [u8; STREAM_HEADER_LEN] {
        let mut out = [0u8; STREAM_HEADER_LEN];
        out[..4].copy_from_slice(&MAGIC);
        out[4..8].copy_from_slice(&self.version);
        out[8] = u8::from(self.compressed);
        out[9] = 2; // protobuf
        out
    }
}

/// The 16 bytes before every message: its kind and length.
pub(crate) fn parse_message_header(bytes: &[u8; MESSAGE_HEADER_LEN]) -> (u64, u64) {
    let mut kind = [0u8; 8];
    let mut len = [0u8; 8];
    kind.copy_from_slice(&bytes[..8]);
    len.copy_from_slice(&bytes[8..]);
    (u64::from_le_bytes(kind), u64::from_le_bytes(len))
}

pub(crate) fn encode_message_header(kind: MessageKind, len: u64) -> [u8; MESSAGE_HEADER_LEN] {
    let mut out = [0u8; MESSAGE_HEADER_LEN];
    out[..8].copy_from_slice(&kind.as_u64().to_le_bytes());
    out[8..].copy_from_slice(&len.to_le_bytes());
    out
}

/// The stream footer: where the footer message's body is, and its checksum.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct StreamFooter {
    pub(crate) footer_start: u64,
    pub(crate) footer_len: u64,
    pub(crate) crc: u32,
}

impl StreamFooter {
    /// Parses the last 32 bytes of a stream; `None` if they are not a stream footer.
    pub(crate) fn parse(bytes: &[u8; STREAM_FOOTER_LEN]) -> Option<Self> {
        let u64_at = |at: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(&bytes[at..at + 8]);
            u64::from_le_bytes(b)
        };
        let tail = &bytes[20..];
        if tail[..4] != MAGIC || tail[4..8] != FOOTER_ID || tail[8..12] != 1u32.to_le_bytes() {
            return None;
        }
        Some(Self {
            footer_start: u64_at(0),
            footer_len: u64_at(8),
            crc: u32::from_le_bytes([bytes[16], bytes[17], bytes[18], bytes[19]]),
        })
    }

    pub(crate) fn for_footer(footer_start: u64, footer: &[u8]) -> Self {
        Self {
            footer_start,
            footer_len: footer.len() as u64,
            crc: crc(footer),
        }
    }

    pub(crate) fn encode(self) -> [u8; STREAM_FOOTER_LEN] {
        let mut out = [0u8; STREAM_FOOTER_LEN];
        out[..8].copy_from_slice(&self.footer_start.to_le_bytes());
        out[8..16].copy_from_slice(&self.footer_len.to_le_bytes());
        out[16..20].copy_from_slice(&self.crc.to_le_bytes());
        out[20..24].copy_from_slice(&MAGIC);
        out[24..28].copy_from_slice(&FOOTER_ID);
        out[28..].copy_from_slice(&1u32.to_le_bytes());
        out
    }
}

/// The footer message's checksum.
pub(crate) fn crc(footer: &[u8]) -> u32 {
    xxhash_rust::xxh32::xxh32(footer, FOOTER_CRC_SEED)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn headers_round_trip_and_bad_ones_are_refused() {
        let header = StreamHeader {
            version: WRITTEN_VERSION,
            compressed: true,
        };
        assert_eq!(StreamHeader::parse(&header.encode()).unwrap(), header);
        let mut old = header.encode();
        old[..4].copy_from_slice(b"RRF1");
        assert!(matches!(
            StreamHeader::parse(&old),
            Err(RrdErrorKind::OldFraming { .. })
        ));
        let mut ancient = header.encode();
        ancient[5] = 22;
        assert!(matches!(
            StreamHeader::parse(&ancient),
            Err(RrdErrorKind::UnsupportedVersion { .. })
        ));
        let mut newer = header.encode();
        newer[3] = b'3';
        assert!(matches!(
            StreamHeader::parse(&newer),
            Err(RrdErrorKind::NewerFraming { .. })
        ));
        let mut msgpack = header.encode();
        msgpack[9] = 1;
        assert!(matches!(
            StreamHeader::parse(&msgpack),
            Err(RrdErrorKind::BadOptions { .. })
        ));
        let footer = StreamFooter::for_footer(99, b"footer");
        assert_eq!(StreamFooter::parse(&footer.encode()), Some(footer));
        let mut bad = footer.encode();
        bad[25] = b'X';
        assert_eq!(StreamFooter::parse(&bad), None);
    }
}
