//! [`ComponentColumn`]: one component's cells in a chunk, with what the indices need from
//! them (per-timeline bounds, the static winner's row) and zero-copy reads of primitive
//! cells.

use arrow_array::cast::AsArray;
use arrow_array::{Array, ArrayRef, ArrowPrimitiveType, ListArray};
use arrow_buffer::Buffer;
use arrow_schema::{DataType, FieldRef};
use smallvec::SmallVec;

use super::data_types::{instance_bytes, is_type_of, leaf_shape, with_shared_item_field};
use super::time_column::TimeColumn;
use crate::ChunkError;
use crate::sanity::{SanityError, Structure};
use crate::{ChunkId, ComponentDescriptor, ComponentName, RowId, TimeInt};

/// The greatest and least index of a component's non-null cells on one timeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ComponentTimeBounds {
    /// Least time of a non-null cell.
    pub min_time: TimeInt,
    /// Greatest time of a non-null cell.
    pub max_time: TimeInt,
    /// Greatest row id among the non-null cells at `max_time`.
    pub max_row_id: RowId,
    /// The row holding that cell.
    pub max_row: u32,
}

impl ComponentTimeBounds {
    /// The key of this greatest cell, in chunk `chunk`, in the order latest-at answers by
    /// and garbage collection's `protect_latest` keeps: `(time, row id)`, then chunk id for
    /// a tie (SEMANTICS.md section 3).
    pub(crate) fn max_index_key(&self, chunk: ChunkId) -> (TimeInt, RowId, ChunkId) {
        (self.max_time, self.max_row_id, chunk)
    }
}

/// One component's column in a chunk.
#[derive(Debug)]
// What reading a cell touches first (the list's offsets and validity, the shape flag, the
// leaf's values), then the name, what transport reads and the bounds (last: their row
// ids align to 16 bytes). Rust's own layout put the list, the flag and the leaf over four
// lines of the column's 288 bytes.
#[repr(C)]
pub struct ComponentColumn {
    pub(super) list: ListArray,
    /// For every chunk: the row of the non-null cell with the greatest row id, or
    /// [`NO_ROW`] if every cell is null. It is the static winner of a static chunk. (A
    /// sentinel rather than an `Option`, so that the flag below fits in the same word.)
    pub(super) best_cell_row: u32,
    /// Does every cell span exactly one instance? See
    /// [`ComponentColumn::has_one_instance_per_row`].
    pub(super) one_instance_per_row: bool,
    /// Do neither the items nor (for fixed-size lists) their values hold a null instance?
    /// Then a cell's leaf values are the whole cell ([`ComponentColumn::null_free_leaf`]).
    /// Kept, in the flag's word, because a write buffer's copy of every streamed row asked
    /// Arrow for two null counts through its array handles.
    pub(super) leaf_null_free: bool,
    /// Bytes of one cell's leaf values, with one instance per row and a primitive leaf
    /// whose cells take fewer than 2^16 bytes; 0 otherwise. What
    /// [`ComponentColumn::touch_cell`] reads by, kept in the flags' word.
    pub(super) cell_bytes: u16,
    /// The primitive values beneath the items, when there are such; see [`PrimitiveLeaf`].
    pub(super) leaf: Option<PrimitiveLeaf>,
    pub(super) descriptor: ComponentDescriptor,
    /// The column's field as given (its name and metadata), for lossless transport; `None`
    /// for a column built through the API, whose field is named after the component and
    /// carries no metadata (derived when needed rather than allocated per chunk).
    pub(super) field: Option<FieldRef>,
    /// Per time column of the chunk (same order): bounds of the non-null cells, `None` when
    /// every cell is null.
    pub(super) bounds_per_timeline: SmallVec<[Option<ComponentTimeBounds>; 1]>,
}

/// The primitive values beneath a column's items, when the items are primitive values or
/// fixed-size lists of them, such as scalars or 3D positions.
///
/// Kept so that reading a cell is the offsets and then the values. Through Arrow's arrays it
/// is also one array struct per nesting level, each behind its own pointer: in a store far
/// larger than the cache, a dependent cache miss each, on every query answer read.
///
/// Only the buffer handle is kept (24 bytes a column): the leaf's type and shape are read
/// from the list's item field, which is the process-wide shared copy and so in cache.
#[derive(Clone, Debug)]
pub(super) struct PrimitiveLeaf {
    /// Starting at the items' first value (any slicing already applied). A second handle on
    /// the leaf array's buffer: it shares the allocation.
    pub(super) values: Buffer,
    /// The list's first offset: where row 0's items start. With one instance per row,
    /// row `r`'s item is `first_item + r`, found without reading the offsets (a cache miss
    /// of its own in a store larger than the cache).
    pub(super) first_item: usize,
}

