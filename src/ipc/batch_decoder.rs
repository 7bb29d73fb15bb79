//! Our own decoder of an IPC record batch for the arrays chunks are made of: row ids
//! (`FixedSizeBinary`), times (`Int64`, timestamps, durations), and component lists of
//! primitives, booleans, strings, binaries, fixed-size lists and structs. Each array is
//! built with arrow's typed constructors, zero-copy from the message body, after checking
//! every length, offset and alignment they would otherwise assert on.
//!
//! Why: arrow-ipc's batch reader builds an `ArrayData` per array and validates it in full
//! (its cheaper path needs `unsafe`), which was the largest part of decoding a small
//! chunk (`docs/PERFORMANCE.md`, "`.rrd` files"). The typed constructors check what the
//! arrays' safe use relies on (offsets within the values, UTF-8, lengths, nulls where a
//! field allows none) and nothing twice.
//!
//! Anything this decoder does not build (another type, a compressed body, a buffer out of
//! place, counts that disagree) makes it answer `None`, and the caller decodes the
//! message with arrow-ipc instead: its answer, or its error, is the one given. So the two
//! can differ only where this decoder builds a batch arrow-ipc would refuse or build
//! otherwise; the fuzz target `ipc_batch_decoder` checks on every input that they never
//! do, but where arrow-ipc panics (a bug of its own, contained by the caller: it asserts
//! that an offsets buffer is a whole number of offsets long, where this decoder reads the
//! offsets it needs).

use std::cell::Cell;
use std::sync::Arc;

use arrow_array::types::{
    ArrowTimestampType, DurationMicrosecondType, DurationMillisecondType, DurationNanosecondType,
    DurationSecondType, Float16Type, Float32Type, Float64Type, Int8Type, Int16Type, Int32Type,
    Int64Type, TimestampMicrosecondType, TimestampMillisecondType, TimestampNanosecondType,
    TimestampSecondType, UInt8Type, UInt16Type, UInt32Type, UInt64Type,
};
use arrow_array::{
    Array, ArrayRef, ArrowPrimitiveType, BinaryArray, BooleanArray, FixedSizeBinaryArray,
    FixedSizeListArray, ListArray, PrimitiveArray, StringArray, StructArray,
};
use arrow_buffer::{BooleanBuffer, Buffer, NullBuffer, OffsetBuffer, ScalarBuffer};
use arrow_schema::{DataType, Field, Fields, TimeUnit};

use smallvec::SmallVec;

use super::batch_message::BatchHeader;

thread_local! {
    /// Set while [`without`] runs.
    static OFF: Cell<bool> = const { Cell::new(false) };
    /// Batches this decoder built on this thread (for tests and probes).
    static BUILT: Cell<u64> = const { Cell::new(0) };
}

/// How many batches this decoder built on this thread.
#[cfg(test)]
pub(super) fn batches_built() -> u64 {
    BUILT.with(Cell::get)
}

/// Is this decoder on on this thread (not within [`without`])?
pub(super) fn is_on() -> bool {
    !OFF.with(Cell::get)
}

/// Runs `decode` with this decoder off on this thread: every batch goes to arrow-ipc.
pub(super) fn without<T>(decode: impl FnOnce() -> T) -> T {
    super::with_flag_set(&OFF, decode)
}

/// Decodes the batch `header` describes, whose body is `body`, against the schema's
/// `fields`: its columns and row count, checked as `RecordBatch::try_new` checks them (the
/// caller may build a chunk of them without a `RecordBatch`). `None` if this decoder does
/// not build it (see the module docs: the caller asks arrow-ipc).
pub(super) fn decode_batch(
    body: &Buffer,
    header: &BatchHeader,
    fields: &Fields,
) -> Option<(Columns, usize)> {
    if OFF.with(Cell::get) {
        return None;
    }
    let mut reader = Reader {
        body,
        nodes: &header.nodes,
        buffers: &header.buffers,
        next_node: 0,
        next_buffer: 0,
    };
    let mut columns = Columns::with_capacity(fields.len());
    for field in fields {
        columns.push(reader.array(field)?);
    }
    if reader.next_node != reader.nodes.len() || reader.next_buffer != reader.buffers.len() {
        return None;
    }
    let rows = usize::try_from(header.length).ok()?;
    if !is_valid_batch(fields, &columns, rows) {
        return None;
    }
    BUILT.with(|count| count.set(count.get() + 1));
    Some((columns, rows))
}

/// Would `RecordBatch::try_new_with_options` accept `columns` of `rows` rows for `fields`
/// (with its default options, as arrow-ipc's reader builds a batch)? The same checks: a
/// column per field, no nulls in a non-nullable field, every column `rows` long, and each
/// of exactly its field's type.
fn is_valid_batch(fields: &Fields, columns: &[ArrayRef], rows: usize) -> bool {
    fields.len() == columns.len()
        && fields.iter().zip(columns).all(|(field, column)| {
            (field.is_nullable() || column.null_count() == 0)
                && column.len() == rows
                && column.data_type() == field.data_type()
        })
}

