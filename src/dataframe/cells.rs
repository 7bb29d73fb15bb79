//! A column's cells for one batch, written into a list array as they come
//! ([`ListColumnBuilder`]): an offset per cell (a few instructions each; the validity is
//! read off the offsets when the column ends), the values as the stretches of the source
//! chunks' values the cells take, copied at the end (one zero-copy slice when a batch
//! takes one chunk's values whole, one `MutableArrayData::extend` per stretch otherwise).
//! Null cells hold no values, so a column logged every third row still copies its values
//! in one stretch per source chunk.
//! The `chunks` table, which fills many columns a row at a time, records runs of cells per
//! column first (`cell_runs.rs`) and replays them into the builder.

use std::sync::Arc;

use arrow_array::OffsetSizeTrait;
use arrow_array::cast::AsArray as _;
use arrow_array::{Array, ArrayRef, ListArray, UInt64Array, make_array, new_empty_array};
use arrow_buffer::{
    BooleanBuffer, BooleanBufferBuilder, Buffer, NullBuffer, OffsetBuffer, ScalarBuffer,
};
use arrow_data::ArrayData;
use arrow_data::transform::{Capacities, MutableArrayData};
use arrow_schema::{ArrowError, DataType, FieldRef};

use crate::{Chunk, ChunkId, Timeline};

/// What one cell of the output shows (a null cell is `None`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Cell {
    /// An empty list: what a Clear leaves.
    Empty,
    /// Row `row` of source `source` ([`Sources`]).
    Row { source: u32, row: u32 },
}

/// One stored list array a column's cells come from.
#[derive(Debug)]
struct Source {
    chunk: Arc<Chunk>,
    /// The column's list array, retyped to the output's list type where its item field
    /// differed (name, nullability or metadata; the element type is the same).
    list: ListArray,
    /// `(index column, the chunk's time column there)` for each index column but the
    /// table's own index (whose value a row already has) that the chunk has.
    time_columns: Box<[(u32, u32)]>,
}

/// The list arrays one output column copies from, numbered from 0 in the order they are
/// registered. (A Clear's empty cells need none: they are offsets alone.)
#[derive(Debug)]
pub(crate) struct Sources {
    item_field: FieldRef,
    arrays: Vec<Source>,
    /// `(chunk, component column)` -> source, for sources registered by lookup.
    by_chunk: ahash::HashMap<(ChunkId, u32), u32>,
}

impl Sources {
    pub fn new(item_field: FieldRef) -> Self {
        Self {
            item_field,
            arrays: Vec::new(),
            by_chunk: ahash::HashMap::default(),
        }
    }

    /// Registers column `component_column` of `chunk` (again, if it already is) and
    /// returns its source number. `index_columns` are the table's (`skip`: the position of
    /// its own index among them).
    pub fn push(
        &mut self,
        chunk: &Arc<Chunk>,
        component_column: u32,
        index_columns: &[Timeline],
        skip: Option<usize>,
    ) -> Result<u32, ArrowError> {
        let list = chunk.components()[component_column as usize].list_array();
        let list = if matches!(list.data_type(), arrow_schema::DataType::List(f) if *f == self.item_field)
        {
            list.clone()
        } else {
            ListArray::try_new(
                Arc::clone(&self.item_field),
                list.offsets().clone(),
                Arc::clone(list.values()),
                list.nulls().cloned(),
            )?
        };
        let time_columns = index_columns
            .iter()
            .enumerate()
            .filter(|&(i, _)| Some(i) != skip)
            .filter_map(|(i, timeline)| {
                let position = chunk
                    .time_columns()
                    .iter()
                    .position(|c| c.timeline().name() == timeline.name())?;
                Some((u32::try_from(i).ok()?, u32::try_from(position).ok()?))
            })
            .collect();
        let number = u32::try_from(self.arrays.len())
            .map_err(|_| ArrowError::ComputeError("too many source chunks".to_owned()))?;
        self.arrays.push(Source {
            chunk: Arc::clone(chunk),
            list,
            time_columns,
        });
        Ok(number)
    }

