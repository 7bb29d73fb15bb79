//! What a chunk costs in memory: the Arrow buffers it references (which other chunks may
//! share, so a store must count each once), its own allocations, and the payload its rows
//! really use.

use arrow_array::cast::AsArray;
use arrow_array::{Array, ListArray};
use arrow_buffer::{Buffer, NullBuffer};
use arrow_data::ArrayData;
use arrow_schema::DataType;
use smallvec::SmallVec;

use super::{Chunk, ComponentColumn, TimeColumn};
use crate::RowId;
use crate::sanity::{SanityError, Structure};

/// Heap of one Arrow array node besides its buffers: the array struct behind an `Arc`, its
/// `DataType` and child vector. An estimate; the counting-allocator test holds it to
/// account.
const ARRAY_NODE_BYTES: u64 = 96;
/// Heap of one buffer handle besides its data: the shared `Bytes` header and its `Arc`.
const BUFFER_HANDLE_BYTES: u64 = 64;
/// Heap of one field (name and type behind an `Arc`): a component's own, or a nested
/// type's child.
const FIELD_BYTES: u64 = 128;

/// Memory figures of one chunk, computed once at construction.
#[derive(Debug, Default)]
pub(crate) struct ChunkMemory {
    /// Every distinct Arrow buffer the chunk references (by allocation, not by slice). The
    /// store's ledger keys them by address and reads their reference counts. Room for the
    /// three of a one-timeline chunk of one primitive component (times, offsets, values).
    pub buffers: SmallVec<[Buffer; 3]>,
    /// Heap of `buffers`, each counted once. Kept because reading a buffer's capacity
    /// touches its shared header, a cache miss per buffer on every GC and removal.
    pub buffer_bytes: u64,
    /// Allocations owned by the chunk alone: the struct, row ids, sort orders, the array
    /// and buffer handles.
    pub own_bytes: u64,
    /// See [`Chunk::payload_bytes`].
    pub payload_bytes: u64,
}

/// The range of its items a list's slots reference.
fn referenced_items(list: &ListArray) -> std::ops::Range<usize> {
    let offsets = list.value_offsets();
    // A valid list's offsets are non-negative and ascending (checked when it was built).
    let at = |i: usize| usize::try_from(offsets[i]).unwrap_or(0);
    at(0)..at(offsets.len() - 1)
}

/// An array's validity as `ArrayData` keeps it: not at all when nothing is null (Arrow
/// drops such a bitmap when it builds the tree, so the generic figures never see it).
fn counted_nulls(array: &dyn Array) -> Option<&NullBuffer> {
    array.nulls().filter(|nulls| nulls.null_count() > 0)
}

/// The bytes `data`'s slots reference, children included. Arrow's own
/// `get_slice_memory_size` counts a list's child whole, but a sliced list (a chunk split
/// by compaction) references only the child's range between its first and last offset:
/// counted whole, each piece of a split weighed as much as the chunk it came from, so
/// compaction cut it again and again.
fn referenced_bytes(data: &ArrayData) -> u64 {
    // Only an array built by hand around inconsistent buffers fails Arrow's figure; its
    // whole buffers are then the honest upper bound.
    let arrow_figure = |data: &ArrayData| {
        data.get_slice_memory_size()
            .unwrap_or_else(|_| data.get_buffer_memory_size()) as u64
    };
    let list_range = match data.data_type() {
        DataType::List(_) | DataType::Map(..) => list_child_range::<i32>(data),
        DataType::LargeList(_) => list_child_range::<i64>(data),
        // Arrow slices a fixed-size list's node, not its child.
        DataType::FixedSizeList(_, size) => {
            let size = usize::try_from(*size).unwrap_or(0);
            let range = data.offset() * size..(data.offset() + data.len()) * size;
            data.child_data()
                .first()
                .is_some_and(|child| range.end <= child.len())
                .then_some(range)
        }
        _ if data.child_data().is_empty() => return arrow_figure(data),
        _ => None,
    };
    let children: &[ArrayData] = data.child_data();
    // The node's own buffers: Arrow's figure without its children's.
    let own = children.iter().fold(arrow_figure(data), |own, child| {
        own.saturating_sub(arrow_figure(child))
    });
    let referenced_children: u64 = match (list_range, children) {
        (Some(range), [child]) => referenced_bytes(&child.slice(range.start, range.len())),
        _ => children.iter().map(referenced_bytes).sum(),
    };
    own + referenced_children
}

