//! Where an Arrow IPC schema message's bytes are read, and the proof that its schema-level
//! metadata values are read by nothing else.
//!
//! A stream of chunks repeats one schema per entity and column set, and every repeat
//! differs only in metadata values (a chunk's id above all). [`super::schema_cache`] reuses
//! a parsed schema for a message equal to an earlier one outside those values. Equal bytes
//! elsewhere are not enough on their own: flatbuffers lets any table, vtable, vector or
//! string lie anywhere, even inside another string, and its verifier checks bounds, not
//! aliasing. So a hostile message could have a field's name *be* part of a metadata value;
//! changing the value would change the name, while a cache kept the old one.
//!
//! [`SchemaLayout::prove`] closes that hole. It walks a verified schema message the way
//! flatbuffers' verifier (for arrow-ipc's generated `Message` and `Schema` tables) and
//! arrow-ipc's `fb_to_schema` walk it, recording every byte range either reads: each
//! table's offset to its vtable, the vtable, each known field, each vector and string with
//! its length and terminator. A metadata value qualifies as a *slot* only if no recorded
//! range and no other slot touches its content. A message equal to the proven one outside
//! the slots is then, for the verifier and the decoder, the same message with other
//! strings in the slots: it verifies exactly when those strings are UTF-8, and decodes to
//! the same schema with those values.
//!
//! The walk must read at least what the verifier and decoder read, never less; reading
//! more only turns a cacheable message into one decoded in full. It gives up (no proof) on
//! anything it does not know, such as a type tag newer than this walk.

use std::ops::Range;

/// The flatbuffers union tag of `MessageHeader::Schema`.
const HEADER_SCHEMA: u8 = 1;

/// flatbuffers' own nesting limit (`VerifierOptions::max_depth`); a verified message is
/// never deeper, and the walk recurses no further either.
const MAX_DEPTH: usize = 64;

/// A verified schema message whose schema-level metadata values are proven to be read by
/// nothing but themselves.
#[derive(Debug)]
pub(super) struct SchemaLayout {
    /// The schema's metadata entries in message order, as `fb_to_schema` reads them.
    pub(super) entries: Vec<MetadataEntry>,
    /// The content ranges of the entries' values, sorted by start and disjoint: the bytes
    /// that may differ between messages of this layout.
    pub(super) slots: Vec<Range<usize>>,
}

/// One `KeyValue` of the schema's `custom_metadata`.
#[derive(Debug)]
pub(super) struct MetadataEntry {
    /// The key (absent keys make `fb_to_schema` skip the entry, as the cache does).
    pub(super) key: Option<String>,
    /// Where the value's UTF-8 content lies in the message (absent: the entry is skipped).
    pub(super) value: Option<Range<usize>>,
}

impl SchemaLayout {
    /// Walks `message`, the metadata bytes of one IPC message that flatbuffers' verifier
    /// has accepted and arrow-ipc has decoded as a schema, and proves its slots. `None`
    /// when the message is not a schema message, holds something the walk does not know,
    /// or a metadata value's content is touched by anything else.
    pub(super) fn prove(message: &[u8]) -> Option<Self> {
        let mut walk = Walk {
            buf: message,
            read: Vec::new(),
            entries: Vec::new(),
        };
        walk.message().ok()?;
        let Walk { read, entries, .. } = walk;
        let mut slots: Vec<Range<usize>> = entries
            .iter()
            .filter_map(|e| e.value.clone())
            .filter(|r| !r.is_empty())
            .collect();
        slots.sort_unstable_by_key(|r| r.start);
        if slots.windows(2).any(|w| w[0].end > w[1].start) {
            return None;
        }
        // A few slots against every range read: linear, and cheaper than sorting the ranges.
        let untouched = |slot: &Range<usize>| {
            read.iter()
                .all(|r| r.end <= slot.start || r.start >= slot.end)
        };
        slots
            .iter()
            .all(untouched)
            .then_some(Self { entries, slots })
    }
}

/// The walk met something it cannot prove: the message is decoded in full.
struct Unproven;

/// A step of the walk.
type Step<T> = Result<T, Unproven>;

/// A table's position and its vtable's.
struct Table {
    at: usize,
    vtable: usize,
    vtable_len: usize,
}

/// The walk's state: the message, the ranges read so far, and the schema's metadata.
struct Walk<'a> {
    buf: &'a [u8],
    read: Vec<Range<usize>>,
    entries: Vec<MetadataEntry>,
}

