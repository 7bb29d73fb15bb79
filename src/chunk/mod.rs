//! The [`Chunk`]: an immutable batch of rows of one entity, its validation, and everything
//! the store's indices need from it, computed once at construction (sort orders, time
//! ranges per timeline and per component, static winners).

mod builder;
mod equality;
pub(crate) mod memory;
mod rewrite;
mod transport;

use std::collections::HashMap;

use arrow_array::cast::AsArray;
use arrow_array::{Array, ArrayRef, ArrowPrimitiveType, ListArray};
use arrow_buffer::{Buffer, ScalarBuffer};
use arrow_schema::{DataType, FieldRef};
use smallvec::SmallVec;

use crate::error::ChunkError;
use crate::{ChunkId, ComponentDescriptor, ComponentName, EntityPath, RowId, TimeInt, Timeline};

pub use builder::ChunkBuilder;
pub(crate) use rewrite::RowSource;

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
pub struct Chunk {
    id: ChunkId,
    entity_path: EntityPath,
    row_ids: Box<[RowId]>,
    is_sorted_by_row_id: bool,
    /// Is one of the components [`crate::ComponentName::CLEAR_IS_RECURSIVE`]? Kept so that
    /// removal and GC need not compare every component's name (a cold string per chunk).
    has_clears: bool,
    /// Did the chunk alone hold its Arrow buffers when it was built? Then a store need not
    /// read every buffer's shared reference count (a cold cache line each) on insert.
    owned_buffers_when_built: bool,
    /// Inline room for one: most chunks have one timeline, and a streamed row's chunk is
    /// small enough that a second inline column would be a tenth of it.
    time_columns: SmallVec<[TimeColumn; 1]>,
    components: Vec<ComponentColumn>,
    /// Schema metadata other than `rerun:id` and `rerun:entity_path`, kept for lossless
    /// transport.
    extra_metadata: Metadata,
    /// The least row id, kept here because garbage collection and removal key chunks by
    /// it (reading it from the row ids would cost a cache miss per chunk).
    min_row_id: RowId,
    /// Row of the greatest row id (a position, not an id: a quarter of the bytes).
    max_row_id_row: u32,
    /// Heap the chunk and its Arrow buffers occupy; see [`memory`].
    memory: memory::ChunkMemory,
}

/// One timeline's times in a chunk.
#[derive(Debug)]
pub struct TimeColumn {
    timeline: Timeline,
    times: ScalarBuffer<i64>,
    /// The column's Arrow type as given (a timestamp may carry a timezone).
    data_type: DataType,
    /// Field metadata as given, for lossless transport.
    field_metadata: Metadata,
    is_sorted: bool,
    /// Row positions in ascending `(time, row id)` order; `None` when the rows already are.
    index_order: Option<Box<[u32]>>,
    time_range: (TimeInt, TimeInt),
}

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

/// One component's column in a chunk.
#[derive(Debug)]
pub struct ComponentColumn {
    descriptor: ComponentDescriptor,
    list: ListArray,
    /// The column's field as given (its name and metadata), for lossless transport; `None`
    /// for a column built through the API, whose field is named after the component and
    /// carries no metadata (derived when needed rather than allocated per chunk).
    field: Option<FieldRef>,
    /// Per time column of the chunk (same order): bounds of the non-null cells, `None` when
    /// every cell is null.
    bounds_per_timeline: SmallVec<[Option<ComponentTimeBounds>; 1]>,
    /// For every chunk: the row of the non-null cell with the greatest row id, or
    /// [`NO_ROW`] if every cell is null. It is the static winner of a static chunk. (A
    /// sentinel rather than an `Option`, so that the flag below fits in the same word.)
    best_cell_row: u32,
    /// Does every cell span exactly one instance? See
    /// [`ComponentColumn::has_one_instance_per_row`].
    one_instance_per_row: bool,
    /// The primitive values beneath the items, when there are such; see [`PrimitiveLeaf`].
    leaf: Option<PrimitiveLeaf>,
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
struct PrimitiveLeaf {
    /// Starting at the items' first value (any slicing already applied). A second handle on
    /// the leaf array's buffer: it shares the allocation.
    values: Buffer,
}

impl PrimitiveLeaf {
    /// The leaf of `list`'s items, if they are primitives or fixed-size lists of them.
    fn of(list: &ListArray) -> Option<Self> {
        let items = match list.values().as_fixed_size_list_opt() {
            Some(fixed) => fixed.values(),
            None => list.values(),
        };
        let values = arrow_array::downcast_primitive_array!(
            items => items.values().inner().clone(),
            _ => return None
        );
        Some(Self { values })
    }

