//! The [`Chunk`]: an immutable batch of rows of one entity, its validation, and everything
//! the store's indices need from it, computed once at construction (sort orders, time
//! ranges per timeline and per component, static winners).

mod builder;
mod component_column;
mod data_types;
mod equality;
mod error;
pub(crate) mod memory;
mod metadata;
mod rewrite;
mod row_columns;
mod time_column;
mod transport;

use arrow_array::{Array, ArrayRef};
use arrow_buffer::Buffer;
use smallvec::SmallVec;

use crate::sanity::{SanityError, Structure};
use crate::{ChunkId, ComponentDescriptor, EntityPath, RowId, TimeInt, Timeline};

pub use builder::ChunkBuilder;
pub use component_column::ComponentColumn;
pub(crate) use component_column::ComponentTimeBounds;
use component_column::RawComponentColumn;
pub(crate) use data_types::equal_element_types;
pub use error::ChunkError;
use metadata::Metadata;
#[cfg(feature = "ipc")]
pub(crate) use metadata::str_entries;
pub(crate) use rewrite::RowSource;
pub(crate) use row_columns::RowColumns;
pub use time_column::TimeColumn;
use time_column::{RawTimeColumn, RawTimes};
#[cfg(feature = "rrd")]
pub(crate) use transport::row_id_field;

/// An immutable batch of rows of one entity: a row-id column, zero or more time columns
/// (none: the chunk is *static*), and one or more component columns (Arrow `List` arrays,
/// one cell per row; a null cell means "no data for this component in this row").
///
/// ```
/// use std::sync::Arc;
/// use arrow_array::{builder::{Float64Builder, ListBuilder}, ArrayRef, Int64Array};
/// use chunkstore::{Chunk, ChunkId, EntityPath, RowId, Timeline};
///
/// let mut scalars = ListBuilder::new(Float64Builder::new());
/// for value in [1.0, 2.0] {
///     scalars.values().append_value(value);
///     scalars.append(true);
/// }
/// let chunk = Chunk::try_new(
///     ChunkId::new(),
///     EntityPath::parse("/sensors/temperature").unwrap(),
///     vec![RowId::new(), RowId::new()],
///     vec![(Timeline::sequence("frame"), Arc::new(Int64Array::from(vec![7, 3])) as ArrayRef)],
///     vec![("scalar".into(), Arc::new(scalars.finish()) as ArrayRef)],
/// )
/// .unwrap();
/// assert_eq!(chunk.num_rows(), 2);
/// assert!(!chunk.time_column("frame").unwrap().is_sorted());
/// ```
#[derive(Debug)]
// Fields in the order a query reads them, so that its reads share cache lines: behind
// the `Arc`'s counts (which a query's answer touches anyway), the component columns, the
// row ids, the flags and the first time column's times, range and order fill the first
// 128 bytes; what only inserts, removals and transport read comes after. Rust's own
// layout spread these over four or five lines of the chunk's 352 bytes
// (`docs/performance-log.md`).
#[repr(C)]
pub struct Chunk {
    components: Vec<ComponentColumn>,
    row_ids: Box<[RowId]>,
    /// Row of the greatest row id (a position, not an id: a quarter of the bytes).
    max_row_id_row: u32,
    is_sorted_by_row_id: bool,
    /// Is one of the components [`crate::ComponentName::CLEAR_IS_RECURSIVE`]? Kept so that
    /// removal, GC and a query's check of its answer need not compare a component's name.
    has_clears: bool,
    /// Did the chunk alone hold its Arrow buffers when it was built? Then a store need not
    /// read every buffer's shared reference count (a cold cache line each) on insert.
    owned_buffers_when_built: bool,
    /// Inline room for one: most chunks have one timeline, and a streamed row's chunk is
    /// small enough that a second inline column would be a tenth of it.
    time_columns: SmallVec<[TimeColumn; 1]>,
    id: ChunkId,
    /// The least row id, kept here because garbage collection and removal key chunks by
    /// it (reading it from the row ids would cost a cache miss per chunk).
    min_row_id: RowId,
    entity_path: EntityPath,
    /// Schema metadata other than `rerun:id` and `rerun:entity_path`, kept for lossless
    /// transport.
    extra_metadata: Metadata,
    /// Heap the chunk and its Arrow buffers occupy; see [`memory`].
    memory: memory::ChunkMemory,
}