impl<'a> Walk<'a> {
    /// Reads `len` bytes at `at`, recording them.
    fn bytes(&mut self, at: usize, len: usize) -> Step<&'a [u8]> {
        let range = at..at.checked_add(len).ok_or(Unproven)?;
        let bytes = self.buf.get(range.clone()).ok_or(Unproven)?;
        // Reads are often consecutive (a vtable's entries, a table's fields): one range.
        match self.read.last_mut() {
            Some(last) if last.end == range.start => last.end = range.end,
            Some(last) if last.start <= range.start && range.end <= last.end => {}
            _ => self.read.push(range),
        }
        Ok(bytes)
    }

    fn u16(&mut self, at: usize) -> Step<u16> {
        let b = self.bytes(at, 2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }

    fn u32(&mut self, at: usize) -> Step<usize> {
        let b = self.bytes(at, 4)?;
        usize::try_from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])).map_err(|_| Unproven)
    }

    /// A table: its signed offset to the vtable and the whole vtable, as the verifier's
    /// `visit_table` reads them.
    fn table(&mut self, at: usize) -> Step<Table> {
        let b = self.bytes(at, 4)?;
        let soffset = i32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let vtable = if soffset > 0 {
            at.checked_sub(soffset.unsigned_abs() as usize)
        } else {
            at.checked_add(soffset.unsigned_abs() as usize)
        }
        .ok_or(Unproven)?;
        let vtable_len = usize::from(self.u16(vtable)?);
        self.bytes(vtable, vtable_len)?;
        Ok(Table {
            at,
            vtable,
            vtable_len,
        })
    }

    /// Where a field lies, if the table has it (as the verifier's `deref`: a vtable entry
    /// beyond the vtable's length, or zero, means absent).
    fn field(&mut self, table: &Table, voffset: u16) -> Step<Option<usize>> {
        if usize::from(voffset) >= table.vtable_len {
            return Ok(None);
        }
        let offset = self.u16(table.vtable + usize::from(voffset))?;
        if offset == 0 {
            return Ok(None);
        }
        Ok(Some(table.at + usize::from(offset)))
    }

    /// A scalar field of `size` bytes; its bytes if present.
    fn scalar(&mut self, table: &Table, voffset: u16, size: usize) -> Step<Option<&'a [u8]>> {
        match self.field(table, voffset)? {
            Some(at) => Ok(Some(self.bytes(at, size)?)),
            None => Ok(None),
        }
    }

    /// An offset field: where the object it points to starts, if present.
    fn offset(&mut self, table: &Table, voffset: u16) -> Step<Option<usize>> {
        match self.field(table, voffset)? {
            Some(at) => Ok(Some(at.checked_add(self.u32(at)?).ok_or(Unproven)?)),
            None => Ok(None),
        }
    }

    /// A vector of `element_size`-byte elements: its length and elements are read. Returns
    /// the elements' range.
    fn vector(&mut self, at: usize, element_size: usize) -> Step<Range<usize>> {
        let len = self.u32(at)?;
        let start = at + 4;
        let size = len.checked_mul(element_size).ok_or(Unproven)?;
        self.bytes(start, size)?;
        Ok(start..start + size)
    }

    /// The tables a vector of offsets points to.
    fn tables(&mut self, at: usize) -> Step<Vec<usize>> {
        let elements = self.vector(at, 4)?;
        elements
            .step_by(4)
            .map(|element| element.checked_add(self.u32(element)?).ok_or(Unproven))
            .collect()
    }

    /// A string: its length and terminator are read, and its content unless it is a slot
    /// (whose content the caller keeps apart). Returns the content's range.
    fn string(&mut self, at: usize, content_is_slot: bool) -> Step<Range<usize>> {
        let len = self.u32(at)?;
        let start = at + 4;
        let end = start.checked_add(len).ok_or(Unproven)?;
        if content_is_slot {
            self.buf.get(start..end).ok_or(Unproven)?;
        } else {
            self.bytes(start, len)?;
        }
        self.bytes(end, 1)?;
        Ok(start..end)
    }

    /// An optional string field.
    fn string_field(
        &mut self,
        table: &Table,
        voffset: u16,
        content_is_slot: bool,
    ) -> Step<Option<Range<usize>>> {
        match self.offset(table, voffset)? {
            Some(at) => Ok(Some(self.string(at, content_is_slot)?)),
            None => Ok(None),
        }
    }

    /// The root `Message` table; only a schema message has a layout.
    fn message(&mut self) -> Step<()> {
        let root = self.u32(0)?;
        let message = self.table(root)?;
        self.scalar(&message, 4, 2)?; // version
        let header_type = self.scalar(&message, 6, 1)?;
        let header = self.offset(&message, 8)?;
        match (header_type, header) {
            (Some([HEADER_SCHEMA]), Some(schema)) => self.schema(schema)?,
            _ => return Err(Unproven),
        }
        self.scalar(&message, 10, 8)?; // bodyLength
        if let Some(metadata) = self.offset(&message, 12)? {
            self.key_values(metadata, false)?;
        }
        Ok(())
    }

    fn schema(&mut self, at: usize) -> Step<()> {
        let schema = self.table(at)?;
        self.scalar(&schema, 4, 2)?; // endianness
        if let Some(fields) = self.offset(&schema, 6)? {
            for field in self.tables(fields)? {
                self.field_table(field, 1)?;
            }
        }
        if let Some(metadata) = self.offset(&schema, 8)? {
            self.key_values(metadata, true)?;
        }
        if let Some(features) = self.offset(&schema, 10)? {
            self.vector(features, 8)?;
        }
        Ok(())
    }

    /// A vector of `KeyValue`s. The schema's own (`are_slots`) keep their values apart as
    /// slots; every other one is read whole.
    fn key_values(&mut self, at: usize, are_slots: bool) -> Step<()> {
        for entry in self.tables(at)? {
            let entry = self.table(entry)?;
            let key = self.string_field(&entry, 4, false)?;
            let value = self.string_field(&entry, 6, are_slots)?;
            if are_slots {
                let key = match key {
                    Some(range) => Some(
                        std::str::from_utf8(&self.buf[range])
                            .map_err(|_| Unproven)?
                            .to_owned(),
                    ),
                    None => None,
                };
                self.entries.push(MetadataEntry { key, value });
            }
        }
        Ok(())
    }

    fn field_table(&mut self, at: usize, depth: usize) -> Step<()> {
        if depth > MAX_DEPTH {
            return Err(Unproven);
        }
        let field = self.table(at)?;
        self.string_field(&field, 4, false)?; // name
        self.scalar(&field, 6, 1)?; // nullable
        let type_tag = self.scalar(&field, 8, 1)?;
        let type_table = self.offset(&field, 10)?;
        match (type_tag, type_table) {
            (Some(&[tag]), Some(table)) => self.type_table(tag, table)?,
            (None, None) => {}
            _ => return Err(Unproven),
        }
        if let Some(dictionary) = self.offset(&field, 12)? {
            let dictionary = self.table(dictionary)?;
            self.scalar(&dictionary, 4, 8)?; // id
            if let Some(index_type) = self.offset(&dictionary, 6)? {
                self.type_table(2, index_type)?; // an `Int`
            }
            self.scalar(&dictionary, 8, 1)?; // isOrdered
            self.scalar(&dictionary, 10, 2)?; // dictionaryKind
        }
        if let Some(children) = self.offset(&field, 14)? {
            for child in self.tables(children)? {
                self.field_table(child, depth + 1)?;
            }
        }
        if let Some(metadata) = self.offset(&field, 16)? {
            self.key_values(metadata, false)?;
        }
        Ok(())
    }

    /// A table of the `Type` union, by its tag (arrow-ipc's generated `Type` constants).
    fn type_table(&mut self, tag: u8, at: usize) -> Step<()> {
        let table = self.table(at)?;
        // (voffset, size) of each scalar field.
        let scalars: &[(u16, usize)] = match tag {
            // Null, Binary, Utf8, Bool, List, Struct_, LargeBinary, LargeUtf8, LargeList,
            // RunEndEncoded, BinaryView, Utf8View, ListView, LargeListView: no fields.
            1 | 4 | 5 | 6 | 12 | 13 | 19..=26 => &[],
            2 => &[(4, 4), (6, 1)], // Int: bitWidth, is_signed
            // FloatingPoint: precision; Date, Timestamp, Interval, Duration: unit; Union:
            // mode (Timestamp's and Union's offsets follow below).
            3 | 8 | 10 | 11 | 14 | 18 => &[(4, 2)],
            7 => &[(4, 4), (6, 4), (8, 4)], // Decimal: precision, scale, bitWidth
            9 => &[(4, 2), (6, 4)],         // Time: unit, bitWidth
            15 | 16 => &[(4, 4)],           // FixedSizeBinary: byteWidth; FixedSizeList: listSize
            17 => &[(4, 1)],                // Map: keysSorted
            _ => return Err(Unproven),
        };
        for &(voffset, size) in scalars {
            self.scalar(&table, voffset, size)?;
        }
        match tag {
            10 => {
                self.string_field(&table, 6, false)?; // Timestamp: timezone
            }
            14 => {
                if let Some(type_ids) = self.offset(&table, 6)? {
                    self.vector(type_ids, 4)?; // Union: typeIds
                }
            }
            _ => {}
        }
        Ok(())
    }
}
