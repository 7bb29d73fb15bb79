//! A column's cells for one batch: runs of consecutive rows of one source chunk, copied
//! with one `MutableArrayData::extend` each.

use std::sync::Arc;

use arrow_array::{Array, ArrayRef, ListArray, make_array, new_empty_array};
use arrow_buffer::OffsetBuffer;
use arrow_data::ArrayData;
use arrow_data::transform::{Capacities, MutableArrayData};
use arrow_schema::{ArrowError, FieldRef};

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
    /// `None` for the empty list, which is no chunk's.
    chunk: Option<Arc<Chunk>>,
    /// The column's list array, retyped to the output's list type where its item field
    /// differed (name, nullability or metadata; the element type is the same).
    data: ArrayData,
    /// `(index column, the chunk's time column there)` for each index column but the
    /// table's own index (whose value a row already has) that the chunk has.
    time_columns: Box<[(u32, u32)]>,
}

/// The list arrays one output column copies from. Source 0 is a one-row empty list.
#[derive(Debug)]
pub(crate) struct Sources {
    item_field: FieldRef,
    arrays: Vec<Source>,
    /// `(chunk, component column)` -> source, for sources registered by lookup.
    by_chunk: ahash::HashMap<(ChunkId, u32), u32>,
}

impl Sources {
    pub fn new(item_field: FieldRef) -> Result<Self, ArrowError> {
        let empty = ListArray::try_new(
            Arc::clone(&item_field),
            OffsetBuffer::new_zeroed(1),
            new_empty_array(item_field.data_type()),
            None,
        )?;
        Ok(Self {
            item_field,
            arrays: vec![Source {
                chunk: None,
                data: empty.into_data(),
                time_columns: Box::new([]),
            }],
            by_chunk: ahash::HashMap::default(),
        })
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
        let data = if matches!(list.data_type(), arrow_schema::DataType::List(f) if *f == self.item_field)
        {
            list.to_data()
        } else {
            ListArray::try_new(
                Arc::clone(&self.item_field),
                list.offsets().clone(),
                Arc::clone(list.values()),
                list.nulls().cloned(),
            )?
            .into_data()
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
            chunk: Some(Arc::clone(chunk)),
            data,
            time_columns,
        });
        Ok(number)
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

    /// Raises `maxima[i]` to the time the cell's row has on index column `i`, where its
    /// chunk has that timeline (the table's own index aside).
    pub fn raise_times(&self, cell: Cell, maxima: &mut [Option<i64>]) {
        let Cell::Row { source, row } = cell else {
            return;
        };
        let source = &self.arrays[source as usize];
        let Some(chunk) = &source.chunk else { return };
        for &(index_column, time_column) in &source.time_columns {
            let time = chunk.time_columns()[time_column as usize].times()[row as usize];
            let max = &mut maxima[index_column as usize];
            *max = (*max).max(Some(time));
        }
    }
}

/// One batch's cells of one column, as runs. A column the merge does not touch at a row
/// is not visited: it is padded (with nulls, its static cell or its fill value) when it
/// is next touched or the batch ends, so a sparse row costs only the columns it has.
#[derive(Debug, Default)]
pub(crate) struct ColumnCells {
    runs: Vec<Run>,
    len: usize,
}

#[derive(Clone, Copy, Debug)]
enum Run {
    Nulls(u32),
    Empties(u32),
    Rows {
        source: u32,
        start: u32,
        len: u32,
    },
    /// One row, repeated.
    Repeat {
        source: u32,
        row: u32,
        times: u32,
    },
}

impl ColumnCells {
    /// Appends copies of `cell` until the column holds `len` cells.
    #[expect(clippy::cast_possible_truncation, reason = "a batch holds < 2^32 rows")]
    pub fn pad(&mut self, cell: Option<Cell>, len: usize) {
        let Some(missing) = len.checked_sub(self.len).filter(|&n| n > 0) else {
            return;
        };
        match cell {
            Some(Cell::Row { source, row }) => {
                self.push(cell);
                let extra = (missing - 1) as u32;
                if extra > 0 {
                    self.runs.push(Run::Repeat {
                        source,
                        row,
                        times: extra,
                    });
                    self.len += extra as usize;
                }
            }
            None => {
                match self.runs.last_mut() {
                    Some(Run::Nulls(n)) => *n += missing as u32,
                    _ => self.runs.push(Run::Nulls(missing as u32)),
                }
                self.len = len;
            }
            Some(Cell::Empty) => {
                match self.runs.last_mut() {
                    Some(Run::Empties(n)) => *n += missing as u32,
                    _ => self.runs.push(Run::Empties(missing as u32)),
                }
                self.len = len;
            }
        }
    }

    pub fn push(&mut self, cell: Option<Cell>) {
        self.len += 1;
        match (self.runs.last_mut(), cell) {
            (Some(Run::Nulls(n)), None) | (Some(Run::Empties(n)), Some(Cell::Empty)) => *n += 1,
            (Some(Run::Rows { source, start, len }), Some(Cell::Row { source: s, row }))
                if *source == s && *start + *len == row =>
            {
                *len += 1;
            }
            (_, None) => self.runs.push(Run::Nulls(1)),
            (_, Some(Cell::Empty)) => self.runs.push(Run::Empties(1)),
            (_, Some(Cell::Row { source, row })) => self.runs.push(Run::Rows {
                source,
                start: row,
                len: 1,
            }),
        }
    }

    /// The column's array for the batch; the runs are cleared for the next one.
    pub fn finish(&mut self, sources: &Sources, num_rows: usize) -> ArrayRef {
        self.len = 0;
        // Only the sources this batch uses take part (an output array is built from
        // them), numbered locally; the empty list is always among them, so there is one.
        let mut local: Vec<u32> = vec![u32::MAX; sources.arrays.len()];
        let mut used: Vec<&ArrayData> = vec![&sources.arrays[0].data];
        local[0] = 0;
        for run in &self.runs {
            if let Run::Rows { source, .. } | Run::Repeat { source, .. } = *run
                && local[source as usize] == u32::MAX
            {
                local[source as usize] = u32::try_from(used.len()).unwrap_or(u32::MAX);
                used.push(&sources.arrays[source as usize].data);
            }
        }
        let mut out = MutableArrayData::with_capacities(used, true, Capacities::Array(num_rows));
        for run in self.runs.drain(..) {
            match run {
                Run::Nulls(n) => out.extend_nulls(n as usize),
                Run::Empties(n) => {
                    for _ in 0..n {
                        out.extend(0, 0, 1);
                    }
                }
                Run::Rows { source, start, len } => out.extend(
                    local[source as usize] as usize,
                    start as usize,
                    (start + len) as usize,
                ),
                Run::Repeat { source, row, times } => {
                    for _ in 0..times {
                        out.extend(
                            local[source as usize] as usize,
                            row as usize,
                            row as usize + 1,
                        );
                    }
                }
            }
        }
        make_array(out.freeze())
    }
}