impl PrimitiveLeaf {
    /// The leaf of `list`'s items, if they are primitives or fixed-size lists of them.
    pub(super) fn of(list: &ListArray) -> Option<Self> {
        let items = match list.values().as_fixed_size_list_opt() {
            Some(fixed) => fixed.values(),
            None => list.values(),
        };
        let values = arrow_array::downcast_primitive_array!(
            items => items.values().inner().clone(),
            _ => return None
        );
        let first_item = usize::try_from(*list.value_offsets().first()?).ok()?;
        Some(Self { values, first_item })
    }

    /// The same values: the very same bytes, not equal ones.
    pub(super) fn is_the_same(&self, other: &Self) -> bool {
        (self.values.as_ptr(), self.values.len()) == (other.values.as_ptr(), other.values.len())
    }
}

/// [`ComponentColumn::cell_bytes`] of `list`.
fn touchable_cell_bytes(list: &ListArray, has_leaf: bool, one_instance_per_row: bool) -> u16 {
    let width = || instance_bytes(list.data_type());
    match (has_leaf && one_instance_per_row).then(width).flatten() {
        Some(bytes) => u16::try_from(bytes).unwrap_or(0),
        None => 0,
    }
}

/// Do neither `list`'s items nor, for fixed-size lists, their values hold a null
/// instance? (Of a list whose leaf is primitive: see [`ComponentColumn::leaf_null_free`].)
fn has_null_free_items(list: &ListArray) -> bool {
    let items = list.values();
    let leaf_nulls = match items.as_fixed_size_list_opt() {
        Some(fixed) => fixed.values().null_count(),
        None => 0,
    };
    items.null_count() + leaf_nulls == 0
}

/// Does every cell of `list` span exactly one value?
pub(super) fn has_one_instance_per_row(list: &ListArray) -> bool {
    list.value_offsets().windows(2).all(|w| w[1] - w[0] == 1)
}

/// Values a column may describe per byte of its buffers: a boolean takes a bit.
const MAX_VALUES_PER_BYTE: usize = 8;

/// Refuses a column whose cells describe more values than its buffers could hold (see
/// [`ChunkError::UnbackedValues`]): a list of `Null`s or of empty structs, whose offsets
/// span billions of values that take no byte, made a merge of a 4 KB input allocate
/// gigabytes of interleave indices.
fn check_backed_values(list: &ListArray, name: impl Fn() -> String) -> Result<(), ChunkError> {
    let values = values_walked(list, 0, list.len()).unwrap_or(usize::MAX);
    let bytes = list.get_buffer_memory_size();
    let allowed = bytes
        .saturating_mul(MAX_VALUES_PER_BYTE)
        .saturating_add(list.len());
    if values > allowed {
        return Err(ChunkError::UnbackedValues {
            component: name(),
            values,
            bytes,
        });
    }
    Ok(())
}

/// How many values a copy of elements `start..start + len` of `array` walks through, at
/// every nesting level together (`None` past `usize`, or for offsets out of bounds,
/// which Arrow's validation already excludes). O(depth): a list's elements below a range
/// are one span of its offsets.
fn values_walked(array: &dyn Array, start: usize, len: usize) -> Option<usize> {
    /// The values below elements `start..start + len` of a list-like array: its offsets'
    /// span of `child`.
    fn below_span<O: arrow_array::OffsetSizeTrait>(
        offsets: &[O],
        child: &dyn Array,
        start: usize,
        len: usize,
    ) -> Option<usize> {
        let first = offsets.get(start)?.as_usize();
        let last = offsets.get(start.checked_add(len)?)?.as_usize();
        values_walked(child, first, last.checked_sub(first)?)
    }
    let below = match array.data_type() {
        DataType::List(_) => {
            let list = array.as_list::<i32>();
            below_span(list.value_offsets(), list.values(), start, len)?
        }
        DataType::LargeList(_) => {
            let list = array.as_list::<i64>();
            below_span(list.value_offsets(), list.values(), start, len)?
        }
        DataType::Map(..) => {
            let map = array.as_map();
            below_span(map.value_offsets(), map.entries(), start, len)?
        }
        DataType::FixedSizeList(_, size) => {
            let size = usize::try_from(*size).ok()?;
            let list = array.as_fixed_size_list();
            values_walked(
                list.values(),
                start.checked_mul(size)?,
                len.checked_mul(size)?,
            )?
        }
        DataType::Struct(_) => array
            .as_struct()
            .columns()
            .iter()
            .try_fold(0usize, |sum, column| {
                sum.checked_add(values_walked(column.as_ref(), start, len)?)
            })?,
        _ => 0,
    };
    len.checked_add(below)
}