    /// How many sources are registered (they are only ever added).
    #[cfg(feature = "datafusion")]
    pub fn num_sources(&self) -> usize {
        self.arrays.len()
    }

    /// Bytes one cell of `source` takes in an output batch, about: that one cell's values
    /// (with its offset) for a `row`, else the source's average cell.
    pub fn cell_bytes(&self, source: u32, row: Option<u32>) -> usize {
        let Some(source) = self.arrays.get(source as usize) else {
            return 0;
        };
        let list = &source.list;
        let values = list.values().to_data().get_slice_memory_size().unwrap_or(0);
        let cells = list.len().max(1);
        let (start, end) = match row {
            Some(row) if (row as usize) < list.len() => {
                let offsets = list.value_offsets();
                (offsets[row as usize], offsets[row as usize + 1])
            }
            _ => return values / cells + 4,
        };
        let items = list.values().len().max(1);
        let cell_items = usize::try_from(end - start).unwrap_or(0);
        values / items * cell_items + 4
    }

    /// The average bytes of a cell over the registered sources (at most the first 64: an
    /// estimate need not read a column of 100,000 chunks), 0 if none.
    pub fn average_cell_bytes(&self) -> usize {
        let sampled = self.arrays.len().min(64);
        let numbers = 0..u32::try_from(sampled).unwrap_or(u32::MAX);
        let total: usize = numbers.map(|n| self.cell_bytes(n, None)).sum();
        total / sampled.max(1)
    }

    /// The ids of the chunks registered (repeats included).
    pub fn chunk_ids(&self) -> impl Iterator<Item = ChunkId> + '_ {
        self.arrays.iter().map(|source| source.chunk.id())
    }

    /// The source of `(chunk, component_column)`, registered on first use.
    pub fn find_or_push(
        &mut self,
        chunk: &Arc<Chunk>,
        component_column: u32,
        index_columns: &[Timeline],
        skip: Option<usize>,
    ) -> Result<u32, ArrowError> {
        let key = (chunk.id(), component_column);
        if let Some(&number) = self.by_chunk.get(&key) {
            return Ok(number);
        }
        let number = self.push(chunk, component_column, index_columns, skip)?;
        self.by_chunk.insert(key, number);
        Ok(number)
    }

    /// Raises `index_values[i][at]` (output row `at` on index column `i`) to the time the
    /// cell's row has on index column `i`, where its chunk has that timeline (the table's
    /// own index aside).
    pub fn raise_times(&self, cell: Cell, at: usize, index_values: &mut [Vec<Option<i64>>]) {
        // With the index the only index column there is nothing to raise, and the source
        // need not be read.
        let (true, Cell::Row { source, row }) = (index_values.len() > 1, cell) else {
            return;
        };
        let source = &self.arrays[source as usize];
        for &(index_column, time_column) in &source.time_columns {
            let time = source.chunk.time_columns()[time_column as usize].times()[row as usize];
            let max = &mut index_values[index_column as usize][at];
            *max = (*max).max(Some(time));
        }
    }
}

