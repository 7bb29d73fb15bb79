//! [`ChunkBuilder`]: builds a chunk row by row, the way a logger produces data.

use std::sync::Arc;

use arrow_array::{Array, ArrayRef, ListArray};
use arrow_buffer::{NullBuffer, OffsetBuffer};
use arrow_schema::{DataType, Field};

use super::Chunk;
use crate::ChunkError;
use crate::{ChunkId, ComponentDescriptor, ComponentName, EntityPath, RowId, Timeline};

/// Builds a [`Chunk`] one row at a time.
///
/// A row names its times (one per timeline; every row must name the same timelines) and
/// its cells (the instances of each component it logs; a component a row leaves out gets a
/// null cell there). A chunk whose rows name no timeline is static.
///
/// ```
/// use std::sync::Arc;
/// use arrow_array::{ArrayRef, Float64Array};
/// use chunkstore::{ChunkBuilder, ChunkId, EntityPath, RowId, Timeline};
///
/// let frame = Timeline::sequence("frame");
/// let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/robot/speed").unwrap())
///     .with_row(RowId::new(), [(frame.clone(), 1)], [("scalar", Arc::new(Float64Array::from(vec![0.5])) as ArrayRef)])
///     .with_row(RowId::new(), [(frame, 2)], [("scalar", Arc::new(Float64Array::from(vec![0.7])) as ArrayRef)])
///     .build()
///     .unwrap();
/// assert_eq!(chunk.num_rows(), 2);
/// ```
#[derive(Debug)]
pub struct ChunkBuilder {
    id: ChunkId,
    entity_path: EntityPath,
    row_ids: Vec<RowId>,
    timelines: Vec<(Timeline, Vec<Option<i64>>)>,
    components: Vec<(ComponentDescriptor, Vec<Option<ArrayRef>>)>,
    /// Position of each component in `components`: a row of many components finds each
    /// in O(1) (a search per cell made a row of 100,000 components quadratic).
    component_positions: ahash::HashMap<ComponentName, usize>,
    /// The first problem a row had (`with_row` cannot fail); [`ChunkBuilder::build`]
    /// reports it.
    error: Option<ChunkError>,
}

impl ChunkBuilder {
    /// An empty builder for a chunk of `entity_path`.
    pub fn new(id: ChunkId, entity_path: EntityPath) -> Self {
        Self {
            id,
            entity_path,
            row_ids: Vec::new(),
            timelines: Vec::new(),
            components: Vec::new(),
            component_positions: ahash::HashMap::default(),
            error: None,
        }
    }

    /// Appends a row: its id, its time on each timeline, and its cells.
    ///
    /// A row names each timeline and each component at most once, and a timeline always
    /// with the same type; otherwise [`ChunkBuilder::build`] fails, naming the row.
    #[must_use]
    pub fn with_row<C: Into<ComponentDescriptor>>(
        mut self,
        row_id: RowId,
        times: impl IntoIterator<Item = (Timeline, i64)>,
        cells: impl IntoIterator<Item = (C, ArrayRef)>,
    ) -> Self {
        let row = self.row_ids.len();
        self.row_ids.push(row_id);
        for (timeline, time) in times {
            let existing = self
                .timelines
                .iter()
                .position(|(t, _)| t.name() == timeline.name());
            let index = if let Some(index) = existing {
                let first = self.timelines[index].0.time_type();
                if first != timeline.time_type() {
                    self.fail(ChunkError::TimelineTypeMismatch {
                        timeline: timeline.name().to_owned(),
                        first,
                        second: timeline.time_type(),
                    });
                    continue;
                }
                index
            } else {
                self.timelines.push((timeline, vec![None; row]));
                self.timelines.len() - 1
            };
            let (timeline, column) = &mut self.timelines[index];
            if column.len() > row {
                let timeline = timeline.name().to_owned();
                self.fail(ChunkError::TimelineRepeatedInRow { row, timeline });
                continue;
            }
            column.resize(row, None);
            column.push(Some(time));
        }
        for (descriptor, cell) in cells {
            let descriptor = descriptor.into();
            let index = if let Some(&index) = self.component_positions.get(&descriptor.name) {
                index
            } else {
                let index = self.components.len();
                self.component_positions
                    .insert(descriptor.name.clone(), index);
                self.components.push((descriptor, vec![None; row]));
                index
            };
            let (descriptor, column) = &mut self.components[index];
            if column.len() > row {
                let component = descriptor.name.to_string();
                self.fail(ChunkError::ComponentRepeatedInRow { row, component });
                continue;
            }
            column.resize(row, None);
            column.push(Some(cell));
        }
        self
    }