/// The range of its child that a list's slots reference, if its offsets are readable
/// and inside the child.
fn list_child_range<O: arrow_buffer::ArrowNativeType + TryInto<usize>>(
    data: &ArrayData,
) -> Option<std::ops::Range<usize>> {
    let offsets: &[O] = data.buffers().first()?.typed_data();
    let first = (*offsets.get(data.offset())?).try_into().ok()?;
    let last = (*offsets.get(data.offset() + data.len())?)
        .try_into()
        .ok()?;
    let child = data.child_data().first()?;
    (first <= last && last <= child.len()).then_some(first..last)
}

/// The address that identifies a buffer's allocation, however it is sliced.
pub(crate) fn buffer_address(buffer: &Buffer) -> usize {
    buffer.data_ptr().as_ptr().addr()
}

/// A buffer's heap: its allocation's capacity, or its length when the allocation is
/// foreign and reports none.
pub(crate) fn buffer_bytes(buffer: &Buffer) -> u64 {
    buffer.capacity().max(buffer.len()) as u64
}

impl ChunkMemory {
    pub fn of(chunk: &Chunk) -> Self {
        Self::compute(chunk, false)
    }

    /// [`ChunkMemory::of`]; with `generic`, every column goes through Arrow's `ArrayData`
    /// tree (what the sanity check compares the typed shortcut with).
    pub(super) fn compute(chunk: &Chunk, generic: bool) -> Self {
        let num_rows = chunk.row_ids.len() as u64;
        let mut memory = Self {
            buffers: SmallVec::new(),
            buffer_bytes: 0,
            own_bytes: (size_of::<Chunk>() + 2 * size_of::<usize>()) as u64
                + num_rows * size_of::<RowId>() as u64,
            payload_bytes: num_rows * size_of::<RowId>() as u64,
        };
        if chunk.time_columns.spilled() {
            memory.own_bytes += (chunk.time_columns.capacity() * size_of::<TimeColumn>()) as u64;
        }
        for column in &chunk.time_columns {
            memory.add_buffer(column.times.inner());
            memory.own_bytes += column.field_metadata.heap_bytes();
            memory.own_bytes += column
                .index_order
                .as_ref()
                .map_or(0, |o| o.len() as u64 * 4);
            memory.payload_bytes += num_rows * 8;
        }
        memory.own_bytes += (chunk.components.capacity() * size_of::<ComponentColumn>()) as u64
            + chunk.extra_metadata.heap_bytes();
        for column in &chunk.components {
            if column.field.is_some() {
                memory.own_bytes += FIELD_BYTES;
            }
            if column.bounds_per_timeline.spilled() {
                memory.own_bytes += (column.bounds_per_timeline.capacity()
                    * size_of::<Option<super::ComponentTimeBounds>>())
                    as u64;
            }
            memory.payload_bytes += match column.leaf.as_ref() {
                Some(leaf) if !generic => memory
                    .add_leaf_list(&column.list, &leaf.values)
                    .unwrap_or_else(|| memory.add_list(&column.list)),
                _ => memory.add_list(&column.list),
            };
        }
        // One handle per allocation: columns may share one (a batch decoded from one IPC
        // message). Sorted then deduplicated, so that a chunk of many columns costs
        // O(n log n) rather than a search of every buffer before each.
        memory.buffers.sort_unstable_by_key(buffer_address);
        memory.buffers.dedup_by_key(|buffer| buffer_address(buffer));
        memory.buffers.shrink_to_fit();
        memory.own_bytes += BUFFER_HANDLE_BYTES * memory.buffers.len() as u64;
        memory.buffer_bytes = memory.buffers.iter().map(buffer_bytes).sum();
        memory
    }

    /// A list column through Arrow's generic `ArrayData` tree; returns its payload bytes.
    fn add_list(&mut self, list: &ListArray) -> u64 {
        let data = list.to_data();
        self.add_array(&data);
        // Only an array built by hand around inconsistent buffers fails this; its whole
        // buffers are then the honest upper bound.
        referenced_bytes(&data)
    }

