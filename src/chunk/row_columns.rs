//! [`RowColumns`]: the rows of small chunks of one layout, copied into growing columns as
//! the chunks arrive, so that a full fan of them becomes one chunk without a gather.
//!
//! The write buffer (`store/buffer.rs`) holds a streamed entity's one-row chunks until
//! `merge_fanout` of them are merged. A gather at that point reads every source chunk
//! again (its struct, row ids, time column, component column and leaf: cold lines by
//! then) and pays a setup per source and per column: most of a streamed row's merge. Here
//! each chunk's rows are appended while the chunk is still in cache, a few bulk copies,
//! and the merge builds the chunk from the columns, ordered as a gather of the same
//! chunks would be (`compaction/rewrite.rs`: by time on the first timeline, then row id).
//! A one-row chunk's row goes straight to its place in that order, so rows arriving out
//! of order cost a few moves each rather than a sort and a copy of every column.
//!
//! Only the shape streamed rows mostly have is kept: every component's cells one instance
//! each (or null), of primitives or fixed-size lists of them with no null instance.
//! Chunks of any other shape leave their group without columns, and the merge gathers.

use arrow_array::Array;
use arrow_buffer::{MutableBuffer, NullBuffer, ScalarBuffer};
use arrow_schema::DataType;
use smallvec::SmallVec;

use super::data_types::{instance_bytes, leaf_shape};
use super::rewrite::single_values_list;
use super::{Buffers, Chunk, ChunkError, RawComponentColumns, RawTimeColumns};
use crate::{ChunkId, RowId};

/// Rows of chunks of one layout in growing columns: see the module docs.
#[derive(Debug, PartialEq)]
pub(crate) struct RowColumns {
    /// Has a chunk of several rows been appended since the rows were last in order? A
    /// one-row chunk's row goes straight to its place, so only those can leave them out of
    /// order, and [`RowColumns::build`] then sorts.
    unordered: bool,
    row_ids: Vec<RowId>,
    /// Per time column of the layout.
    times: SmallVec<[Vec<i64>; 1]>,
    /// Per component column of the layout.
    cells: SmallVec<[CellColumn; 1]>,
}

/// One component's cells: each row's leaf values, `width` bytes (a null cell's slot too,
/// as one instance per row lays it out), and which cells are valid. The bytes are in an
/// Arrow buffer, aligned for any primitive, which the built chunk takes over as it is.
#[derive(Debug)]
struct CellColumn {
    width: usize,
    bytes: MutableBuffer,
    /// `None` while every cell is valid.
    valid: Option<Vec<bool>>,
}

/// A copy (a store's clone copies the writer's part of every entity) keeps each column's
/// room, so that the copy's next push does not reallocate every column.
impl Clone for RowColumns {
    fn clone(&self) -> Self {
        fn with_room<T: Copy>(values: &[T], room: usize) -> Vec<T> {
            let mut copy = Vec::with_capacity(room.max(values.len()));
            copy.extend_from_slice(values);
            copy
        }
        Self {
            unordered: self.unordered,
            row_ids: with_room(&self.row_ids, self.row_ids.capacity()),
            times: self
                .times
                .iter()
                .map(|times| with_room(times, times.capacity()))
                .collect(),
            cells: self.cells.clone(),
        }
    }
}

/// The same cells, whatever room each buffer has left (Arrow's own equality compares that
/// too).
impl PartialEq for CellColumn {
    fn eq(&self, other: &Self) -> bool {
        self.width == other.width
            && self.bytes.as_slice() == other.bytes.as_slice()
            && self.valid == other.valid
    }
}

/// See [`RowColumns`]'s `Clone`: the copy keeps the buffer's room.
impl Clone for CellColumn {
    fn clone(&self) -> Self {
        let mut bytes = MutableBuffer::with_capacity(self.bytes.capacity());
        bytes.extend_from_slice(self.bytes.as_slice());
        Self {
            width: self.width,
            bytes,
            valid: self.valid.clone(),
        }
    }
}