/// A chunk's time columns before validation: most chunks have one or two timelines, so
/// they stay inline (a one-row chunk's decode allocates little besides its arrays).
type RawTimeColumns = SmallVec<[RawTimeColumn; 2]>;

/// A chunk's component columns before validation, inline for a few.
type RawComponentColumns = SmallVec<[RawComponentColumn; 4]>;

/// Every component name is non-empty and appears once. A set for many columns (a chunk
/// may have 100,000); for the few most chunks have, comparing each with those before it
/// costs less than making the set (a merge of one-row chunks builds a chunk per 16 rows).
fn check_component_names(raw_components: &[RawComponentColumn]) -> Result<(), ChunkError> {
    const FEW_COLUMNS: usize = 16;
    let names = raw_components
        .iter()
        .map(|raw| raw.descriptor.name.as_str());
    if names.clone().any(str::is_empty) {
        return Err(ChunkError::EmptyName { kind: "component" });
    }
    let duplicate = if raw_components.len() <= FEW_COLUMNS {
        names
            .clone()
            .enumerate()
            .find(|&(i, name)| names.clone().take(i).any(|before| before == name))
            .map(|(_, name)| name)
    } else {
        let mut seen: ahash::HashSet<&str> = ahash::HashSet::default();
        seen.reserve(raw_components.len());
        names.clone().find(|&name| !seen.insert(name))
    };
    match duplicate {
        Some(name) => Err(ChunkError::DuplicateComponent {
            component: name.to_owned(),
        }),
        None => Ok(()),
    }
}

/// What [`Chunk::from_raw`] knows of who else holds the new chunk's Arrow buffers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Buffers {
    /// Nothing: every buffer's reference count is read.
    Unknown,
    /// A slice: the source chunk, alive while the slice is built, shares every one of
    /// them (reading the counts was an eighth of slicing a small piece).
    SharedWithSource,
}

impl Chunk {
    /// Builds a chunk from columns, validating everything SEMANTICS.md section 2 asks.
    ///
    /// `time_columns` pairs a timeline with an `Int64`, `Duration(ns)` or `Timestamp(ns)`
    /// array (the timeline's [`crate::TimeType`] must match the array's type);
    /// `components` pairs a descriptor with a `List` array. All have one value per row id.
    ///
    /// # Errors
    /// A [`ChunkError`] naming the offending column.
    pub fn try_new(
        id: ChunkId,
        entity_path: EntityPath,
        row_ids: Vec<RowId>,
        time_columns: Vec<(Timeline, ArrayRef)>,
        components: Vec<(ComponentDescriptor, ArrayRef)>,
    ) -> Result<Self, ChunkError> {
        let time_columns = time_columns
            .into_iter()
            .map(|(timeline, array)| {
                let actual = crate::TimeType::from_arrow(array.data_type());
                if actual != Some(timeline.time_type()) {
                    return Err(ChunkError::BadTimeType {
                        timeline: timeline.name().to_owned(),
                        data_type: array.data_type().clone(),
                    });
                }
                Ok(RawTimeColumn {
                    timeline,
                    times: RawTimes::Array(array),
                    field_metadata: Metadata::default(),
                })
            })
            .collect::<Result<RawTimeColumns, _>>()?;
        let components = components
            .into_iter()
            .map(|(descriptor, array)| RawComponentColumn {
                descriptor,
                array,
                field: None,
                from_accepted_cells: false,
            })
            .collect();
        Self::from_raw(
            id,
            entity_path,
            row_ids,
            time_columns,
            components,
            Metadata::default(),
            Buffers::Unknown,
        )
    }

    /// Like [`Chunk::try_new`], for data known to be valid.
    ///
    /// # Panics
    /// If the columns are invalid (see [`Chunk::try_new`]).
    #[expect(clippy::expect_used, reason = "documented panicking constructor")]
    pub fn new(
        id: ChunkId,
        entity_path: EntityPath,
        row_ids: Vec<RowId>,
        time_columns: Vec<(Timeline, ArrayRef)>,
        components: Vec<(ComponentDescriptor, ArrayRef)>,
    ) -> Self {
        Self::try_new(id, entity_path, row_ids, time_columns, components)
            .expect("Chunk::new was given invalid columns")
    }