/// A batch's list arrays, built a column at a time and cell by cell: an offset per cell
/// (a few instructions each), the values as the stretches of the sources' values
/// the cells take, copied when the column is done (usually one zero-copy slice). Every
/// column of a batch writes its offsets and validity into one buffer each, which the
/// batch's arrays share: two allocations a batch rather than two a column (a batch of a
/// wide table has thousands of columns of a few hundred cells, and an allocation per
/// column cost more than the cells). The dataframe builds a batch with one of these;
/// [`ColumnCells`](super::cell_runs::ColumnCells) replays its runs into one.
#[derive(Debug)]
pub(crate) struct ListColumnBuilder {
    /// Every finished column's offsets, then the current column's (each starting at 0).
    offsets: Vec<i32>,
    /// Where the current column's offsets start.
    column_start: usize,
    /// Every finished column's validity bits. A column's bits are written when it ends,
    /// read off its offsets: a cell holding values is valid, an empty one null, except
    /// the cells in `exceptions`. Nulls are most of a sparse table's cells and empty
    /// lists (a Clear's mark) are rare, so the common cell writes no bit of its own.
    validity: BooleanBufferBuilder,
    /// The current column's cells (numbered from its start) whose validity is not what
    /// their length says: valid empty lists, and null source rows that hold values.
    exceptions: Vec<u32>,
    /// Scratch for a column's packed validity bits.
    packed: Vec<u8>,
    /// The stretches of the sources' values the current column's cells take, in order,
    /// each as long as consecutive cells continue it: `(source, start, end)`.
    stretches: Vec<(u32, usize, usize)>,
    /// The values would overflow the 32-bit offsets (reported by `finish_column`).
    overflow: bool,
    /// Source number -> its place among the sources a copy uses (`u32::MAX`: unused).
    local: Vec<u32>,
    /// The sources a copy uses, in local order.
    used: Vec<u32>,
    /// The finished columns, waiting for the batch's shared buffers.
    finished: Vec<FinishedList>,
}

/// A finished column of a batch: where its offsets and validity are in the shared
/// buffers, and its own values.
#[derive(Debug)]
struct FinishedList {
    item_field: FieldRef,
    offsets_start: usize,
    cells: usize,
    nulls: usize,
    values: ArrayRef,
}

/// The exact capacities of copying `parts` (an array of `data_type`, rows `from..to`) into
/// one array, nested lists and strings included: grown by doubling instead, a batch of
/// large cells (images) reserved up to twice its bytes, and held both buffers while one
/// grew into the other (a scan of image recordings peaked at 140 MB of batches, 2.5
/// times what they held).
fn capacities_of(data_type: &DataType, parts: &[(&dyn Array, usize, usize)]) -> Capacities {
    let items = parts.iter().map(|&(_, from, to)| to - from).sum();
    match data_type {
        DataType::List(item) => Capacities::List(
            items,
            Some(Box::new(list_capacities::<i32>(item.data_type(), parts))),
        ),
        DataType::LargeList(item) => Capacities::List(
            items,
            Some(Box::new(list_capacities::<i64>(item.data_type(), parts))),
        ),
        DataType::Utf8 | DataType::Binary => {
            let bytes = parts
                .iter()
                .map(|&(array, from, to)| {
                    let offsets = match array.as_string_opt::<i32>() {
                        Some(strings) => strings.value_offsets(),
                        None => array.as_binary::<i32>().value_offsets(),
                    };
                    value_span(offsets, from, to).len()
                })
                .sum();
            Capacities::Binary(items, Some(bytes))
        }
        _ => Capacities::Array(items),
    }
}

/// The capacities of the items of `parts`, lists with `O` offsets.
fn list_capacities<O: OffsetSizeTrait>(
    item_type: &DataType,
    parts: &[(&dyn Array, usize, usize)],
) -> Capacities {
    let items: Vec<(&dyn Array, usize, usize)> = parts
        .iter()
        .map(|&(array, from, to)| {
            let list = array.as_list::<O>();
            let span = value_span(list.value_offsets(), from, to);
            (list.values().as_ref(), span.start, span.end)
        })
        .collect();
    capacities_of(item_type, &items)
}

/// The values that rows `from..to` of offsets `offsets` span.
fn value_span<O: OffsetSizeTrait>(offsets: &[O], from: usize, to: usize) -> std::ops::Range<usize> {
    offsets[from].as_usize()..offsets[to].as_usize()
}