    /// The same values: the very same bytes, not equal ones.
    fn is_the_same(&self, other: &Self) -> bool {
        (self.values.as_ptr(), self.values.len()) == (other.values.as_ptr(), other.values.len())
    }
}

/// The leaf type of a list type whose items are primitives or fixed-size lists of them,
/// and the fixed size (`None` for primitive items). Arrow checks that a list's values have
/// its item type, so this is the type of the values a [`PrimitiveLeaf`] holds.
fn leaf_shape(list_type: &DataType) -> Option<(&DataType, Option<usize>)> {
    let DataType::List(item) = list_type else {
        return None;
    };
    match item.data_type() {
        DataType::FixedSizeList(leaf, size) => {
            Some((leaf.data_type(), Some(usize::try_from(*size).ok()?)))
        }
        primitive => Some((primitive, None)),
    }
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
            .collect::<Result<Vec<_>, _>>()?;
        let components = components
            .into_iter()
            .map(|(descriptor, array)| RawComponentColumn {
                descriptor,
                array,
                field: None,
            })
            .collect();
        Self::from_raw(
            id,
            entity_path,
            row_ids,
            time_columns,
            components,
            Metadata::default(),
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
        raw_times: Vec<RawTimeColumn>,
        raw_components: Vec<RawComponentColumn>,
        extra_metadata: Metadata,
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
            return Err(ChunkError::TooManyRows {
                num_rows: raw_times.len() + raw_components.len(),
            });
        }
        if raw_components.is_empty() {
            return Err(ChunkError::NoComponents);
        }
        let is_sorted_by_row_id = row_ids.is_sorted();
        let (min_row, max_row_id_row) = row_id_range_rows(&row_ids);
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
        // A set, not a search of the columns before each: a chunk may have 100,000.
        let mut names: ahash::HashSet<&str> = ahash::HashSet::default();
        names.reserve(raw_components.len());
        for raw in &raw_components {
            let name = raw.descriptor.name.as_str();
            if name.is_empty() {
                return Err(ChunkError::EmptyName { kind: "component" });
            }
            if !names.insert(name) {
                return Err(ChunkError::DuplicateComponent {
                    component: name.to_owned(),
                });
            }
        }
        drop(names);
        for raw in raw_components {
            components.push(ComponentColumn::try_new(raw, &row_ids, &time_columns)?);
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
        chunk.owned_buffers_when_built = chunk.owns_all_buffers_now();
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

    /// Checks every invariant of the chunk; construction guarantees them, so an error here
    /// is a bug in this crate.
    ///
    /// # Errors
    /// A description of the first broken invariant.
    pub fn sanity_check(&self) -> Result<(), String> {
        let Self {
            id: _,
            entity_path: _,
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
        let n = row_ids.len();
        if n == 0 || components.is_empty() {
            return Err("a chunk has rows and components".into());
        }
        if *is_sorted_by_row_id != row_ids.is_sorted() {
            return Err("is_sorted_by_row_id matches the row ids".into());
        }
        if *has_clears != components.iter().any(|c| c.descriptor.name.is_clear()) {
            return Err("has_clears matches the components".into());
        }
        if *max_row_id_row as usize >= n
            || row_ids.iter().min() != Some(min_row_id)
            || row_ids.iter().max() != Some(&row_ids[*max_row_id_row as usize])
        {
            return Err("row_id_range spans the row ids".into());
        }
        memory.sanity_check(self)?;
        if extra_metadata.contains_key(transport::META_ID)
            || extra_metadata.contains_key(transport::META_ENTITY_PATH)
        {
            return Err("id and entity path are not duplicated in extra metadata".into());
        }
        for column in time_columns {
            column.sanity_check(row_ids)?;
        }
        for column in components {
            if column.list.len() != n {
                return Err(format!(
                    "component {} has one cell per row",
                    column.descriptor.name
                ));
            }
            if column.bounds_per_timeline.len() != time_columns.len() {
                return Err("component bounds exist for every timeline".into());
            }
            if column.one_instance_per_row != has_one_instance_per_row(&column.list) {
                return Err(format!(
                    "component {}'s one-instance flag matches its offsets",
                    column.descriptor.name
                ));
            }
            let leaf_matches = match (&column.leaf, &PrimitiveLeaf::of(&column.list)) {
                (Some(kept), Some(fresh)) => kept.is_the_same(fresh),
                (kept, fresh) => kept.is_none() && fresh.is_none(),
            };
            if !leaf_matches {
                return Err(format!(
                    "component {}'s primitive leaf is its items' values",
                    column.descriptor.name
                ));
            }
        }
        Ok(())
    }
}

/// `list` with its item field replaced by the process-wide shared copy of an equal field
/// (see [`crate::shared`]): the same data, and a type that compares by pointer.
fn with_shared_item_field(list: &ListArray) -> ListArray {
    let DataType::List(field) = list.data_type() else {
        return list.clone();
    };
    let shared = crate::shared::share_field(field);
    if std::sync::Arc::ptr_eq(&shared, field) {
        return list.clone();
    }
    // The parts come from a valid list and the field is equal, so this does not fail; if
    // it ever did, the list keeps its own field.
    ListArray::try_new(
        shared,
        list.offsets().clone(),
        std::sync::Arc::clone(list.values()),
        list.nulls().cloned(),
    )
    .unwrap_or_else(|_| list.clone())
}

/// Does every cell of `list` span exactly one value?
fn has_one_instance_per_row(list: &ListArray) -> bool {
    list.value_offsets().windows(2).all(|w| w[1] - w[0] == 1)
}

/// No row: a chunk has fewer than `u32::MAX` rows (checked in `Chunk::from_raw`), so its
/// rows are numbered below this.
const NO_ROW: u32 = u32::MAX;

/// Rows of the least and greatest row id (the first of equals for the least, the last for
/// the greatest; `row_ids` is not empty and shorter than `2^32`, checked by the caller).
#[expect(
    clippy::cast_possible_truncation,
    reason = "rows < 2^32, checked in Chunk::from_raw"
)]
fn row_id_range_rows(row_ids: &[RowId]) -> (u32, u32) {
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

struct RawTimeColumn {
    timeline: Timeline,
    times: RawTimes,
    field_metadata: Metadata,
}

/// A time column's data before validation.
enum RawTimes {
    /// As given: checked for length and nulls, then read as `i64`.
    Array(ArrayRef),
    /// Copied from a valid column (compaction, slices): already `i64`, without nulls.
    Copied {
        times: ScalarBuffer<i64>,
        data_type: DataType,
    },
}

struct RawComponentColumn {
    descriptor: ComponentDescriptor,
    array: ArrayRef,
    field: Option<FieldRef>,
}

/// String metadata kept only for lossless transport: almost always empty, so it costs one
/// pointer until it is not.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
#[expect(
    clippy::box_collection,
    reason = "one pointer instead of a 48-byte empty map in every chunk and time column"
)]
pub(crate) struct Metadata(Option<Box<HashMap<String, String>>>);