/// No row: a chunk has fewer than `u32::MAX` rows (checked in `Chunk::from_raw`), so its
/// rows are numbered below this.
pub(super) const NO_ROW: u32 = u32::MAX;

pub(super) struct RawComponentColumn {
    pub(super) descriptor: ComponentDescriptor,
    pub(super) array: ArrayRef,
    pub(super) field: Option<FieldRef>,
    /// The cells are a slice or a copy of cells of accepted chunks (a split or a merge),
    /// so [`check_backed_values`], a guard on input, does not judge them again: a slice's
    /// allowance (one value per row beyond its bytes) shrinks with its rows, and a chunk
    /// the store accepted whole must stay splittable; the copy of a merge walks only what
    /// its inputs, each accepted, walk.
    pub(super) from_accepted_cells: bool,
}

impl ComponentColumn {
    pub(super) fn try_new(
        raw: RawComponentColumn,
        row_ids: &[RowId],
        sorted_by_row_id: bool,
        time_columns: &[TimeColumn],
    ) -> Result<Self, ChunkError> {
        let RawComponentColumn {
            descriptor,
            array,
            field,
            from_accepted_cells,
        } = raw;
        let name = || descriptor.name.as_str().to_owned();
        let Some(list) = array.as_any().downcast_ref::<ListArray>() else {
            return Err(ChunkError::NotAList {
                component: name(),
                data_type: array.data_type().clone(),
            });
        };
        if list.len() != row_ids.len() {
            return Err(ChunkError::LengthMismatch {
                column: name(),
                expected: row_ids.len(),
                actual: list.len(),
            });
        }
        // Accepted cells' lists carry their source's item field, which was shared when
        // that source was built (sharing it again was a tenth of slicing a small piece).
        let list = if from_accepted_cells {
            list.clone()
        } else {
            with_shared_item_field(list)
        };
        let best_cell_row = best_cell_row(&list, row_ids, sorted_by_row_id);
        let one_instance_per_row = has_one_instance_per_row(&list);
        let leaf = PrimitiveLeaf::of(&list);
        let leaf_null_free = leaf.is_some() && has_null_free_items(&list);
        let cell_bytes = touchable_cell_bytes(&list, leaf.is_some(), one_instance_per_row);
        if leaf.is_none() && !from_accepted_cells {
            // Primitive items (and fixed-size lists of them) take bytes per value.
            check_backed_values(&list, name)?;
        }
        let bounds_per_timeline = time_columns
            .iter()
            .map(|column| time_bounds(&list, column, row_ids))
            .collect();

        Ok(Self {
            list,
            best_cell_row,
            one_instance_per_row,
            leaf_null_free,
            cell_bytes,
            leaf,
            descriptor,
            field,
            bounds_per_timeline,
        })
    }

    /// The descriptor (name and metadata).
    pub fn descriptor(&self) -> &ComponentDescriptor {
        &self.descriptor
    }

    /// The component's name.
    pub fn name(&self) -> &ComponentName {
        &self.descriptor.name
    }

    /// The whole column.
    pub fn list_array(&self) -> &ListArray {
        &self.list
    }

    /// The Arrow type of one element of a cell.
    pub fn element_type(&self) -> &DataType {
        self.list.value_type_ref()
    }

    /// The cell at `row`, or `None` if out of bounds or null. Zero-copy.
    pub fn cell(&self, row: usize) -> Option<ArrayRef> {
        self.is_valid_row(row).then(|| self.list.value(row))
    }

    /// Does every cell span exactly one instance of the values array (a scalar series, a
    /// single pose per row)? Then the instances of rows `a..b` are the values
    /// `offsets[a]..offsets[a] + (b − a)`: a reader can take them as one slice. Null cells
    /// span one too when this holds; check [`Array::null_count`] on the list.
    pub fn has_one_instance_per_row(&self) -> bool {
        self.one_instance_per_row
    }