impl RowColumns {
    /// Columns holding `chunk`'s rows, with room for `rows` in all (growing row by row
    /// reallocated each column four times per fan), or `None` if its shape is not kept
    /// (see the module docs).
    pub(crate) fn start(chunk: &Chunk, rows: usize) -> Option<Self> {
        let rows = rows.max(chunk.num_rows());
        let mut cells = SmallVec::with_capacity(chunk.components.len());
        for column in &chunk.components {
            let width = instance_bytes(column.list.data_type())?;
            cells.push(CellColumn {
                width,
                bytes: MutableBuffer::with_capacity(rows.checked_mul(width)?),
                valid: None,
            });
        }
        let mut columns = Self {
            unordered: false,
            row_ids: Vec::with_capacity(rows),
            times: chunk
                .time_columns
                .iter()
                .map(|_| Vec::with_capacity(rows))
                .collect(),
            cells,
        };
        columns.append(chunk).then_some(columns)
    }

    /// Appends `chunk`'s rows (a chunk of the layout the columns were started with);
    /// returns false, leaving the columns unusable, if its shape is not kept.
    #[must_use = "columns a chunk did not fit in must be dropped"]
    pub(crate) fn append(&mut self, chunk: &Chunk) -> bool {
        if chunk.time_columns.len() != self.times.len()
            || chunk.components.len() != self.cells.len()
        {
            return false;
        }
        let before = self.row_ids.len();
        let num_rows = chunk.num_rows();
        for (cells, column) in self.cells.iter_mut().zip(&chunk.components) {
            let Some(leaf) = column.null_free_leaf() else {
                return false;
            };
            if !column.one_instance_per_row {
                return false;
            }
            let span = leaf
                .first_item
                .checked_mul(cells.width)
                .and_then(|start| Some((start, start.checked_add(num_rows * cells.width)?)));
            let Some(bytes) = span.and_then(|(start, end)| leaf.values.as_slice().get(start..end))
            else {
                return false;
            };
            push_bytes(&mut cells.bytes, bytes);
            if column.list.null_count() > 0 || cells.valid.is_some() {
                let valid = cells.valid.get_or_insert_with(|| vec![true; before]);
                valid.extend((0..num_rows).map(|row| column.list.is_valid(row)));
            }
        }
        // A streamed row's chunk holds one row: a push each, not a copy of unknown length
        // (a call to `memcpy` per column), then moved to its place if it arrived early.
        if let [row_id] = *chunk.row_ids {
            self.row_ids.push(row_id);
            for (times, column) in self.times.iter_mut().zip(&chunk.time_columns) {
                times.extend(column.times.first());
            }
            self.place_last_row();
        } else {
            self.row_ids.extend_from_slice(&chunk.row_ids);
            for (times, column) in self.times.iter_mut().zip(&chunk.time_columns) {
                times.extend_from_slice(&column.times);
            }
            self.unordered = true;
        }
        true
    }

    /// Moves the last row to its place by (time on the first timeline, row id), after the
    /// rows equal to it (a stable sort's place), if the rows before it are in order: a few
    /// rows moved each time one arrives early, rather than a sort and a copy of every
    /// column when the fan is merged.
    fn place_last_row(&mut self) {
        let (Some(times), Some(last)) = (self.times.first(), self.row_ids.len().checked_sub(1))
        else {
            return;
        };
        if self.unordered {
            return;
        }
        let key = |row: usize| (times[row], self.row_ids[row]);
        let new = key(last);
        if last == 0 || key(last - 1) <= new {
            return;
        }
        // The first row after the new one's key: a binary search over the rows before it.
        let (mut place, mut end) = (0, last);
        while place < end {
            let middle = place + (end - place) / 2;
            if key(middle) <= new {
                place = middle + 1;
            } else {
                end = middle;
            }
        }
        // Each column's last value moves to `place` and the values from there shift up
        // one: a move of memory each, where a slice rotation is a loop of swaps.
        move_last_to(&mut self.row_ids, place);
        for times in &mut self.times {
            move_last_to(times, place);
        }
        for cells in &mut self.cells {
            let width = cells.width;
            let bytes = cells.bytes.as_slice_mut();
            let mut value = [0; 16];
            if let Some(value) = value.get_mut(..width) {
                value.copy_from_slice(&bytes[last * width..]);
                bytes.copy_within(place * width..last * width, (place + 1) * width);
                bytes[place * width..(place + 1) * width].copy_from_slice(value);
            } else {
                bytes[place * width..].rotate_right(width);
            }
            if let Some(valid) = &mut cells.valid {
                move_last_to(valid, place);
            }
        }
    }