impl Metadata {
    pub(crate) fn new(map: HashMap<String, String>) -> Self {
        Self((!map.is_empty()).then(|| Box::new(map)))
    }

    /// A copy of the entries.
    pub(crate) fn to_map(&self) -> HashMap<String, String> {
        self.0.as_deref().cloned().unwrap_or_default()
    }

    pub(crate) fn contains_key(&self, key: &str) -> bool {
        self.0.as_ref().is_some_and(|map| map.contains_key(key))
    }

    /// Heap the entries' map occupies (its strings aside).
    pub(crate) fn heap_bytes(&self) -> u64 {
        self.0
            .as_ref()
            .map_or(0, |_| size_of::<HashMap<String, String>>() as u64)
    }
}

impl TimeColumn {
    #[expect(
        clippy::cast_possible_truncation,
        reason = "rows < 2^32, checked in Chunk::from_raw"
    )]
    fn try_new(raw: RawTimeColumn, row_ids: &[RowId]) -> Result<Self, ChunkError> {
        let RawTimeColumn {
            timeline,
            times,
            field_metadata,
        } = raw;
        let name = || timeline.name().to_owned();
        let (times, data_type) = match times {
            RawTimes::Array(array) => {
                if array.len() != row_ids.len() {
                    return Err(ChunkError::LengthMismatch {
                        column: name(),
                        expected: row_ids.len(),
                        actual: array.len(),
                    });
                }
                if array.null_count() > 0 {
                    return Err(ChunkError::NullTimes {
                        timeline: name(),
                        null_count: array.null_count(),
                    });
                }
                let data = array.to_data();
                // All three timeline types are 64-bit primitives: one buffer of i64, sliced.
                let times =
                    ScalarBuffer::<i64>::new(data.buffers()[0].clone(), data.offset(), data.len());
                (times, array.data_type().clone())
            }
            RawTimes::Copied { times, data_type } => (times, data_type),
        };
        if times.len() != row_ids.len() {
            // Only a copy made by this crate gets here with another length: a bug.
            return Err(ChunkError::LengthMismatch {
                column: name(),
                expected: row_ids.len(),
                actual: times.len(),
            });
        }
        if let Some(row) = times.iter().position(|&t| t == i64::MIN) {
            return Err(ChunkError::ReservedTime {
                timeline: name(),
                row,
            });
        }
        let is_sorted = times.is_sorted();
        let in_index_order = is_sorted
            && times
                .windows(2)
                .zip(row_ids.windows(2))
                .all(|(t, r)| t[0] < t[1] || r[0] <= r[1]);
        let index_order = (!in_index_order).then(|| {
            let mut order: Vec<u32> = (0..row_ids.len() as u32).collect();
            order.sort_by_key(|&i| (times[i as usize], row_ids[i as usize]));
            order.into_boxed_slice()
        });
        let (min, max) = times.iter().fold((i64::MAX, i64::MIN + 1), |(lo, hi), &t| {
            (lo.min(t), hi.max(t))
        });
        Ok(Self {
            timeline,
            data_type,
            times,
            field_metadata,
            is_sorted,
            index_order,
            time_range: (TimeInt::saturating(min), TimeInt::saturating(max)),
        })
    }

    fn sanity_check(&self, row_ids: &[RowId]) -> Result<(), String> {
        let Self {
            timeline,
            times,
            data_type,
            field_metadata: _,
            is_sorted,
            index_order,
            time_range,
        } = self;
        let name = timeline.name();
        if times.len() != row_ids.len() {
            return Err(format!("time column {name} has one time per row"));
        }
        if crate::TimeType::from_arrow(data_type) != Some(timeline.time_type()) {
            return Err(format!(
                "time column {name}'s Arrow type matches its timeline"
            ));
        }
        if *is_sorted != times.is_sorted() {
            return Err(format!(
                "time column {name}'s is_sorted flag matches its times"
            ));
        }
        let (lo, hi) = (times.iter().min(), times.iter().max());
        if (lo.copied(), hi.copied()) != (Some(time_range.0.as_i64()), Some(time_range.1.as_i64()))
        {
            return Err(format!("time column {name}'s range matches its times"));
        }
        let key = |i: usize| (times[i], row_ids[i]);
        let ordered = match index_order {
            Some(order) => {
                order.len() == times.len()
                    && order
                        .windows(2)
                        .all(|w| key(w[0] as usize) <= key(w[1] as usize))
            }
            None => (1..times.len()).all(|i| key(i - 1) <= key(i)),
        };
        if !ordered {
            return Err(format!(
                "time column {name}'s index order sorts by (time, row id)"
            ));
        }
        Ok(())
    }

    /// The timeline.
    pub fn timeline(&self) -> &Timeline {
        &self.timeline
    }

    /// The times, in row order.
    pub fn times(&self) -> &[i64] {
        &self.times
    }

    /// The Arrow type of the column as it was given.
    pub fn data_type(&self) -> &DataType {
        &self.data_type
    }

    /// Are the times non-decreasing in row order?
    pub fn is_sorted(&self) -> bool {
        self.is_sorted
    }

    /// Least and greatest time.
    pub fn time_range(&self) -> (TimeInt, TimeInt) {
        self.time_range
    }

    /// The row at position `pos` of ascending `(time, row id)` order.
    #[inline]
    pub(crate) fn row_at(&self, pos: usize) -> usize {
        match &self.index_order {
            Some(order) => order[pos] as usize,
            None => pos,
        }
    }

    /// The rows in ascending `(time, row id)` order, when that is not row order.
    pub(crate) fn index_order(&self) -> Option<&[u32]> {
        self.index_order.as_deref()
    }

    /// Number of positions whose time is `<= t` (a partition point in index order).
    pub(crate) fn num_positions_at_or_before(&self, t: i64) -> usize {
        self.partition_point(t, |time| time <= t)
    }

    /// Number of positions whose time is `< t`.
    pub(crate) fn num_positions_before(&self, t: i64) -> usize {
        self.partition_point(t, |time| time < t)
    }

    /// The number of leading positions (in index order) whose time `holds`, where `holds`
    /// is true up to around `t` and false after.
    fn partition_point(&self, t: i64, holds: impl Fn(i64) -> bool) -> usize {
        let (min, max) = self.time_range;
        match &self.index_order {
            Some(order) => guided_partition_point(
                order.len(),
                (min, max),
                t,
                |p| self.times[order[p] as usize],
                holds,
            ),
            None => {
                guided_partition_point(self.times.len(), (min, max), t, |p| self.times[p], holds)
            }
        }
    }
}