    /// The values of the cell at `row`, for a column of `List<T>` (e.g. scalars): one
    /// zero-copy slice, read through the offsets and the values buffer only.
    ///
    /// `None` if `row` is out of bounds, the cell is null, or the items are not `T`
    /// (compared with [`ArrowPrimitiveType::DATA_TYPE`]). Like Arrow's
    /// `PrimitiveArray::values`, a null *instance* reads as whatever its slot holds.
    ///
    /// ```
    /// use arrow_array::types::Float64Type;
    /// # use std::sync::Arc;
    /// # use arrow_array::{builder::{Float64Builder, ListBuilder}, ArrayRef, Int64Array};
    /// # use chunkstore::{Chunk, ChunkId, EntityPath, RowId, Timeline};
    /// # let mut scalars = ListBuilder::new(Float64Builder::new());
    /// # scalars.values().append_value(1.5);
    /// # scalars.values().append_value(2.5);
    /// # scalars.append(true);
    /// # let chunk = Chunk::try_new(
    /// #     ChunkId::new(),
    /// #     EntityPath::parse("sensor").unwrap(),
    /// #     vec![RowId::new()],
    /// #     vec![(Timeline::sequence("frame"), Arc::new(Int64Array::from(vec![0])) as ArrayRef)],
    /// #     vec![("scalar".into(), Arc::new(scalars.finish()) as ArrayRef)],
    /// # )
    /// # .unwrap();
    /// let column = &chunk.components()[0];
    /// assert_eq!(column.primitive_values::<Float64Type>(0), Some(&[1.5, 2.5][..]));
    /// ```
    pub fn primitive_values<T: ArrowPrimitiveType>(&self, row: usize) -> Option<&[T::Native]> {
        self.leaf_values::<T>(row, None)
    }

    /// The values of the cell at `row`, for a column of `List<FixedSizeList<T, N>>` (e.g.
    /// 3D positions, `N = 3`): one zero-copy slice of `N`-arrays, read through the offsets
    /// and the values buffer only.
    ///
    /// `None` if `row` is out of bounds, the cell is null, `N` is 0, or the items are not
    /// fixed-size lists of `N` `T`s. As in [`ComponentColumn::primitive_values`], null
    /// instances read as whatever their slots hold.
    pub fn fixed_size_values<T: ArrowPrimitiveType, const N: usize>(
        &self,
        row: usize,
    ) -> Option<&[[T::Native; N]]> {
        if N == 0 {
            return None;
        }
        self.leaf_values::<T>(row, Some(N))
            .map(|values| values.as_chunks::<N>().0)
    }

    pub(super) fn leaf_values<T: ArrowPrimitiveType>(
        &self,
        row: usize,
        fixed_size: Option<usize>,
    ) -> Option<&[T::Native]> {
        let leaf = self.leaf.as_ref()?;
        let (leaf_type, shape) = leaf_shape(self.list.data_type())?;
        if shape != fixed_size || !is_type_of::<T>(leaf_type) || !self.is_valid_row(row) {
            return None;
        }
        let (start, end) = self.leaf_span(leaf, row, fixed_size.unwrap_or(1))?;
        leaf.values.typed_data::<T::Native>().get(start..end)
    }

    /// The bytes of the cell at `row`'s values, when the column's items are primitives or
    /// fixed-size lists of them without any null (then the bytes are the whole cell; a null
    /// instance would hide whatever its slot holds). `None` otherwise, or for a null cell.
    pub(crate) fn leaf_bytes(&self, row: usize) -> Option<&[u8]> {
        let leaf = self.null_free_leaf()?;
        let width = instance_bytes(self.list.data_type())?;
        if !self.is_valid_row(row) {
            return None;
        }
        let (start, end) = self.leaf_span(leaf, row, width)?;
        leaf.values.as_slice().get(start..end)
    }

    /// The column's leaf, when neither its items nor (for fixed-size lists) their values
    /// hold a null instance: then a cell's leaf values are the whole cell, since a null
    /// instance would hide whatever its slot holds.
    pub(super) fn null_free_leaf(&self) -> Option<&PrimitiveLeaf> {
        self.leaf.as_ref().filter(|_| self.leaf_null_free)
    }