    fn from_raw(
        id: ChunkId,
        entity_path: EntityPath,
        row_ids: Vec<RowId>,
        raw_times: RawTimeColumns,
        raw_components: RawComponentColumns,
        extra_metadata: Metadata,
        buffers: Buffers,
    ) -> Result<Self, ChunkError> {
        let num_rows = row_ids.len();
        if num_rows == 0 {
            return Err(ChunkError::NoRows);
        }
        if u32::try_from(num_rows).is_err() {
            return Err(ChunkError::TooManyRows { num_rows });
        }
        // Indices address columns by u32 too; no real batch comes near.
        if u32::try_from(raw_times.len() + raw_components.len()).is_err() {
            return Err(ChunkError::TooManyColumns {
                num_columns: raw_times.len() + raw_components.len(),
            });
        }
        if raw_components.is_empty() {
            return Err(ChunkError::NoComponents);
        }
        let is_sorted_by_row_id = row_ids.is_sorted();
        let (min_row, max_row_id_row) = if is_sorted_by_row_id {
            // The first row, and the first of the last row's equals (as the scan finds).
            let last = row_ids[num_rows - 1];
            (
                0,
                u32::try_from(row_ids.partition_point(|id| *id < last)).unwrap_or(0),
            )
        } else {
            row_id_range_rows(&row_ids)
        };
        let min_row_id = row_ids[min_row as usize];

        let mut time_columns = SmallVec::<[TimeColumn; 1]>::new();
        for raw in raw_times {
            if raw.timeline.name().is_empty() {
                return Err(ChunkError::EmptyName { kind: "timeline" });
            }
            if time_columns
                .iter()
                .any(|c: &TimeColumn| c.timeline.name() == raw.timeline.name())
            {
                return Err(ChunkError::DuplicateTimeline {
                    timeline: raw.timeline.name().to_owned(),
                });
            }
            time_columns.push(TimeColumn::try_new(raw, &row_ids)?);
        }

        let mut components: Vec<ComponentColumn> = Vec::with_capacity(raw_components.len());
        check_component_names(&raw_components)?;
        for raw in raw_components {
            components.push(ComponentColumn::try_new(
                raw,
                &row_ids,
                is_sorted_by_row_id,
                &time_columns,
            )?);
        }

        let has_clears = components.iter().any(|c| c.descriptor.name.is_clear());
        let mut chunk = Self {
            id,
            entity_path,
            row_ids: row_ids.into_boxed_slice(),
            is_sorted_by_row_id,
            has_clears,
            owned_buffers_when_built: false,
            time_columns,
            components,
            extra_metadata,
            min_row_id,
            max_row_id_row,
            memory: memory::ChunkMemory::default(),
        };
        chunk.memory = memory::ChunkMemory::of(&chunk);
        chunk.owned_buffers_when_built = match buffers {
            Buffers::Unknown => chunk.owns_all_buffers_now(),
            Buffers::SharedWithSource => false,
        };
        debug_assert!(chunk.sanity_check().is_ok(), "{:?}", chunk.sanity_check());
        Ok(chunk)
    }

    /// The chunk's id.
    pub fn id(&self) -> ChunkId {
        self.id
    }

    /// The entity all rows belong to.
    pub fn entity_path(&self) -> &EntityPath {
        &self.entity_path
    }

    /// Number of rows.
    pub fn num_rows(&self) -> usize {
        self.row_ids.len()
    }

    /// A chunk without time columns holds static data.
    pub fn is_static(&self) -> bool {
        self.time_columns.is_empty()
    }

    /// The row ids, in row order.
    pub fn row_ids(&self) -> &[RowId] {
        &self.row_ids
    }

    /// Are the row ids ascending?
    pub fn is_sorted_by_row_id(&self) -> bool {
        self.is_sorted_by_row_id
    }

    /// The time columns, in the order given.
    pub fn time_columns(&self) -> &[TimeColumn] {
        &self.time_columns
    }

    /// The time column of a timeline, by name.
    pub fn time_column(&self, timeline: &str) -> Option<&TimeColumn> {
        self.time_columns
            .iter()
            .find(|c| c.timeline.name() == timeline)
    }

    /// The component columns, in the order given.
    pub fn components(&self) -> &[ComponentColumn] {
        &self.components
    }

    /// A component column, by name.
    pub fn component(&self, name: &str) -> Option<&ComponentColumn> {
        self.components
            .iter()
            .find(|c| c.descriptor.name.as_str() == name)
    }