    /// What [`ChunkMemory::add_list`] finds for a list of primitives or of fixed-size
    /// lists of them (`leaf`: its leaf values), read from the typed arrays: building the
    /// `ArrayData` tree, and the layouts Arrow allocates to size it, were a third of the
    /// figures of a small chunk, which compaction builds for every merge. `None` (and
    /// nothing added) for another shape.
    fn add_leaf_list(&mut self, list: &ListArray, leaf: &Buffer) -> Option<u64> {
        let (leaf_type, fixed_size) = super::data_types::leaf_shape(list.data_type())?;
        let width = leaf_type.primitive_width()? as u64;
        let items = list.values();
        let leaf_array: &dyn Array = match fixed_size {
            Some(_) => items.as_fixed_size_list_opt()?.values().as_ref(),
            None => items.as_ref(),
        };
        let bitmap = |len: usize| len.div_ceil(8) as u64;
        // Only the items the slots reference: a sliced list (a piece of a split chunk)
        // keeps its whole child.
        let num_items = referenced_items(list).len();

        let mut payload = list.len() as u64 * size_of::<i32>() as u64;
        self.own_bytes += ARRAY_NODE_BYTES;
        if let DataType::List(field) = list.data_type()
            && !crate::interner::is_shared_field(field)
        {
            self.own_bytes += FIELD_BYTES;
        }
        self.add_buffer(list.offsets().inner().inner());
        if let Some(nulls) = counted_nulls(list) {
            self.add_buffer(nulls.buffer());
            payload += bitmap(list.len());
        }
        if fixed_size.is_some() {
            // The fixed-size list node: no buffer of its own but its validity, and always
            // its own child field.
            self.own_bytes += ARRAY_NODE_BYTES + FIELD_BYTES;
            if let Some(nulls) = counted_nulls(items.as_ref()) {
                self.add_buffer(nulls.buffer());
                payload += bitmap(num_items);
            }
        }
        self.own_bytes += ARRAY_NODE_BYTES;
        self.add_buffer(leaf);
        let leaf_len = num_items * fixed_size.unwrap_or(1);
        payload += leaf_len as u64 * width;
        if let Some(nulls) = counted_nulls(leaf_array) {
            self.add_buffer(nulls.buffer());
            payload += bitmap(leaf_len);
        }
        Some(payload)
    }

    fn add_array(&mut self, data: &ArrayData) {
        self.own_bytes += ARRAY_NODE_BYTES;
        // A nested type holds its child's field behind an `Arc` of its own, unless that is
        // the process-wide shared copy (a list's item field usually is; see
        // `crate::interner`), which no chunk owns.
        let owns_child_field = match data.data_type() {
            DataType::List(field) => !crate::interner::is_shared_field(field),
            DataType::LargeList(_) | DataType::FixedSizeList(..) => true,
            _ => false,
        };
        if owns_child_field {
            self.own_bytes += FIELD_BYTES;
        }
        for buffer in data.buffers() {
            self.add_buffer(buffer);
        }
        if let Some(nulls) = data.nulls() {
            self.add_buffer(nulls.buffer());
        }
        for child in data.child_data() {
            self.add_array(child);
        }
    }

    /// Records a buffer the chunk references (duplicates are removed once all are in).
    fn add_buffer(&mut self, buffer: &Buffer) {
        // The columns of a chunk decoded from one IPC message all slice its one allocation:
        // skipping the repeat of the last buffer keeps their handles inline.
        if self
            .buffers
            .last()
            .is_some_and(|last| buffer_address(last) == buffer_address(buffer))
        {
            return;
        }
        self.buffers.push(buffer.clone());
    }

    pub fn heap_size_bytes(&self) -> u64 {
        self.own_bytes + self.buffer_bytes
    }

    /// Does the chunk alone hold its buffers? Each is then referenced exactly twice (once
    /// by its column, once by [`ChunkMemory::buffers`]), plus once per handle in
    /// `also_held` on the same allocation (the chunk's own further handles). Any further
    /// reference is another array (perhaps another chunk) sharing it.
    pub fn owns_all_buffers(&self, also_held: &[&Buffer]) -> bool {
        let mut also_held: SmallVec<[usize; 4]> =
            also_held.iter().map(|b| buffer_address(b)).collect();
        also_held.sort_unstable();
        self.buffers.iter().all(|b| {
            let address = buffer_address(b);
            let extra = also_held.partition_point(|&a| a <= address)
                - also_held.partition_point(|&a| a < address);
            b.strong_count() == 2 + extra
        })
    }

    /// Recounts every figure from the chunk's columns.
    pub fn sanity_check(&self, chunk: &Chunk) -> Result<(), SanityError> {
        let Self {
            buffers,
            buffer_bytes,
            own_bytes,
            payload_bytes,
        } = self;
        let fresh = Self::compute(chunk, true);
        let addresses = |buffers: &[Buffer]| {
            let mut a: Vec<usize> = buffers.iter().map(buffer_address).collect();
            a.sort_unstable();
            a
        };
        let fail =
            |invariant| Err(SanityError::new(Structure::ChunkMemory, invariant).at(chunk.id()));
        if addresses(&fresh.buffers) != addresses(buffers) {
            return fail("the buffers are the distinct allocations of the chunk's columns");
        }
        if fresh.buffer_bytes != *buffer_bytes {
            return fail("buffer bytes are the buffers' capacities, each counted once");
        }
        if fresh.own_bytes != *own_bytes {
            return fail("own bytes are the chunk's own allocations");
        }
        if fresh.payload_bytes != *payload_bytes {
            return fail("payload bytes are the bytes the rows use");
        }
        Ok(())
    }
}