    /// Keeps the first error: later ones are often its consequences.
    fn fail(&mut self, error: ChunkError) {
        self.error.get_or_insert(error);
    }

    /// Appends a static row (no times).
    #[must_use]
    pub fn with_static_row<C: Into<ComponentDescriptor>>(
        self,
        row_id: RowId,
        cells: impl IntoIterator<Item = (C, ArrayRef)>,
    ) -> Self {
        self.with_row(row_id, [], cells)
    }

    /// Builds the chunk.
    ///
    /// # Errors
    /// Everything [`Chunk::try_new`] rejects, plus rows that miss a timeline others have
    /// ([`ChunkError::NullTimes`]), cells of one component with different element types
    /// ([`ChunkError::CellTypeMismatch`]), a row naming a timeline or component twice
    /// ([`ChunkError::TimelineRepeatedInRow`], [`ChunkError::ComponentRepeatedInRow`]) and
    /// a timeline named with two types ([`ChunkError::TimelineTypeMismatch`]).
    pub fn build(self) -> Result<Chunk, ChunkError> {
        let Self {
            id,
            entity_path,
            row_ids,
            timelines,
            components,
            component_positions: _,
            error,
        } = self;
        if let Some(error) = error {
            return Err(error);
        }
        let num_rows = row_ids.len();
        let time_columns = timelines
            .into_iter()
            .map(|(timeline, mut times)| {
                times.resize(num_rows, None);
                let null_count = times.iter().filter(|t| t.is_none()).count();
                if null_count > 0 {
                    return Err(ChunkError::NullTimes {
                        timeline: timeline.name().to_owned(),
                        null_count,
                    });
                }
                let times: Vec<i64> = times.into_iter().flatten().collect();
                let array = timeline.time_type().dense_array(times);
                Ok((timeline, array))
            })
            .collect::<Result<Vec<_>, _>>()?;
        let components = components
            .into_iter()
            .map(|(descriptor, mut cells)| {
                cells.resize(num_rows, None);
                let list = list_from_cells(descriptor.name.as_str(), &cells)?;
                Ok((descriptor, Arc::new(list) as ArrayRef))
            })
            .collect::<Result<Vec<_>, ChunkError>>()?;
        Chunk::try_new(id, entity_path, row_ids, time_columns, components)
    }
}

/// One list array from optional cells; `None` cells become nulls.
fn list_from_cells(component: &str, cells: &[Option<ArrayRef>]) -> Result<ListArray, ChunkError> {
    let present: Vec<&dyn Array> = cells.iter().flatten().map(AsRef::as_ref).collect();
    let element_type: DataType = present
        .first()
        .map_or(DataType::Null, |a| a.data_type().clone());
    if let Some(other) = present.iter().find(|a| *a.data_type() != element_type) {
        return Err(ChunkError::CellTypeMismatch {
            component: component.to_owned(),
            expected: element_type,
            found: other.data_type().clone(),
        });
    }
    let values = if present.is_empty() {
        arrow_array::new_empty_array(&element_type)
    } else {
        arrow_select::concat::concat(&present)?
    };
    let offsets =
        OffsetBuffer::from_lengths(cells.iter().map(|c| c.as_ref().map_or(0, Array::len)));
    let nulls: NullBuffer = cells.iter().map(Option::is_some).collect();
    let nulls = (nulls.null_count() > 0).then_some(nulls);
    let field = Arc::new(Field::new_list_field(element_type, true));
    Ok(ListArray::try_new(field, offsets, values, nulls)?)
}