    /// The cell of `component` at `row`: `None` if the column is absent, the row out of
    /// bounds or the cell null. The slice shares the chunk's buffers (no copy).
    pub fn cell(&self, component: &str, row: usize) -> Option<ArrayRef> {
        self.component(component).and_then(|c| c.cell(row))
    }

    /// The index `(time, row id)` of `row` on the `time_column`-th time column.
    #[inline]
    pub(crate) fn index_of_row(&self, time_column: usize, row: usize) -> (TimeInt, RowId) {
        let time = self.time_columns[time_column].times[row];
        (TimeInt::saturating(time), self.row_ids[row])
    }

    /// Reads, and discards, a word on each of the chunk's cache lines an insert reads
    /// (its struct's, its first column's and its greatest row id's), so that they load
    /// together: a batch of rows was usually built long before it is inserted and is
    /// cold, and the insert's own reads of it come one after another between lookups of
    /// the store's maps, some found through others (the column and the row ids through
    /// the struct's first line). `insert_batched` 581–611 → 503–533 ns a chunk (four
    /// alternating runs each; `docs/performance-log.md`). A chunk of one
    /// row (a streamed row, usually built just before) is left alone: the 45 instructions
    /// bought nothing on `out_of_order`'s inserts.
    #[inline]
    pub(crate) fn touch_for_insert(&self) {
        if self.row_ids.len() >= 2 {
            self.touch_lines();
        }
    }

    /// The reads of [`Chunk::touch_for_insert`], out of line: a streamed row's insert pays
    /// only the check above.
    #[inline(never)]
    fn touch_lines(&self) {
        std::hint::black_box((self.id, self.memory.own_bytes, self.row_id_range().1));
        if let Some(column) = self.components.first() {
            std::hint::black_box((
                column.bounds(0),
                matches!(column.list.data_type(), arrow_schema::DataType::List(_)),
            ));
        }
    }

    /// Reads, and discards, a word on each line of the chunk's struct that a garbage
    /// collection's plan reads (its columns' address, id, path, time bounds and figures),
    /// so that the misses of a batch of candidates overlap (`gc.rs`, `PLAN_BATCH`).
    #[inline]
    pub(crate) fn touch_struct(&self) {
        std::hint::black_box((
            self.components.len(),
            self.id,
            self.entity_path.num_parts(),
            self.memory.own_bytes,
            self.time_columns.first().map(TimeColumn::time_range),
        ));
    }

    /// Reads, and discards, the first column's bounds, found through the struct's first
    /// line: the second step of [`Chunk::touch_struct`].
    #[inline]
    pub(crate) fn touch_first_column(&self) {
        if let Some(column) = self.components.first() {
            std::hint::black_box(column.bounds(0));
        }
    }

    /// Least and greatest row id of the chunk's rows.
    pub fn row_id_range(&self) -> (RowId, RowId) {
        (self.min_row_id, self.row_ids[self.max_row_id_row as usize])
    }

    /// Bytes of heap the chunk occupies: its own allocations plus the whole capacity of
    /// every Arrow buffer it references (each counted once, however many columns share
    /// it). A store counts a buffer shared by several chunks once; see
    /// [`crate::StoreStats`].
    pub fn heap_size_bytes(&self) -> u64 {
        self.memory.heap_size_bytes()
    }

    /// Heap the chunk owns alone (everything but its Arrow buffers).
    pub(crate) fn own_heap_bytes(&self) -> u64 {
        self.memory.own_bytes
    }

    /// Every distinct Arrow buffer the chunk references.
    pub(crate) fn buffers(&self) -> &[arrow_buffer::Buffer] {
        &self.memory.buffers
    }

    /// Heap of [`Chunk::buffers`], each counted once (read without touching them).
    pub(crate) fn buffer_bytes(&self) -> u64 {
        self.memory.buffer_bytes
    }

    /// Does the chunk have a Clear column? Read from the chunk's first cache line, where
    /// asking a column its name reads the column and the name.
    #[inline]
    pub(crate) fn has_clears(&self) -> bool {
        self.has_clears
    }

    /// The Clear column ([`crate::ComponentName::CLEAR_IS_RECURSIVE`]), if the chunk has
    /// one.
    pub(crate) fn clear_column(&self) -> Option<&ComponentColumn> {
        if self.has_clears {
            self.component(crate::ComponentName::CLEAR_IS_RECURSIVE)
        } else {
            None
        }
    }