    /// Where the cell at `row` lies in `leaf`, in units of `width` leaf elements or bytes
    /// per item. With one instance per row this is arithmetic, without the offsets.
    fn leaf_span(&self, leaf: &PrimitiveLeaf, row: usize, width: usize) -> Option<(usize, usize)> {
        if self.one_instance_per_row {
            let start = leaf.first_item.checked_add(row)?.checked_mul(width)?;
            return Some((start, start.checked_add(width)?));
        }
        let offsets = self.list.value_offsets();
        let at = |item: &i32| usize::try_from(*item).ok()?.checked_mul(width);
        Some((at(offsets.get(row)?)?, at(offsets.get(row + 1)?)?))
    }

    /// Is `row` a row of this column, with a non-null cell?
    pub(super) fn is_valid_row(&self, row: usize) -> bool {
        row < self.list.len() && self.list.is_valid(row)
    }

    /// Is the cell at `row` non-null? `false` for a row out of bounds.
    #[inline]
    pub fn is_valid(&self, row: usize) -> bool {
        self.is_valid_row(row)
    }

    /// Reads, and discards, what reading the cell at `row` will need: the column's list
    /// type (a line of the column a cell's read goes through) and, with one instance per
    /// row and a primitive leaf, a byte of the cell's values. A latest-at calls this with
    /// the row its time search will probe first
    /// (`TimeColumn::num_positions_at_or_before_touching`), so that those lines are on
    /// their way while the search waits for the times, where each was a dependent cache
    /// miss after it: `latest_at_mono` 14% faster in wall time for 26 instructions more a
    /// query, with as many misses in all (callgrind's cache model over the whole run); a
    /// store in cache pays the instructions for nothing (`clear_recursive` +4%). See
    /// `docs/performance-log.md`. (Reading the cell's validity too was slower.)
    #[inline]
    pub(crate) fn touch_cell(&self, row: usize) {
        std::hint::black_box(matches!(self.list.data_type(), DataType::List(_)));
        if self.cell_bytes != 0
            && let Some(leaf) = &self.leaf
        {
            let at = leaf
                .first_item
                .wrapping_add(row)
                .wrapping_mul(usize::from(self.cell_bytes));
            std::hint::black_box(leaf.values.as_slice().get(at).copied());
        }
    }

    /// [`ComponentColumn::is_valid`] for a row known to be in bounds (the queries' rows
    /// come from the chunk's own time column), without the bounds check.
    #[inline]
    pub(crate) fn is_valid_in_bounds(&self, row: usize) -> bool {
        self.list.is_valid(row)
    }

    /// Bounds of the non-null cells on the chunk's `timeline_position`-th time column.
    pub(crate) fn bounds(&self, timeline_position: usize) -> Option<ComponentTimeBounds> {
        self.bounds_per_timeline
            .get(timeline_position)
            .copied()
            .flatten()
    }

    /// The non-null cell with the greatest row id, as `(row id, row)`, given the chunk's
    /// row ids.
    pub(crate) fn max_row_id_cell(&self, row_ids: &[RowId]) -> Option<(RowId, u32)> {
        let row = self.best_cell_row;
        if row == NO_ROW {
            return None;
        }
        Some((*row_ids.get(row as usize)?, row))
    }
}

trait ListValueTypeRef {
    fn value_type_ref(&self) -> &DataType;
}

impl ListValueTypeRef for ListArray {
    fn value_type_ref(&self) -> &DataType {
        match self.data_type() {
            DataType::List(field) => field.data_type(),
            other => other,
        }
    }
}

/// The row of `list`'s non-null cell with the greatest row id (the last of equals), or
/// [`NO_ROW`] if every cell is null.
#[expect(
    clippy::cast_possible_truncation,
    reason = "rows < 2^32, checked in Chunk::from_raw"
)]
fn best_cell_row(list: &ListArray, row_ids: &[RowId], sorted_by_row_id: bool) -> u32 {
    if sorted_by_row_id {
        // The greatest row id is the last row's: the last non-null cell is the best.
        return (0..list.len())
            .rev()
            .find(|&row| list.is_valid(row))
            .map_or(NO_ROW, |row| row as u32);
    }
    best_cell_row_by_scan(list, row_ids)
}

/// [`best_cell_row`] by reading every row, whatever their order: what the sanity check
/// compares the shortcut with.
#[expect(
    clippy::cast_possible_truncation,
    reason = "rows < 2^32, checked in Chunk::from_raw"
)]
fn best_cell_row_by_scan(list: &ListArray, row_ids: &[RowId]) -> u32 {
    let mut best: Option<(RowId, u32)> = None;
    for (row, &row_id) in row_ids.iter().enumerate() {
        if list.is_valid(row) && best.is_none_or(|(id, _)| row_id >= id) {
            best = Some((row_id, row as u32));
        }
    }
    best.map_or(NO_ROW, |(_, row)| row)
}