/// Below this many positions a plain binary search is as good as a guided one.
const GUIDED_SEARCH_MIN_POSITIONS: usize = 32;

/// The partition point of `holds` over `time_at(0..n)`, times ascending with the position
/// between `min` and `max`. The first probe goes where `t` would be if the times were
/// evenly spread, then the search gallops outward from there: a series logged at a steady
/// rate is answered from one or two cache lines instead of `log2(n)` scattered ones, and
/// any other spread costs at most twice the binary search.
fn guided_partition_point(
    n: usize,
    (min, max): (TimeInt, TimeInt),
    t: i64,
    time_at: impl Fn(usize) -> i64,
    holds: impl Fn(i64) -> bool,
) -> usize {
    let binary = |mut low: usize, mut high: usize| {
        while low < high {
            let middle = low + (high - low) / 2;
            if holds(time_at(middle)) {
                low = middle + 1;
            } else {
                high = middle;
            }
        }
        low
    };
    let span = i128::from(max.as_i64()) - i128::from(min.as_i64());
    if n < GUIDED_SEARCH_MIN_POSITIONS || span <= 0 {
        return binary(0, n);
    }
    let offset = (i128::from(t) - i128::from(min.as_i64())).clamp(0, span);
    let last = i128::try_from(n - 1).unwrap_or(i128::MAX);
    let guess = usize::try_from(offset * last / span).map_or(n - 1, |g| g.min(n - 1));
    let mut step = 1;
    if holds(time_at(guess)) {
        // The answer is past `guess`: gallop up to the first position that fails.
        let mut low = guess + 1;
        loop {
            let probe = guess + step;
            if probe >= n {
                return binary(low, n);
            }
            if !holds(time_at(probe)) {
                return binary(low, probe);
            }
            low = probe + 1;
            step *= 2;
        }
    }
    // The answer is at or before `guess`: gallop down to the last position that holds.
    let mut high = guess;
    loop {
        let Some(probe) = guess.checked_sub(step) else {
            return binary(0, high);
        };
        if holds(time_at(probe)) {
            return binary(probe + 1, high);
        }
        high = probe;
        step *= 2;
    }
}