/// Appends the validity of the `offsets.len() - 1` cells `offsets` bound to `validity`
/// (`packed`: scratch): a cell holding values is valid, an empty one null, and each cell
/// numbered in `exceptions` the other way. Returns how many are null.
fn append_validity(
    offsets: &[i32],
    exceptions: &[u32],
    packed: &mut Vec<u8>,
    validity: &mut BooleanBufferBuilder,
) -> usize {
    let cells = offsets.len().saturating_sub(1);
    packed.clear();
    let mut valid = 0;
    // 64 cells a word: a loop over two shifted slices, which compiles without bounds checks.
    for first in (0..cells).step_by(64) {
        let n = (cells - first).min(64);
        let (starts, ends) = (&offsets[first..first + n], &offsets[first + 1..=first + n]);
        let mut word = 0u64;
        for (bit, (start, end)) in starts.iter().zip(ends).enumerate() {
            word |= u64::from(start != end) << bit;
        }
        valid += word.count_ones() as usize;
        packed.extend_from_slice(&word.to_le_bytes()[..n.div_ceil(8)]);
    }
    for &cell in exceptions {
        let (byte, bit) = (cell as usize / 8, 1 << (cell % 8));
        packed[byte] ^= bit;
        if packed[byte] & bit == 0 {
            valid -= 1;
        } else {
            valid += 1;
        }
    }
    validity.append_packed_range(0..cells, packed);
    cells - valid
}

impl Default for ListColumnBuilder {
    fn default() -> Self {
        Self {
            offsets: vec![0],
            column_start: 0,
            validity: BooleanBufferBuilder::new(0),
            exceptions: Vec::new(),
            packed: Vec::new(),
            stretches: Vec::new(),
            overflow: false,
            local: Vec::new(),
            used: Vec::new(),
            finished: Vec::new(),
        }
    }
}

impl ListColumnBuilder {
    /// How many cells the current column holds.
    pub fn len(&self) -> usize {
        self.offsets.len() - self.column_start - 1
    }

    /// Makes room for `cells` more cells in the current column, so that pushing them
    /// never grows the buffer one step at a time.
    pub fn reserve(&mut self, cells: usize) {
        self.offsets.reserve(cells);
    }

    /// Starts the current column over.
    fn clear_column(&mut self) {
        self.offsets.truncate(self.column_start + 1);
        self.exceptions.clear();
        self.stretches.clear();
        self.overflow = false;
    }

    /// Appends one cell.
    pub fn push(&mut self, sources: &Sources, cell: Option<Cell>) {
        match cell {
            None => self.repeat_offset(1, false),
            Some(Cell::Empty) => self.repeat_offset(1, true),
            Some(Cell::Row { source, row }) => self.row(sources, source, row),
        }
    }

