//! The little of the protobuf wire format that `.rrd` messages use: varints, fixed64 and
//! length-delimited fields, read with bounds checks and written by hand.
//!
//! Why not `prost`: the messages are six small structs, read once each; a reader of our
//! own names the byte offset of a fault in the file, checks every length against the bytes
//! that remain before taking them (so a hostile length never allocates), hands out
//! zero-copy slices of the payload, and costs no derive macros in the build.

use super::error::RrdErrorKind;

/// The wire types protobuf uses (3 and 4, groups, are long deprecated and refused).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum WireValue<'a> {
    Varint(u64),
    Fixed64(u64),
    Bytes(&'a [u8]),
    Fixed32(u32),
}

/// A field read from a message: its number, its value and where the value starts in the
/// message (to name offsets in errors and to slice payloads without copying).
#[derive(Debug, Clone, Copy)]
pub(crate) struct WireField<'a> {
    pub(crate) number: u32,
    pub(crate) value: WireValue<'a>,
    pub(crate) value_start: usize,
}

/// Iterates over the fields of one encoded message.
pub(crate) struct FieldReader<'a> {
    bytes: &'a [u8],
    position: usize,
}

/// A fault inside a message: the offset in the message and what is wrong.
pub(crate) type WireError = (usize, RrdErrorKind);

impl<'a> FieldReader<'a> {
    pub(crate) fn new(bytes: &'a [u8]) -> Self {
        Self { bytes, position: 0 }
    }

    fn varint(&mut self) -> Result<u64, WireError> {
        // Keys, lengths of small fields and enums are one byte.
        if let Some(&byte) = self.bytes.get(self.position)
            && byte < 0x80
        {
            self.position += 1;
            return Ok(u64::from(byte));
        }
        let start = self.position;
        match varint_at(self.bytes, start) {
            Ok(Some((value, end))) => {
                self.position = end;
                Ok(value)
            }
            Ok(None) => Err((start, protobuf("varint runs past the end of the message"))),
            Err(()) => Err((start, protobuf("varint longer than ten bytes"))),
        }
    }

    fn take(&mut self, len: u64) -> Result<&'a [u8], WireError> {
        let start = self.position;
        let remaining = self.bytes.len() - self.position;
        match usize::try_from(len) {
            Ok(len) if len <= remaining => {
                self.position += len;
                Ok(&self.bytes[start..start + len])
            }
            _ => Err((
                start,
                protobuf(&format!(
                    "field claims {len} bytes but the message has {remaining} left"
                )),
            )),
        }
    }

    /// The next field, `None` at the end of the message.
    pub(crate) fn next_field(&mut self) -> Result<Option<WireField<'a>>, WireError> {
        if self.position == self.bytes.len() {
            return Ok(None);
        }
        let key_start = self.position;
        let key = self.varint()?;
        let number = u32::try_from(key >> 3)
            .ok()
            .filter(|&n| n != 0)
            // Lazily: the message is built for a bad key only, not for every field.
            .ok_or_else(|| (key_start, protobuf(&format!("invalid field key {key}"))))?;
        let value_start = self.position;
        let value = match key & 7 {
            0 => WireValue::Varint(self.varint()?),
            1 => {
                let b = self.take(8)?;
                let mut le = [0u8; 8];
                le.copy_from_slice(b);
                WireValue::Fixed64(u64::from_le_bytes(le))
            }
            2 => {
                let len_start = self.position;
                let len = self.varint()?;
                let value_start = self.position;
                // A bad length is reported where the length field starts.
                let bytes = self.take(len).map_err(|(_, e)| (len_start, e))?;
                return Ok(Some(WireField {
                    number,
                    value: WireValue::Bytes(bytes),
                    value_start,
                }));
            }
            5 => {
                let b = self.take(4)?;
                WireValue::Fixed32(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            }
            other => {
                return Err((
                    key_start,
                    protobuf(&format!("unsupported wire type {other} (field {number})")),
                ));
            }
        };
        Ok(Some(WireField {
            number,
            value,
            value_start,
        }))
    }
}

fn protobuf(reason: &str) -> RrdErrorKind {
    RrdErrorKind::Protobuf {
        reason: reason.to_owned(),
    }
}