impl ComponentColumn {
    #[expect(
        clippy::cast_possible_truncation,
        reason = "rows < 2^32, checked in Chunk::from_raw"
    )]
    fn try_new(
        raw: RawComponentColumn,
        row_ids: &[RowId],
        time_columns: &[TimeColumn],
    ) -> Result<Self, ChunkError> {
        let RawComponentColumn {
            descriptor,
            array,
            field,
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
        let list = with_shared_item_field(list);
        let valid = |row: usize| list.is_valid(row);

        let mut max_row_id_cell: Option<(RowId, u32)> = None;
        for (row, &row_id) in row_ids.iter().enumerate() {
            if valid(row) && max_row_id_cell.is_none_or(|(best, _)| row_id >= best) {
                max_row_id_cell = Some((row_id, row as u32));
            }
        }
        let best_cell_row = max_row_id_cell.map_or(NO_ROW, |(_, row)| row);
        let one_instance_per_row = has_one_instance_per_row(&list);
        let leaf = PrimitiveLeaf::of(&list);

        let bounds_per_timeline = time_columns
            .iter()
            .map(|column| {
                let mut bounds: Option<ComponentTimeBounds> = None;
                for (row, (&time, &row_id)) in column.times.iter().zip(row_ids).enumerate() {
                    if !valid(row) {
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
            })
            .collect();

        Ok(Self {
            descriptor,
            list,
            field,
            bounds_per_timeline,
            best_cell_row,
            one_instance_per_row,
            leaf,
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

    fn leaf_values<T: ArrowPrimitiveType>(
        &self,
        row: usize,
        fixed_size: Option<usize>,
    ) -> Option<&[T::Native]> {
        let leaf = self.leaf.as_ref()?;
        let (leaf_type, shape) = leaf_shape(self.list.data_type())?;
        if shape != fixed_size || *leaf_type != T::DATA_TYPE || !self.is_valid_row(row) {
            return None;
        }
        let width = fixed_size.unwrap_or(1);
        let offsets = self.list.value_offsets();
        let value = |item: &i32| usize::try_from(*item).ok()?.checked_mul(width);
        let (start, end) = (value(offsets.get(row)?)?, value(offsets.get(row + 1)?)?);
        leaf.values.typed_data::<T::Native>().get(start..end)
    }

    /// The bytes of the cell at `row`'s values, when the column's items are primitives or
    /// fixed-size lists of them without any null (then the bytes are the whole cell; a null
    /// instance would hide whatever its slot holds). `None` otherwise, or for a null cell.
    pub(crate) fn leaf_bytes(&self, row: usize) -> Option<&[u8]> {
        let leaf = self.leaf.as_ref()?;
        let (leaf_type, fixed_size) = leaf_shape(self.list.data_type())?;
        let items = self.list.values();
        let leaf_nulls = match fixed_size {
            Some(_) => items.as_fixed_size_list_opt()?.values().null_count(),
            None => 0,
        };
        if items.null_count() + leaf_nulls > 0 || !self.is_valid_row(row) {
            return None;
        }
        let width = leaf_type.primitive_width()? * fixed_size.unwrap_or(1);
        let offsets = self.list.value_offsets();
        let byte = |item: &i32| usize::try_from(*item).ok()?.checked_mul(width);
        let (start, end) = (byte(offsets.get(row)?)?, byte(offsets.get(row + 1)?)?);
        leaf.values.as_slice().get(start..end)
    }

    /// Is `row` a row of this column, with a non-null cell?
    fn is_valid_row(&self, row: usize) -> bool {
        row < self.list.len() && self.list.is_valid(row)
    }

    /// Is the cell at `row` non-null?
    #[inline]
    pub fn is_valid(&self, row: usize) -> bool {
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

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;

    /// A chunk of one `frame` row per cell of `list` (times 0, 1, …).
    fn chunk_of(list: ListArray) -> Chunk {
        let n = u32::try_from(list.len()).unwrap();
        Chunk::try_new(
            ChunkId::new(),
            EntityPath::parse("a").unwrap(),
            (1..=u128::from(n)).map(RowId::from_u128).collect(),
            vec![(
                Timeline::sequence("frame"),
                Arc::new(arrow_array::Int64Array::from_iter_values(0..i64::from(n))) as ArrayRef,
            )],
            vec![("x".into(), Arc::new(list) as ArrayRef)],
        )
        .unwrap()
    }

    /// The flag holds exactly when every cell spans one value, a null cell included.
    #[test]
    fn one_instance_per_row_follows_the_offsets() {
        let list = |offsets: Vec<i32>, nulls: Option<Vec<bool>>| {
            let len = usize::try_from(*offsets.last().unwrap()).unwrap();
            ListArray::new(
                Arc::new(arrow_schema::Field::new_list_field(DataType::Float64, true)),
                arrow_buffer::OffsetBuffer::new(offsets.into()),
                Arc::new(arrow_array::Float64Array::from(vec![1.0; len])),
                nulls.map(arrow_buffer::NullBuffer::from),
            )
        };
        let flag = |l: ListArray| chunk_of(l).components()[0].has_one_instance_per_row();
        assert!(flag(list(vec![0, 1, 2, 3], None)));
        assert!(flag(list(vec![0, 1, 2], Some(vec![true, false]))));
        assert!(!flag(list(vec![0, 1, 3], None)), "a cell of two");
        assert!(!flag(list(vec![0, 1, 1, 2], None)), "an empty cell");
        assert!(
            !flag(list(vec![0, 1, 1], Some(vec![true, false]))),
            "a null spanning none"
        );
    }

    /// Scalars and fixed-size lists read as slices of the right cells, through slicing at
    /// every level; nulls, other types and other widths read as `None`.
    #[test]
    fn primitive_and_fixed_size_values_read_the_cells() {
        use arrow_array::types::{Float32Type, Float64Type, Int64Type};
        use arrow_array::{FixedSizeListArray, Float32Array, Float64Array};
        use arrow_schema::Field;

        // Cells [1.0, 2.0], null, [], [4.0], sliced out of a longer values array.
        let values = Float64Array::from(vec![9.0, 1.0, 2.0, 3.0, 4.0]).slice(1, 4);
        let scalars = ListArray::new(
            Arc::new(Field::new_list_field(DataType::Float64, true)),
            arrow_buffer::OffsetBuffer::new(vec![0, 2, 3, 3, 4].into()),
            Arc::new(values),
            Some(arrow_buffer::NullBuffer::from(vec![
                true, false, true, true,
            ])),
        );
        let chunk = chunk_of(scalars);
        let column = &chunk.components()[0];
        assert_eq!(
            column.primitive_values::<Float64Type>(0),
            Some(&[1.0, 2.0][..])
        );
        assert_eq!(
            column.primitive_values::<Float64Type>(1),
            None,
            "a null cell"
        );
        assert_eq!(column.primitive_values::<Float64Type>(2), Some(&[][..]));
        assert_eq!(column.primitive_values::<Float64Type>(3), Some(&[4.0][..]));
        assert_eq!(
            column.primitive_values::<Float64Type>(4),
            None,
            "out of bounds"
        );
        assert_eq!(
            column.primitive_values::<Int64Type>(0),
            None,
            "another type"
        );
        assert_eq!(
            column.fixed_size_values::<Float64Type, 1>(0),
            None,
            "another shape"
        );
        assert_eq!(
            chunk_of_points_1().components()[0].primitive_values::<Float64Type>(0),
            None
        );

        // Points [0,1,2] | [3,4,5] [6,7,8], the list itself sliced past a first cell.
        let floats = Float32Array::from_iter_values((0..12u8).map(f32::from));
        let xyz = FixedSizeListArray::new(
            Arc::new(Field::new_list_field(DataType::Float32, false)),
            3,
            Arc::new(floats),
            None,
        );
        let points = ListArray::new(
            Arc::new(Field::new_list_field(xyz.data_type().clone(), false)),
            arrow_buffer::OffsetBuffer::new(vec![0, 1, 3, 4].into()),
            Arc::new(xyz),
            None,
        )
        .slice(1, 2);
        let chunk = chunk_of(points);
        let column = &chunk.components()[0];
        assert_eq!(
            column.fixed_size_values::<Float32Type, 3>(0),
            Some(&[[3.0, 4.0, 5.0], [6.0, 7.0, 8.0]][..])
        );
        assert_eq!(
            column.fixed_size_values::<Float32Type, 3>(1),
            Some(&[[9.0, 10.0, 11.0]][..])
        );
        assert_eq!(column.fixed_size_values::<Float32Type, 2>(0), None);
        assert_eq!(column.fixed_size_values::<Float32Type, 0>(0), None);
        assert_eq!(column.primitive_values::<Float32Type>(0), None);
        chunk.sanity_check().unwrap();
    }

    /// One cell holding one fixed-size list of one `Float64`.
    fn chunk_of_points_1() -> Chunk {
        let xyz = arrow_array::FixedSizeListArray::new(
            Arc::new(arrow_schema::Field::new_list_field(
                DataType::Float64,
                false,
            )),
            1,
            Arc::new(arrow_array::Float64Array::from(vec![1.0])),
            None,
        );
        chunk_of(ListArray::new(
            Arc::new(arrow_schema::Field::new_list_field(
                xyz.data_type().clone(),
                false,
            )),
            arrow_buffer::OffsetBuffer::new(vec![0, 1].into()),
            Arc::new(xyz),
            None,
        ))
    }

    /// A chunk built from arrays nobody else holds owns its buffers, although its columns
    /// keep second handles on their leaf values; one whose arrays are also held elsewhere
    /// does not.
    #[test]
    fn a_chunk_owns_buffers_only_nobody_else_holds() {
        let list = || {
            ListArray::new(
                Arc::new(arrow_schema::Field::new_list_field(DataType::Float64, true)),
                arrow_buffer::OffsetBuffer::new(vec![0, 1, 2].into()),
                Arc::new(arrow_array::Float64Array::from(vec![1.0, 2.0])),
                None,
            )
        };
        let alone = chunk_of(list());
        assert!(alone.components()[0].leaf.is_some());
        assert!(alone.owns_all_buffers_now());
        assert!(alone.owns_all_buffers());

        let shared = list();
        let sharing = chunk_of(shared.clone());
        assert!(!sharing.owns_all_buffers_now());
        assert!(!sharing.owns_all_buffers());
        drop(shared);
        assert!(sharing.owns_all_buffers_now(), "the other holder is gone");
    }

    /// The memory figures read from typed arrays equal those of Arrow's generic
    /// `ArrayData` tree, for lists of primitives and of fixed-size lists of them, with
    /// nulls at every level, sliced, and with item fields no other chunk shares.
    #[test]
    fn typed_memory_figures_equal_the_generic_ones() {
        use arrow_array::{FixedSizeListArray, Float32Array, Int16Array};
        use arrow_buffer::{NullBuffer, OffsetBuffer};
        use arrow_schema::Field;

        let nulls = |bits: &[bool]| Some(NullBuffer::from(bits.to_vec()));
        let primitive = |leaf_nulls: Option<NullBuffer>| {
            Arc::new(Int16Array::new(vec![1, 2, 3, 4, 5, 6].into(), leaf_nulls)) as ArrayRef
        };
        let points = |point_nulls: Option<NullBuffer>, leaf_nulls: Option<NullBuffer>| {
            let leaf = Float32Array::new((0..12u8).map(f32::from).collect(), leaf_nulls);
            Arc::new(FixedSizeListArray::new(
                Arc::new(Field::new_list_field(DataType::Float32, true)),
                2,
                Arc::new(leaf),
                point_nulls,
            )) as ArrayRef
        };
        let list = |items: ArrayRef, list_nulls: Option<NullBuffer>, field_name: &str| {
            ListArray::new(
                Arc::new(Field::new(field_name, items.data_type().clone(), true)),
                OffsetBuffer::new(vec![0, 2, 3, 3, 6].into()),
                items,
                list_nulls,
            )
        };
        let some = [true, false, true, true];
        let lists = vec![
            list(primitive(None), None, "item"),
            list(
                primitive(nulls(&[true, false, true, true, false, true])),
                nulls(&some),
                "item",
            ),
            list(points(None, None), None, "item"),
            list(
                points(
                    nulls(&[true, true, false, true, true, true]),
                    nulls(&[true; 12]),
                ),
                nulls(&some),
                "item",
            ),
            // Not the shared item field: the chunk owns its own.
            list(primitive(None), None, "unshared"),
            list(points(None, None), nulls(&some), "unshared").slice(1, 3),
            list(primitive(None), None, "item").slice(2, 2),
        ];
        for list in lists {
            let chunk = chunk_of(list);
            assert!(chunk.components()[0].leaf.is_some());
            let (typed, generic) = (
                memory::ChunkMemory::of(&chunk),
                memory::ChunkMemory::compute(&chunk, true),
            );
            assert_eq!(
                (
                    typed.own_bytes,
                    typed.payload_bytes,
                    typed.buffer_bytes,
                    typed.buffers.len()
                ),
                (
                    generic.own_bytes,
                    generic.payload_bytes,
                    generic.buffer_bytes,
                    generic.buffers.len()
                ),
                "{:?}",
                chunk.components()[0].list_array().data_type()
            );
            chunk.sanity_check().unwrap();
        }
    }

    /// The guided search finds exactly the partition point a binary search finds, for
    /// evenly spread, clustered, duplicated and extreme times, and targets inside, between
    /// and beyond them.
    #[test]
    fn guided_partition_point_agrees_with_a_binary_search() {
        let mut state = 7u64;
        let mut random = move |n: u64| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            (state >> 33) % n
        };
        let shapes: Vec<Vec<i64>> = vec![
            (0..1000).collect(),
            (0..1000).map(|i| i / 10).collect(),
            (0..200)
                .map(|i| if i < 190 { i } else { 1_000_000 + i })
                .collect(),
            (0..300).map(|i| i * i * i).collect(),
            vec![i64::MIN + 1, -5, 0, 0, 0, 3, i64::MAX - 1]
                .into_iter()
                .chain(std::iter::repeat_n(i64::MAX, 40))
                .collect(),
            {
                let mut v: Vec<i64> = (0..500)
                    .map(|_| random(10_000).cast_signed() - 5_000)
                    .collect();
                v.sort_unstable();
                v
            },
        ];
        for times in shapes {
            let range = (
                TimeInt::saturating(times[0]),
                TimeInt::saturating(*times.last().unwrap()),
            );
            let targets = times
                .iter()
                .flat_map(|&t| [t.saturating_sub(1), t, t.saturating_add(1)])
                .chain([i64::MIN, i64::MAX, 0]);
            for target in targets {
                for strict in [false, true] {
                    let holds = |time: i64| {
                        if strict {
                            time < target
                        } else {
                            time <= target
                        }
                    };
                    assert_eq!(
                        guided_partition_point(times.len(), range, target, |p| times[p], holds),
                        times.partition_point(|&time| holds(time)),
                        "target {target}, strict {strict}"
                    );
                }
            }
        }
    }
}