    /// Does the chunk alone hold its Arrow buffers (no other array shares them)?
    ///
    /// A chunk that did when it was built is taken to still do: only a caller taking
    /// its columns out to build another chunk from them could change that, and a store
    /// deciding when the second chunk arrives could not tell which came first either.
    pub(crate) fn owns_all_buffers(&self) -> bool {
        self.owned_buffers_when_built || self.owns_all_buffers_now()
    }

    /// Reads every buffer's reference count; a column's primitive leaf is one more
    /// reference of the chunk's own.
    fn owns_all_buffers_now(&self) -> bool {
        let leaves: SmallVec<[&Buffer; 2]> = self
            .components
            .iter()
            .filter_map(|c| c.leaf.as_ref().map(|leaf| &leaf.values))
            .collect();
        self.memory.owns_all_buffers(&leaves)
    }

    /// Bytes of data the chunk's rows really use (row ids, times, offsets, validity and
    /// the referenced part of each values array), whatever the buffers around them hold.
    /// Compaction thresholds are measured in these.
    pub fn payload_bytes(&self) -> u64 {
        self.memory.payload_bytes
    }

    /// Checks every invariant of the chunk, its columns and its memory figures;
    /// construction guarantees them, so an error here is a bug in this crate.
    ///
    /// # Errors
    /// The first broken invariant.
    pub fn sanity_check(&self) -> Result<(), SanityError> {
        let Self {
            id,
            entity_path: _, // parsed and validated by its own type
            row_ids,
            is_sorted_by_row_id,
            has_clears,
            owned_buffers_when_built: _, // a fact of the past; nothing to check it against
            time_columns,
            components,
            extra_metadata,
            min_row_id,
            max_row_id_row,
            memory,
        } = self;
        let fail = |invariant| Err(SanityError::new(Structure::Chunk, invariant).at(id));
        let n = row_ids.len();
        if n == 0 || components.is_empty() {
            return fail("a chunk has rows and components");
        }
        if u32::try_from(n).is_err()
            || u32::try_from(time_columns.len() + components.len()).is_err()
        {
            return fail("rows and columns are numbered by u32");
        }
        if *is_sorted_by_row_id != row_ids.is_sorted() {
            return fail("is_sorted_by_row_id matches the row ids");
        }
        if *has_clears != components.iter().any(|c| c.descriptor.name.is_clear()) {
            return fail("has_clears matches the components");
        }
        if *max_row_id_row as usize >= n
            || row_ids.iter().min() != Some(min_row_id)
            || row_ids.iter().max() != Some(&row_ids[*max_row_id_row as usize])
        {
            return fail("row_id_range spans the row ids");
        }
        if extra_metadata.contains_key(transport::META_ID)
            || extra_metadata.contains_key(transport::META_ENTITY_PATH)
        {
            return fail("id and entity path are not duplicated in extra metadata");
        }
        for (position, column) in time_columns.iter().enumerate() {
            let name = column.timeline.name();
            if name.is_empty()
                || time_columns[..position]
                    .iter()
                    .any(|c| c.timeline.name() == name)
            {
                return fail("timelines are named, each once");
            }
            column.sanity_check(row_ids)?;
        }
        let mut names = ahash::HashSet::default();
        for column in components {
            if column.descriptor.name.as_str().is_empty()
                || !names.insert(column.descriptor.name.as_str())
            {
                return fail("components are named, each once");
            }
            column.sanity_check(row_ids, time_columns)?;
        }
        memory.sanity_check(self)
    }
}

/// Rows of the least and greatest row id (the first of equals for the least, the last for
/// the greatest; `row_ids` is not empty and shorter than `2^32`, checked by the caller).
#[expect(
    clippy::cast_possible_truncation,
    reason = "rows < 2^32, checked in Chunk::from_raw"
)]
pub(super) fn row_id_range_rows(row_ids: &[RowId]) -> (u32, u32) {
    let (mut min, mut max) = (0, 0);
    for (row, id) in row_ids.iter().enumerate() {
        if *id < row_ids[min] {
            min = row;
        }
        if *id > row_ids[max] {
            max = row;
        }
    }
    (min as u32, max as u32)
}

#[cfg(test)]
mod tests;