    /// Pads with `pad` up to `at` cells, then appends `cell` at `at`: the merge's step
    /// for each cell it visits. A sparse column's step (null padding, a row) is kept to a
    /// few instructions without a call (a call's register saves alone cost a third).
    #[expect(
        clippy::inline_always,
        reason = "measured: left to the compiler, the merge's step stayed a call"
    )]
    #[inline(always)]
    pub fn pad_and_push(
        &mut self,
        sources: &Sources,
        pad: Option<Cell>,
        at: usize,
        cell: Option<Cell>,
    ) {
        match pad {
            None => {
                // A sparse column's gaps are a few cells: pushed one by one, not through
                // `resize`'s general path.
                let last = self.offsets.last().copied().unwrap_or(0);
                for _ in self.len()..at {
                    self.offsets.push(last);
                }
            }
            pad => self.pad(sources, pad, at),
        }
        match cell {
            Some(Cell::Row { source, row }) => self.row(sources, source, row),
            cell => self.push(sources, cell),
        }
    }

    /// Appends copies of `cell` until the column holds `len` cells.
    pub fn pad(&mut self, sources: &Sources, cell: Option<Cell>, len: usize) {
        let missing = len.saturating_sub(self.len());
        match cell {
            None => self.repeat_offset(missing, false),
            Some(Cell::Empty) => self.repeat_offset(missing, true),
            Some(Cell::Row { source, row }) => {
                for _ in 0..missing {
                    self.row(sources, source, row);
                }
            }
        }
    }

    /// `n` cells holding no values: nulls, or empty lists.
    #[expect(clippy::cast_possible_truncation, reason = "a batch holds < 2^32 rows")]
    pub(super) fn repeat_offset(&mut self, n: usize, valid: bool) {
        let first = self.len();
        let last = self.offsets.last().copied().unwrap_or(0);
        self.offsets.resize(self.offsets.len() + n, last);
        if valid {
            self.exceptions
                .extend((first..first + n).map(|cell| cell as u32));
        }
    }

    /// Row `row` of source `source`: the dataframe's cell, one at a time.
    #[expect(
        clippy::inline_always,
        reason = "measured: left to the compiler, the merge's step stayed a call"
    )]
    #[inline(always)]
    #[expect(clippy::cast_possible_truncation, reason = "a batch holds < 2^32 rows")]
    pub(super) fn row(&mut self, sources: &Sources, source: u32, row: u32) {
        let list = &sources.arrays[source as usize].list;
        let offsets = list.value_offsets();
        let row = row as usize;
        let (from, to) = (offsets[row], offsets[row + 1]);
        let previous_end = self.offsets.last().copied().unwrap_or(0);
        let offset = previous_end.checked_add(to - from).unwrap_or_else(|| {
            self.overflow = true;
            previous_end
        });
        // Its validity is what its length says, unless it is an empty valid list or a
        // null holding values.
        if (to == from) != list.is_null(row) {
            self.exceptions.push(self.len() as u32);
        }
        self.offsets.push(offset);
        self.take_values(
            source,
            from.unsigned_abs() as usize,
            to.unsigned_abs() as usize,
        );
    }

    /// Rows `start..end` of source `source`, none of them null (a stretch of a column
    /// without null cells): their offsets shifted at once, their values one stretch, an
    /// exception noted only for an empty list (valid, where its length says null).
    #[expect(clippy::cast_possible_truncation, reason = "a batch holds < 2^32 rows")]
    pub fn push_rows(&mut self, sources: &Sources, source: u32, start: u32, end: u32) {
        let list = &sources.arrays[source as usize].list;
        let Some(offsets) = list.value_offsets().get(start as usize..=end as usize) else {
            return;
        };
        let (values_start, values_end) = (offsets[0], offsets[offsets.len() - 1]);
        let previous_end = self.offsets.last().copied().unwrap_or(0);
        if previous_end
            .checked_add(values_end - values_start)
            .is_none()
        {
            self.overflow = true;
            return;
        }
        let cell = self.len();
        self.offsets.extend(
            offsets[1..]
                .iter()
                .map(|&offset| previous_end + (offset - values_start)),
        );
        for (i, pair) in offsets.windows(2).enumerate() {
            if pair[0] == pair[1] {
                self.exceptions.push((cell + i) as u32);
            }
        }
        self.take_values(
            source,
            values_start.unsigned_abs() as usize,
            values_end.unsigned_abs() as usize,
        );
    }

    /// Rows `start..end` of source `source` (consecutive rows take one stretch of values).
    pub(super) fn rows(&mut self, sources: &Sources, source: u32, start: u32, end: u32) {
        for row in start..end {
            self.row(sources, source, row);
        }
    }

    /// Notes that the current column's cells take values `from..to` of source `source`,
    /// continuing the last stretch where they follow it.
    #[inline]
    fn take_values(&mut self, source: u32, from: usize, to: usize) {
        match self.stretches.last_mut() {
            Some((s, _, stretch_end)) if *s == source && *stretch_end == from => *stretch_end = to,
            _ if from == to => {}
            _ => self.stretches.push((source, from, to)),
        }
    }

    /// Ends the current column: its values are copied (or sliced) from `sources`; its
    /// array comes with the batch's ([`Self::finish_batch`]).
    ///
    /// # Errors
    /// The values overflow the list's 32-bit offsets (the column is dropped).
    pub fn finish_column(&mut self, sources: &Sources) -> Result<(), ArrowError> {
        if self.overflow {
            self.clear_column();
            return Err(ArrowError::OffsetOverflowError(usize::MAX));
        }
        let values = match self.stretches.as_slice() {
            [] => new_empty_array(sources.item_field.data_type()),
            &[(source, from, to)] => sources.arrays[source as usize]
                .list
                .values()
                .slice(from, to - from),
            stretches if stretches.iter().all(|&(s, _, _)| s == stretches[0].0) => {
                // Several stretches of one chunk (cells a fill repeats): one gather.
                let indices: UInt64Array = stretches
                    .iter()
                    .flat_map(|&(_, from, to)| from as u64..to as u64)
                    .collect();
                let values = sources.arrays[stretches[0].0 as usize].list.values();
                arrow_select::take::take(values, &indices, None)?
            }
            stretches => {
                // Stretches of several chunks: copied stretch by stretch.
                let Self { local, used, .. } = self;
                local.clear();
                local.resize(sources.arrays.len(), u32::MAX);
                used.clear();
                for &(source, _, _) in stretches {
                    if local[source as usize] == u32::MAX {
                        local[source as usize] = u32::try_from(used.len()).unwrap_or(u32::MAX);
                        used.push(source);
                    }
                }
                let data: Vec<ArrayData> = used
                    .iter()
                    .map(|&s| sources.arrays[s as usize].list.values().to_data())
                    .collect();
                let parts: Vec<(&dyn Array, usize, usize)> = stretches
                    .iter()
                    .map(|&(source, from, to)| {
                        (
                            sources.arrays[source as usize].list.values().as_ref(),
                            from,
                            to,
                        )
                    })
                    .collect();
                let capacities = capacities_of(sources.item_field.data_type(), &parts);
                let mut values =
                    MutableArrayData::with_capacities(data.iter().collect(), false, capacities);
                for &(source, from, to) in stretches {
                    values.extend(local[source as usize] as usize, from, to);
                }
                make_array(values.freeze())
            }
        };
        let nulls = append_validity(
            &self.offsets[self.column_start..],
            &self.exceptions,
            &mut self.packed,
            &mut self.validity,
        );
        self.finished.push(FinishedList {
            item_field: Arc::clone(&sources.item_field),
            offsets_start: self.column_start,
            cells: self.len(),
            nulls,
            values,
        });
        self.column_start = self.offsets.len();
        self.offsets.push(0);
        self.exceptions.clear();
        self.stretches.clear();
        Ok(())
    }

    /// The list arrays of the columns finished since the last batch, in order; the
    /// builder is emptied for the next batch.
    ///
    /// # Errors
    /// Only if a column's parts disagree, which would be a bug here.
    pub fn finish_batch(&mut self) -> Result<Vec<ArrayRef>, ArrowError> {
        self.clear_column();
        // The next batch is about as large: its buffers are sized for it.
        let capacity = self.offsets.len();
        let mut offsets = Vec::with_capacity(capacity);
        offsets.push(0);
        let offsets = Buffer::from_vec(std::mem::replace(&mut self.offsets, offsets));
        let validity = std::mem::replace(&mut self.validity, BooleanBufferBuilder::new(capacity))
            .finish()
            .into_inner();
        self.column_start = 0;
        // Each column's validity bits follow the previous columns' cells.
        let mut bit = 0;
        self.finished
            .drain(..)
            .map(|list| {
                let column_offsets =
                    ScalarBuffer::new(offsets.clone(), list.offsets_start, list.cells + 1);
                let nulls = (list.nulls > 0).then(|| {
                    NullBuffer::new(BooleanBuffer::new(validity.clone(), bit, list.cells))
                });
                bit += list.cells;
                let list = ListArray::try_new(
                    list.item_field,
                    OffsetBuffer::new(column_offsets),
                    list.values,
                    nulls,
                )?;
                Ok(Arc::new(list) as ArrayRef)
            })
            .collect()
    }
}