impl<'a> WireField<'a> {
    /// The value as a varint, or an error naming the field.
    pub(crate) fn varint(&self, message: &str) -> Result<u64, WireError> {
        match self.value {
            WireValue::Varint(v) => Ok(v),
            _ => Err(self.wrong_type(message, "a varint")),
        }
    }

    pub(crate) fn fixed64(&self, message: &str) -> Result<u64, WireError> {
        match self.value {
            WireValue::Fixed64(v) => Ok(v),
            _ => Err(self.wrong_type(message, "a fixed64")),
        }
    }

    pub(crate) fn bytes(&self, message: &str) -> Result<&'a [u8], WireError> {
        match self.value {
            WireValue::Bytes(b) => Ok(b),
            _ => Err(self.wrong_type(message, "length-delimited")),
        }
    }

    /// The value as a nested message, decoded by `decode`; offsets in its errors count from
    /// the start of the outer message, as every other offset does.
    pub(crate) fn nested<T>(
        &self,
        message: &str,
        decode: impl FnOnce(&'a [u8]) -> Result<T, WireError>,
    ) -> Result<T, WireError> {
        let base = self.value_start;
        decode(self.bytes(message)?).map_err(|(at, e)| (at + base, e))
    }

    pub(crate) fn string(&self, message: &str) -> Result<String, WireError> {
        let bytes = self.bytes(message)?;
        std::str::from_utf8(bytes).map(str::to_owned).map_err(|_| {
            (
                self.value_start,
                protobuf(&format!("{message} field {} is not UTF-8", self.number)),
            )
        })
    }

    fn wrong_type(&self, message: &str, expected: &str) -> WireError {
        (
            self.value_start,
            protobuf(&format!(
                "{message} field {} should be {expected}",
                self.number
            )),
        )
    }
}

/// A varint at `at`: `Ok(Some((value, end)))`, `Ok(None)` if `bytes` end inside it, `Err`
/// if it is longer than ten bytes.
fn varint_at(bytes: &[u8], at: usize) -> Result<Option<(u64, usize)>, ()> {
    let mut value = 0u64;
    for (i, shift) in (0..64).step_by(7).enumerate() {
        let Some(&byte) = bytes.get(at + i) else {
            return Ok(None);
        };
        value |= u64::from(byte & 0x7f) << shift;
        if byte < 0x80 {
            return Ok(Some((value, at + i + 1)));
        }
    }
    Err(())
}

/// Where the field starting at `at` ends (it may run past the end of `bytes`): `Ok(None)`
/// if `bytes` end inside its key or length, `Err` for a key no real message has (field
/// 0, a group, a wire type that does not exist) or an overlong varint. Only the framing
/// is read, never a value: a walk over a message's fields is as cheap as their number.
fn field_end(bytes: &[u8], at: usize) -> Result<Option<u64>, ()> {
    let Some((key, after_key)) = varint_at(bytes, at)? else {
        return Ok(None);
    };
    if key >> 3 == 0 || key >> 3 > u64::from(u32::MAX >> 3) {
        return Err(());
    }
    Ok(match key & 7 {
        0 => varint_at(bytes, after_key)?.map(|(_, end)| end as u64),
        1 => Some(after_key as u64 + 8),
        5 => Some(after_key as u64 + 4),
        2 => varint_at(bytes, after_key)?.map(|(len, start)| (start as u64).saturating_add(len)),
        _ => return Err(()),
    })
}

/// Could `prefix` be the first bytes of a message `len` bytes long? Every whole field it
/// holds must end within `len`, and a field cut off by the end of `prefix` must claim no
/// more than `len` either; a key of field 0 or of a group is never the start of a real
/// message. What tells a write cut short (a prefix of a real message) from a length that
/// was damaged: past a real message's end come the next frame's header bytes, whose first
/// byte (a message kind, 0 to 3) is no valid key.
pub(crate) fn could_start_message_of(prefix: &[u8], len: u64) -> bool {
    if prefix.len() as u64 > len {
        return false;
    }
    let mut at = 0usize;
    while at < prefix.len() {
        let end = match field_end(prefix, at) {
            Ok(Some(end)) => end,
            // Cut off inside its key or length.
            Ok(None) => return true,
            Err(()) => return false,
        };
        if end > len {
            return false;
        }
        match usize::try_from(end) {
            Ok(end) if end <= prefix.len() => at = end,
            // Cut off inside this field, which fits.
            _ => return true,
        }
    }
    true
}