/// A batch's columns: a chunk's few stay inline.
pub(super) type Columns = SmallVec<[ArrayRef; 8]>;

/// A part of the batch this decoder does not build (arrow-ipc decodes the batch instead).
struct NotBuilt;

/// The nodes (length, null count) and buffers (offset, length) of one batch, taken in the
/// order of the schema's fields, depth first (the IPC format's order).
struct Reader<'a> {
    body: &'a Buffer,
    nodes: &'a [(i64, i64)],
    buffers: &'a [(i64, i64)],
    next_node: usize,
    next_buffer: usize,
}

impl Reader<'_> {
    /// The next node: its length and null count.
    fn node(&mut self) -> Option<(usize, usize)> {
        let &(length, null_count) = self.nodes.get(self.next_node)?;
        self.next_node += 1;
        Some((
            usize::try_from(length).ok()?,
            usize::try_from(null_count).ok()?,
        ))
    }

    /// The next buffer, a slice of the body (zero-copy).
    fn buffer(&mut self) -> Option<Buffer> {
        let &(offset, length) = self.buffers.get(self.next_buffer)?;
        self.next_buffer += 1;
        let start = usize::try_from(offset).ok()?;
        let length = usize::try_from(length).ok()?;
        if start.checked_add(length)? > self.body.len() {
            return None;
        }
        Some(self.body.slice_with_length(start, length))
    }

    /// The next buffer as the validity of `len` slots holding `null_count` nulls; no
    /// validity where the count is 0 (arrow-ipc ignores the buffer then too).
    fn nulls(&mut self, len: usize, null_count: usize) -> Result<Option<NullBuffer>, NotBuilt> {
        let buffer = self.buffer().ok_or(NotBuilt)?;
        if null_count == 0 {
            return Ok(None);
        }
        let nulls = NullBuffer::new(bits(buffer, len).ok_or(NotBuilt)?);
        if nulls.null_count() == null_count {
            Ok(Some(nulls))
        } else {
            Err(NotBuilt)
        }
    }

    /// The next buffer as `len + 1` offsets that start at 0 or more and never decrease.
    fn offsets(&mut self, len: usize) -> Option<OffsetBuffer<i32>> {
        let offsets: ScalarBuffer<i32> = scalars(self.buffer()?, len.checked_add(1)?)?;
        let valid = offsets.first().is_some_and(|&first| first >= 0)
            && offsets.windows(2).all(|pair| pair[0] <= pair[1]);
        // Checked above: `OffsetBuffer::new` would assert the same.
        valid.then(|| OffsetBuffer::new(offsets))
    }

    /// The array of `field` (its node, its buffers, its children's).
    fn array(&mut self, field: &Field) -> Option<ArrayRef> {
        let (len, null_count) = self.node()?;
        let array: ArrayRef = match field.data_type() {
            DataType::Boolean => {
                let nulls = self.nulls(len, null_count).ok()?;
                Arc::new(BooleanArray::new(bits(self.buffer()?, len)?, nulls))
            }
            DataType::Int8 => self.primitive::<Int8Type>(len, null_count)?,
            DataType::Int16 => self.primitive::<Int16Type>(len, null_count)?,
            DataType::Int32 => self.primitive::<Int32Type>(len, null_count)?,
            DataType::Int64 => self.primitive::<Int64Type>(len, null_count)?,
            DataType::UInt8 => self.primitive::<UInt8Type>(len, null_count)?,
            DataType::UInt16 => self.primitive::<UInt16Type>(len, null_count)?,
            DataType::UInt32 => self.primitive::<UInt32Type>(len, null_count)?,
            DataType::UInt64 => self.primitive::<UInt64Type>(len, null_count)?,
            DataType::Float16 => self.primitive::<Float16Type>(len, null_count)?,
            DataType::Float32 => self.primitive::<Float32Type>(len, null_count)?,
            DataType::Float64 => self.primitive::<Float64Type>(len, null_count)?,
            // Rerun's timestamp and duration timelines.
            DataType::Timestamp(unit, zone) => {
                let array: ArrayRef = match unit {
                    TimeUnit::Second => {
                        self.timestamps::<TimestampSecondType>(len, null_count, zone.as_ref())?
                    }
                    TimeUnit::Millisecond => {
                        self.timestamps::<TimestampMillisecondType>(len, null_count, zone.as_ref())?
                    }
                    TimeUnit::Microsecond => {
                        self.timestamps::<TimestampMicrosecondType>(len, null_count, zone.as_ref())?
                    }
                    TimeUnit::Nanosecond => {
                        self.timestamps::<TimestampNanosecondType>(len, null_count, zone.as_ref())?
                    }
                };
                array
            }
            DataType::Duration(TimeUnit::Second) => {
                self.primitive::<DurationSecondType>(len, null_count)?
            }
            DataType::Duration(TimeUnit::Millisecond) => {
                self.primitive::<DurationMillisecondType>(len, null_count)?
            }
            DataType::Duration(TimeUnit::Microsecond) => {
                self.primitive::<DurationMicrosecondType>(len, null_count)?
            }
            DataType::Duration(TimeUnit::Nanosecond) => {
                self.primitive::<DurationNanosecondType>(len, null_count)?
            }
            DataType::Utf8 => {
                let nulls = self.nulls(len, null_count).ok()?;
                let offsets = self.offsets(len)?;
                Arc::new(StringArray::try_new(offsets, self.buffer()?, nulls).ok()?)
            }
            DataType::Binary => {
                let nulls = self.nulls(len, null_count).ok()?;
                let offsets = self.offsets(len)?;
                Arc::new(BinaryArray::try_new(offsets, self.buffer()?, nulls).ok()?)
            }
            DataType::FixedSizeBinary(size) => {
                let nulls = self.nulls(len, null_count).ok()?;
                let width = usize::try_from(*size).ok().filter(|&w| w > 0)?;
                let values = self.buffer()?;
                let bytes = len.checked_mul(width)?;
                if values.len() < bytes {
                    return None;
                }
                let values = values.slice_with_length(0, bytes);
                Arc::new(FixedSizeBinaryArray::try_new(*size, values, nulls).ok()?)
            }
            DataType::List(item) => {
                let nulls = self.nulls(len, null_count).ok()?;
                let offsets = self.offsets(len)?;
                let values = self.array(item)?;
                Arc::new(ListArray::try_new(Arc::clone(item), offsets, values, nulls).ok()?)
            }
            DataType::FixedSizeList(item, size) => {
                let nulls = self.nulls(len, null_count).ok()?;
                let width = usize::try_from(*size).ok().filter(|&w| w > 0)?;
                // Exactly the values the lists hold, as for a struct's children below:
                // being stricter than arrow-ipc costs a fallback, never an answer.
                let values = self.array(item)?;
                if values.len() != len.checked_mul(width)? {
                    return None;
                }
                Arc::new(FixedSizeListArray::try_new(Arc::clone(item), *size, values, nulls).ok()?)
            }
            DataType::Struct(fields) if !fields.is_empty() => {
                let nulls = self.nulls(len, null_count).ok()?;
                let mut children = Vec::with_capacity(fields.len());
                for child in fields {
                    // arrow-ipc refuses a child of another length than its struct's.
                    let array = self.array(child)?;
                    if array.len() != len {
                        return None;
                    }
                    children.push(array);
                }
                Arc::new(StructArray::try_new(fields.clone(), children, nulls).ok()?)
            }
            _ => return None,
        };
        (array.len() == len).then_some(array)
    }

    /// A primitive array of `len` values, with its validity.
    fn primitive<T: ArrowPrimitiveType>(
        &mut self,
        len: usize,
        null_count: usize,
    ) -> Option<ArrayRef> {
        Some(Arc::new(self.primitive_array::<T>(len, null_count)?))
    }

    fn primitive_array<T: ArrowPrimitiveType>(
        &mut self,
        len: usize,
        null_count: usize,
    ) -> Option<PrimitiveArray<T>> {
        let nulls = self.nulls(len, null_count).ok()?;
        let values = scalars::<T::Native>(self.buffer()?, len)?;
        PrimitiveArray::<T>::try_new(values, nulls).ok()
    }

    /// A timestamp array in the time zone of its field (`zone`).
    fn timestamps<T: ArrowTimestampType>(
        &mut self,
        len: usize,
        null_count: usize,
        zone: Option<&Arc<str>>,
    ) -> Option<ArrayRef> {
        let array = self.primitive_array::<T>(len, null_count)?;
        Some(Arc::new(array.with_timezone_opt(zone.cloned())))
    }
}

/// The first `len` bits of `buffer`, if it has them.
fn bits(buffer: Buffer, len: usize) -> Option<BooleanBuffer> {
    if buffer.len().checked_mul(8)? < len {
        return None;
    }
    Some(BooleanBuffer::new(buffer, 0, len))
}

/// The first `len` values of type `T` in `buffer`, if it holds them and is aligned for
/// `T` (checked here: `ScalarBuffer::new` asserts both). A misaligned buffer is left to
/// arrow-ipc, which copies it.
fn scalars<T: arrow_buffer::ArrowNativeType>(
    buffer: Buffer,
    len: usize,
) -> Option<ScalarBuffer<T>> {
    let bytes = len.checked_mul(std::mem::size_of::<T>())?;
    if buffer.len() < bytes || buffer.as_ptr().align_offset(std::mem::align_of::<T>()) != 0 {
        return None;
    }
    Some(ScalarBuffer::new(buffer, 0, len))
}