    /// Number of rows held.
    pub(crate) fn num_rows(&self) -> usize {
        self.row_ids.len()
    }

    /// One chunk of every row held, under a new id, in the order a gather of the chunks
    /// appended would give (by time on the first timeline, then row id; rows already in
    /// that order keep it, and their columns become the chunk's without a copy); `layout`
    /// is any chunk of the layout (its names, types and metadata). Built and checked like
    /// every chunk ([`Chunk::from_raw`]). `None` if `layout` is not the columns' layout,
    /// which the write buffer never lets happen; an error only if Arrow refuses what a
    /// valid layout gives, which would be a bug.
    pub(crate) fn build(self, layout: &Chunk) -> Option<Result<Chunk, ChunkError>> {
        if layout.time_columns.len() != self.times.len()
            || layout.components.len() != self.cells.len()
            || self.row_ids.is_empty()
        {
            return None;
        }
        let order = self.order();
        let num_rows = self.num_rows();
        let pick = |position: usize| order.as_ref().map_or(position, |order| order[position]);
        let row_ids: Vec<RowId> = match &order {
            None => self.row_ids,
            Some(order) => order.iter().map(|&row| self.row_ids[row]).collect(),
        };
        let mut times = RawTimeColumns::new();
        for (column, values) in layout.time_columns.iter().zip(self.times) {
            let ordered: Vec<i64> = match &order {
                None => values,
                Some(order) => order.iter().map(|&row| values[row]).collect(),
            };
            times.push(column.rebuilt(ScalarBuffer::from(ordered)));
        }
        let mut components = RawComponentColumns::new();
        for (column, cells) in layout.components.iter().zip(self.cells) {
            let DataType::List(item_field) = column.list.data_type() else {
                return None;
            };
            let (leaf_type, fixed_size) = leaf_shape(column.list.data_type())?;
            if cells.bytes.len() != num_rows * cells.width {
                return None;
            }
            let values = match &order {
                None => cells.bytes,
                Some(order) => {
                    let mut values = MutableBuffer::with_capacity(cells.bytes.len());
                    for &row in order {
                        let start = row * cells.width;
                        values.extend_from_slice(&cells.bytes[start..start + cells.width]);
                    }
                    values
                }
            };
            let nulls = cells.valid.as_ref().map(|valid| {
                (0..num_rows)
                    .map(|p| valid[pick(p)])
                    .collect::<NullBuffer>()
            });
            // List offsets are `i32`s, and a write buffer's fan far smaller.
            let num_cells = i32::try_from(num_rows).ok()?;
            let array = single_values_list(
                item_field,
                leaf_type,
                fixed_size,
                num_cells,
                values.into(),
                nulls,
            );
            match array {
                Ok(array) => components.push(column.rebuilt(array)),
                Err(error) => return Some(Err(error)),
            }
        }
        Some(Chunk::from_raw(
            ChunkId::new(),
            layout.entity_path.clone(),
            row_ids,
            times,
            components,
            layout.extra_metadata.clone(),
            Buffers::Unknown,
        ))
    }

    /// The rows' positions sorted by (time on the first timeline, row id), stably; `None`
    /// if they are in that order already.
    fn order(&self) -> Option<Vec<usize>> {
        if !self.unordered {
            return None;
        }
        let times = self.times.first()?;
        let key = |row: usize| (times[row], self.row_ids[row]);
        if (1..self.num_rows()).all(|row| key(row - 1) <= key(row)) {
            return None;
        }
        let mut order: Vec<usize> = (0..self.num_rows()).collect();
        order.sort_by_key(|&row| key(row));
        Some(order)
    }
}