/// Do `bytes` read as whole protobuf fields, the last ending exactly at their end? `Err`
/// names where the first field that does not starts. A frame whose length was damaged
/// fails this: its body ends inside a field, or runs into the next frame's header.
pub(crate) fn whole_message(bytes: &[u8]) -> Result<(), usize> {
    let mut at = 0usize;
    while at < bytes.len() {
        match field_end(bytes, at) {
            Ok(Some(end)) if end <= bytes.len() as u64 => {
                at = usize::try_from(end).map_err(|_| at)?;
            }
            _ => return Err(at),
        }
    }
    Ok(())
}

/// Appends protobuf fields to a buffer.
#[derive(Default)]
pub(crate) struct FieldWriter {
    pub(crate) bytes: Vec<u8>,
}

impl FieldWriter {
    fn raw_varint(&mut self, mut value: u64) {
        while value >= 0x80 {
            self.bytes.push(value.to_le_bytes()[0] | 0x80);
            value >>= 7;
        }
        self.bytes.push(value.to_le_bytes()[0]);
    }

    fn key(&mut self, number: u32, wire_type: u64) {
        self.raw_varint((u64::from(number) << 3) | wire_type);
    }

    pub(crate) fn varint(&mut self, number: u32, value: u64) -> &mut Self {
        self.key(number, 0);
        self.raw_varint(value);
        self
    }

    pub(crate) fn fixed64(&mut self, number: u32, value: u64) -> &mut Self {
        self.key(number, 1);
        self.bytes.extend_from_slice(&value.to_le_bytes());
        self
    }

    pub(crate) fn bytes(&mut self, number: u32, value: &[u8]) -> &mut Self {
        self.key(number, 2);
        self.raw_varint(value.len() as u64);
        self.bytes.extend_from_slice(value);
        self
    }

    /// A nested message, written by `build` into its own buffer.
    pub(crate) fn message(&mut self, number: u32, build: impl FnOnce(&mut Self)) -> &mut Self {
        let mut inner = Self::default();
        build(&mut inner);
        self.bytes(number, &inner.bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_round_trip_and_unknown_ones_are_readable() {
        let mut w = FieldWriter::default();
        w.varint(1, 300)
            .fixed64(2, u64::MAX)
            .bytes(3, b"abc")
            .message(4, |m| {
                m.varint(1, 7);
            });
        let mut r = FieldReader::new(&w.bytes);
        let f = r.next_field().unwrap().unwrap();
        assert_eq!((f.number, f.varint("t").unwrap()), (1, 300));
        let f = r.next_field().unwrap().unwrap();
        assert_eq!(f.fixed64("t").unwrap(), u64::MAX);
        let f = r.next_field().unwrap().unwrap();
        assert_eq!(f.bytes("t").unwrap(), b"abc");
        assert!(f.varint("t").is_err(), "a wrong wire type is an error");
        let f = r.next_field().unwrap().unwrap();
        assert_eq!(f.bytes("t").unwrap(), &[0x08, 7]);
        assert!(r.next_field().unwrap().is_none());
    }

    #[test]
    fn hostile_lengths_and_varints_are_errors() {
        // Field 1, length-delimited, claiming 2^63 bytes.
        let mut w = FieldWriter::default();
        w.key(1, 2);
        w.raw_varint(1 << 63);
        let err = FieldReader::new(&w.bytes).next_field().unwrap_err();
        assert_eq!(err.0, 1);
        assert!(matches!(
            FieldReader::new(&[0x08, 0xff]).next_field(),
            Err((1, _))
        ));
        assert!(FieldReader::new(&[0x08]).next_field().is_err(), "no value");
        let eleven = [
            0x08, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0x01,
        ];
        assert!(FieldReader::new(&eleven).next_field().is_err());
        assert!(FieldReader::new(&[0x0b]).next_field().is_err(), "groups");
        assert!(FieldReader::new(&[0x00]).next_field().is_err(), "field 0");
    }
}