/// The bounds of `list`'s non-null cells on one time column, `None` if every cell is null.
#[expect(
    clippy::cast_possible_truncation,
    reason = "rows < 2^32, checked in Chunk::from_raw"
)]
fn time_bounds(
    list: &ListArray,
    column: &TimeColumn,
    row_ids: &[RowId],
) -> Option<ComponentTimeBounds> {
    let times: &[i64] = &column.times;
    if column.index_order.is_none() {
        // Rows in `(time, row id)` order: the first and last non-null cells are the
        // bounds, found from the ends rather than by reading every row.
        let first_valid = (0..times.len()).find(|&row| list.is_valid(row))?;
        let last_valid = (first_valid..times.len())
            .rev()
            .find(|&row| list.is_valid(row))
            .unwrap_or(first_valid);
        return Some(ComponentTimeBounds {
            min_time: TimeInt::saturating(times[first_valid]),
            max_time: TimeInt::saturating(times[last_valid]),
            max_row_id: row_ids[last_valid],
            max_row: last_valid as u32,
        });
    }
    time_bounds_by_scan(list, times, row_ids)
}

/// [`time_bounds`] by reading every row, whatever their order: what the sanity check
/// compares the shortcut with.
#[expect(
    clippy::cast_possible_truncation,
    reason = "rows < 2^32, checked in Chunk::from_raw"
)]
fn time_bounds_by_scan(
    list: &ListArray,
    times: &[i64],
    row_ids: &[RowId],
) -> Option<ComponentTimeBounds> {
    let mut bounds: Option<ComponentTimeBounds> = None;
    for (row, (&time, &row_id)) in times.iter().zip(row_ids).enumerate() {
        if !list.is_valid(row) {
            continue;
        }
        let time = TimeInt::saturating(time);
        let b = bounds.get_or_insert(ComponentTimeBounds {
            min_time: time,
            max_time: time,
            max_row_id: row_id,
            max_row: row as u32,
        });
        b.min_time = b.min_time.min(time);
        if (time, row_id) >= (b.max_time, b.max_row_id) {
            (b.max_time, b.max_row_id, b.max_row) = (time, row_id, row as u32);
        }
    }
    bounds
}

impl ComponentColumn {
    /// Recomputes everything the column derived from its cells.
    pub(super) fn sanity_check(
        &self,
        row_ids: &[RowId],
        time_columns: &[TimeColumn],
    ) -> Result<(), SanityError> {
        let Self {
            descriptor,
            list,
            field,
            bounds_per_timeline,
            best_cell_row: best_row,
            one_instance_per_row,
            leaf_null_free,
            cell_bytes,
            leaf,
        } = self;
        let fail = |invariant| {
            Err(SanityError::new(Structure::ComponentColumn, invariant).at(&descriptor.name))
        };
        if list.len() != row_ids.len() {
            return fail("a component column has one cell per row");
        }
        if field
            .as_ref()
            .is_some_and(|field| !field.data_type().equals_datatype(list.data_type()))
        {
            return fail("the field kept for transport has the column's type");
        }
        let fresh_bounds = time_columns
            .iter()
            .map(|column| time_bounds_by_scan(list, &column.times, row_ids));
        if bounds_per_timeline.len() != time_columns.len()
            || !bounds_per_timeline.iter().copied().eq(fresh_bounds)
        {
            return fail("the bounds on each timeline are those of the non-null cells");
        }
        if *best_row != best_cell_row_by_scan(list, row_ids) {
            return fail("the best cell is the non-null cell of the greatest row id");
        }
        if *one_instance_per_row != has_one_instance_per_row(list) {
            return fail("the one-instance flag matches the offsets");
        }
        if *leaf_null_free != (leaf.is_some() && has_null_free_items(list)) {
            return fail("the null-free flag matches the items' nulls");
        }
        if *cell_bytes != touchable_cell_bytes(list, leaf.is_some(), *one_instance_per_row) {
            return fail("the cell width matches the leaf's shape");
        }
        let leaf_matches = match (leaf, &PrimitiveLeaf::of(list)) {
            (Some(kept), Some(fresh)) => kept.is_the_same(fresh),
            (kept, fresh) => kept.is_none() && fresh.is_none(),
        };
        if !leaf_matches {
            return fail("the primitive leaf is the items' values");
        }
        Ok(())
    }
}