/// Moves the last of `values` to `place`, the ones from there up one.
fn move_last_to<T>(values: &mut Vec<T>, place: usize) {
    if let Some(last) = values.pop() {
        values.insert(place, last);
    }
}

/// Appends `bytes` to `buffer`: the widths of one primitive value as a push of that width
/// (the usual one-row, one-value cell), anything else as a copy.
fn push_bytes(buffer: &mut MutableBuffer, bytes: &[u8]) {
    if let Ok(value) = <[u8; 8]>::try_from(bytes) {
        buffer.push(u64::from_ne_bytes(value));
    } else if let Ok(value) = <[u8; 4]>::try_from(bytes) {
        buffer.push(u32::from_ne_bytes(value));
    } else {
        buffer.extend_from_slice(bytes);
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::builder::{FixedSizeListBuilder, Float32Builder, ListBuilder};
    use arrow_array::{ArrayRef, Float64Array, ListArray, StringArray};

    use super::RowColumns;
    use crate::chunk::RowSource;
    use crate::{Chunk, ChunkBuilder, ChunkId, EntityPath, RowId, Timeline};

    fn scalar_row(frame: i64, log_time: i64, value: Option<f64>) -> Chunk {
        // A null cell spanning one instance, as one instance per row lays it out (a null
        // cell of no instance is another shape, which the columns do not keep).
        let values = ListArray::try_new(
            Arc::new(arrow_schema::Field::new(
                "item",
                arrow_schema::DataType::Float64,
                true,
            )),
            arrow_buffer::OffsetBuffer::new(vec![0, 1].into()),
            Arc::new(Float64Array::from(vec![value.unwrap_or(0.0)])),
            value
                .is_none()
                .then(|| arrow_buffer::NullBuffer::from(vec![false])),
        )
        .unwrap();
        Chunk::try_new(
            ChunkId::new(),
            EntityPath::parse("e").unwrap(),
            vec![RowId::new()],
            vec![
                (
                    Timeline::sequence("frame"),
                    Arc::new(arrow_array::Int64Array::from(vec![frame])) as ArrayRef,
                ),
                (
                    Timeline::sequence("tick"),
                    Arc::new(arrow_array::Int64Array::from(vec![log_time])) as ArrayRef,
                ),
            ],
            vec![("x".into(), Arc::new(values) as ArrayRef)],
        )
        .unwrap()
    }

    fn gathered(chunks: &[Chunk]) -> Chunk {
        let inputs: Vec<&Chunk> = chunks.iter().collect();
        let mut rows: Vec<RowSource> = chunks
            .iter()
            .enumerate()
            .flat_map(|(c, chunk)| (0..chunk.num_rows()).map(move |r| (c, r)))
            .collect();
        rows.sort_by_key(|&(c, r)| {
            (
                chunks[c].time_columns()[0].times()[r],
                chunks[c].row_ids()[r],
            )
        });
        Chunk::gather(&inputs, &rows).unwrap()
    }

    fn same_rows(a: &Chunk, b: &Chunk) {
        assert_eq!(a.row_ids(), b.row_ids());
        for (x, y) in a.time_columns().iter().zip(b.time_columns()) {
            assert_eq!(x.times(), y.times());
        }
        for (x, y) in a.components().iter().zip(b.components()) {
            assert_eq!(x.list_array(), y.list_array());
        }
        assert!(a.has_same_layout(b));
    }

    /// Rows in and out of order, null cells among them, come out as a gather of the same
    /// chunks orders and holds them.
    #[test]
    fn built_chunk_equals_the_gather_of_the_same_chunks() {
        for frames in [[1, 2, 3, 4], [4, 1, 3, 2], [2, 2, 1, 1]] {
            let chunks: Vec<Chunk> = frames
                .iter()
                .enumerate()
                .map(|(i, &f)| {
                    scalar_row(
                        f,
                        10 - f,
                        (i != 2).then_some(f64::from(i32::try_from(f).unwrap())),
                    )
                })
                .collect();
            let mut columns = RowColumns::start(&chunks[0], 0).unwrap();
            for chunk in &chunks[1..] {
                assert!(columns.append(chunk));
            }
            assert_eq!(columns.num_rows(), 4);
            let built = columns.build(&chunks[0]).unwrap().unwrap();
            same_rows(&built, &gathered(&chunks));
            built.sanity_check().unwrap();
        }
    }

    /// Fixed-size lists (positions) and multi-row chunks are kept; a column of strings
    /// is not a shape the columns keep, nor a cell of two instances.
    #[test]
    fn keeps_primitive_and_fixed_size_cells_only() {
        let positions = |rows: &[[f32; 3]]| {
            let mut builder = ListBuilder::new(FixedSizeListBuilder::new(Float32Builder::new(), 3));
            for row in rows {
                for v in row {
                    builder.values().values().append_value(*v);
                }
                builder.values().append(true);
                builder.append(true);
            }
            Arc::new(builder.finish()) as ArrayRef
        };
        let chunk = |frames: Vec<i64>, rows: &[[f32; 3]]| {
            Chunk::try_new(
                ChunkId::new(),
                EntityPath::parse("p").unwrap(),
                frames.iter().map(|_| RowId::new()).collect(),
                vec![(
                    Timeline::sequence("frame"),
                    Arc::new(arrow_array::Int64Array::from(frames)) as ArrayRef,
                )],
                vec![("position".into(), positions(rows))],
            )
            .unwrap()
        };
        let chunks = [
            chunk(vec![5, 6], &[[5.0, 0.0, 0.0], [6.0, 0.0, 0.0]]),
            chunk(vec![1], &[[1.0, 2.0, 3.0]]),
        ];
        let mut columns = RowColumns::start(&chunks[0], 0).unwrap();
        assert!(columns.append(&chunks[1]));
        same_rows(
            &columns.build(&chunks[0]).unwrap().unwrap(),
            &gathered(&chunks),
        );

        let text = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("t").unwrap())
            .with_row(
                RowId::new(),
                [(Timeline::sequence("frame"), 1)],
                [("text", Arc::new(StringArray::from(vec!["a"])) as ArrayRef)],
            )
            .build()
            .unwrap();
        assert!(RowColumns::start(&text, 0).is_none());
        let two = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("e").unwrap())
            .with_row(
                RowId::new(),
                [(Timeline::sequence("frame"), 1)],
                [(
                    "x",
                    Arc::new(Float64Array::from(vec![1.0, 2.0])) as ArrayRef,
                )],
            )
            .build()
            .unwrap();
        assert!(RowColumns::start(&two, 0).is_none());
        let one = scalar_row(1, 1, Some(1.0));
        let mut columns = RowColumns::start(&one, 1).unwrap();
        assert!(!columns.append(&two), "two timelines against one");
        assert!(RowColumns::start(&one, 1).is_some_and(|c| c.cells[0].valid.is_none()));
        let null = scalar_row(2, 2, None);
        assert!(RowColumns::start(&null, 1).is_some_and(|c| c.cells[0].valid.is_some()));
        let empty =
            ListArray::from_iter_primitive::<arrow_array::types::Float64Type, _, _>([None::<
                [Option<f64>; 1],
            >]);
        let empty = Chunk::try_new(
            ChunkId::new(),
            EntityPath::parse("e").unwrap(),
            vec![RowId::new()],
            vec![(
                Timeline::sequence("frame"),
                Arc::new(arrow_array::Int64Array::from(vec![1])) as ArrayRef,
            )],
            vec![("x".into(), Arc::new(empty) as ArrayRef)],
        )
        .unwrap();
        assert!(
            RowColumns::start(&empty, 1).is_none(),
            "a null cell of no instance"
        );

        // A copy (a store's clone copying the writer's columns) keeps the room for the
        // next rows.
        let columns = RowColumns::start(&one, 16).unwrap();
        let copy = columns.clone();
        assert_eq!(copy, columns);
        assert!(copy.row_ids.capacity() >= 16 && copy.times[0].capacity() >= 16);
        assert!(copy.cells[0].bytes.capacity() >= 16 * 8);
    }
}
