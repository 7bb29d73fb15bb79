//! New chunks from the rows of existing ones: the copies compaction, splitting and drops
//! make. Every function here builds through [`Chunk::from_raw`], so a rewritten chunk is
//! validated and indexed exactly like an inserted one.

use std::sync::Arc;

use arrow_array::{Array, ArrayRef, ListArray, make_array};
use arrow_buffer::{ArrowNativeType, Buffer, NullBuffer, OffsetBuffer, ScalarBuffer};
use arrow_data::ArrayData;
use arrow_schema::{DataType, FieldRef};

use super::data_types::{leaf_shape, same_data_type};
use super::{Chunk, ComponentColumn, RawComponentColumn, RawTimeColumn, RawTimes};
use crate::ChunkError;
use crate::{ChunkId, RowId};

/// Rows of several chunks with one layout: `(chunk position, row)`.
pub(crate) type RowSource = (usize, usize);

impl Chunk {
    /// A new chunk holding `rows` of `chunks` (which share one layout), in that order.
    ///
    /// # Errors
    /// Only if Arrow fails to copy, which would be a bug in this crate.
    pub(crate) fn gather(chunks: &[&Self], rows: &[RowSource]) -> Result<Self, ChunkError> {
        Self::gather_as(ChunkId::new(), chunks, rows)
    }

    /// This chunk with its rows in row-id order, under the same id, or `None` if they are
    /// in that order already. Rerun loads no chunk whose row ids are out of order ("Chunks
    /// must be sorted before insertion"), and compaction sorts rows by time, which differs
    /// from row-id order wherever data was logged out of time order: every writer of
    /// files ([`crate::rrd::RrdWriter`], [`crate::ipc::write_chunk_ipc_file`]) sorts on the
    /// way out. The id stays: the rows, and so the chunk, are the same (Rerun sorts in
    /// place too).
    ///
    /// # Errors
    /// Only if Arrow fails to copy, which would be a bug in this crate.
    pub fn sorted_by_row_id(&self) -> Result<Option<Self>, ChunkError> {
        if self.is_sorted_by_row_id {
            return Ok(None);
        }
        let mut rows: Vec<RowSource> = (0..self.num_rows()).map(|row| (0, row)).collect();
        // Stable, so rows under one row id (which only hand-built chunks have) keep their
        // order.
        rows.sort_by_key(|&(_, row)| self.row_ids[row]);
        Self::gather_as(self.id, &[self], &rows).map(Some)
    }

    fn gather_as(id: ChunkId, chunks: &[&Self], rows: &[RowSource]) -> Result<Self, ChunkError> {
        let Some(first) = chunks.first() else {
            return Err(ChunkError::NoRows);
        };
        // Only the chunks the rows come from go to Arrow's interleave, which looks at every
        // array it is given: one piece of a rewrite of thousands of chunks reads a few, and
        // handing it all of them made a rewrite quadratic in its inputs.
        let (used, local_rows) = used_chunks(chunks.len(), rows);
        let row_ids: Vec<RowId> = rows.iter().map(|&(c, r)| chunks[c].row_ids[r]).collect();
        let times = (0..first.time_columns.len())
            .map(|t| {
                let times: Vec<i64> = rows
                    .iter()
                    .map(|&(c, r)| chunks[c].time_columns[t].times[r])
                    .collect();
                first.time_columns[t].rebuilt(ScalarBuffer::from(times))
            })
            .collect();
        let components = (0..first.components.len())
            .map(|position| {
                let columns: Vec<&ComponentColumn> = used
                    .iter()
                    .map(|&c| &chunks[c].components[position])
                    .collect();
                let array = if let Some(array) = gather_single_values(&columns, &local_rows) {
                    array?
                } else {
                    let lists: Vec<&dyn Array> =
                        columns.iter().map(|c| &c.list as &dyn Array).collect();
                    arrow_select::interleave::interleave(&lists, &local_rows)?
                };
                Ok(first.components[position].rebuilt(array))
            })
            .collect::<Result<super::RawComponentColumns, ChunkError>>()?;
        Self::from_raw(
            id,
            first.entity_path.clone(),
            row_ids,
            times,
            components,
            first.extra_metadata.clone(),
            super::Buffers::Unknown,
        )
    }

    /// A new chunk of `len` rows from `offset`, sharing this chunk's buffers (only the row
    /// ids are copied).
    ///
    /// # Errors
    /// If the range is empty or out of bounds.
    pub(crate) fn slice(&self, offset: usize, len: usize) -> Result<Self, ChunkError> {
        if len == 0
            || offset
                .checked_add(len)
                .is_none_or(|end| end > self.num_rows())
        {
            return Err(ChunkError::SliceOutOfRange {
                offset,
                len,
                num_rows: self.num_rows(),
            });
        }
        let times = self
            .time_columns
            .iter()
            .map(|column| column.rebuilt(column.times.slice(offset, len)))
            .collect();
        let components = self
            .components
            .iter()
            .map(|column| column.rebuilt(Arc::new(column.list.slice(offset, len))))
            .collect();
        Self::from_raw(
            ChunkId::new(),
            self.entity_path.clone(),
            self.row_ids[offset..offset + len].to_vec(),
            times,
            components,
            self.extra_metadata.clone(),
            super::Buffers::SharedWithSource,
        )
    }
}

impl super::TimeColumn {
    /// This column's timeline, type and metadata around other times.
    pub(super) fn rebuilt(&self, times: ScalarBuffer<i64>) -> RawTimeColumn {
        RawTimeColumn {
            timeline: self.timeline.clone(),
            times: RawTimes::Copied {
                times,
                data_type: self.data_type.clone(),
            },
            field_metadata: self.field_metadata.clone(),
        }
    }
}

impl super::ComponentColumn {
    /// This column's descriptor and field around other cells.
    pub(super) fn rebuilt(&self, array: ArrayRef) -> RawComponentColumn {
        RawComponentColumn {
            descriptor: self.descriptor.clone(),
            array,
            field: self.field.clone(),
            from_accepted_cells: true,
        }
    }
}

/// `rows` of `columns` (one component's columns, one layout) as one list column, copied
/// value by value, when every cell of every column holds exactly one instance and the
/// items are primitives or fixed-size lists of them with no null instance: the shape of
/// scalars, positions and colors, which is what rows streamed one at a time mostly hold.
/// `None` for any other shape, which Arrow's interleave copies instead.
///
/// Arrow's interleave takes each row through the list's offsets and then the items'
/// array, generically (a quarter of an out-of-order insert's merge). Here a row is one
/// copy from the column's leaf, found by arithmetic as [`ComponentColumn::leaf_bytes`]
/// finds it, and the offsets are `0, 1, .., n`.
pub(super) fn gather_single_values(
    columns: &[&ComponentColumn],
    rows: &[RowSource],
) -> Option<Result<ArrayRef, ChunkError>> {
    let first = columns.first()?;
    let DataType::List(item_field) = first.list.data_type() else {
        return None;
    };
    let (leaf_type, fixed_size) = leaf_shape(first.list.data_type())?;
    let per_item = fixed_size.unwrap_or(1);
    let mut any_null_cell = false;
    for column in columns {
        if column.null_free_leaf().is_none()
            || !column.one_instance_per_row
            || !same_data_type(column.list.data_type(), first.list.data_type())
        {
            return None;
        }
        any_null_cell |= column.list.null_count() > 0;
    }
    // Copied as unsigned integers of the leaf's width: the bits are all that matter, and
    // a vector of them keeps the alignment Arrow asks of the values.
    let values = match leaf_type.primitive_width()? {
        1 => gather_leaf::<u8>(columns, rows, per_item)?,
        2 => gather_leaf::<u16>(columns, rows, per_item)?,
        4 => gather_leaf::<u32>(columns, rows, per_item)?,
        8 => gather_leaf::<u64>(columns, rows, per_item)?,
        16 => gather_leaf::<i128>(columns, rows, per_item)?,
        _ => return None,
    };
    let nulls = any_null_cell.then(|| {
        rows.iter()
            .map(|&(c, r)| columns.get(c).is_some_and(|column| column.list.is_valid(r)))
            .collect::<NullBuffer>()
    });
    // List offsets are `i32`s; a merge's piece is far smaller.
    let num_cells = i32::try_from(rows.len()).ok()?;
    Some(single_values_list(
        item_field, leaf_type, fixed_size, num_cells, values, nulls,
    ))
}

/// The leaf values of `rows` of `columns` (checked by [`gather_single_values`] to hold
/// one item of `per_item` leaf values per row), read as `T`s. `None` if a row is out of
/// bounds, which a valid merge never asks for.
fn gather_leaf<T: ArrowNativeType>(
    columns: &[&ComponentColumn],
    rows: &[RowSource],
    per_item: usize,
) -> Option<Buffer> {
    // Each column's leaf from its first item: the rows index it from there.
    let leaves: Vec<&[T]> = columns
        .iter()
        .map(|column| {
            let leaf = column.leaf.as_ref()?;
            let first = leaf.first_item.checked_mul(per_item)?;
            leaf.values.typed_data::<T>().get(first..)
        })
        .collect::<Option<_>>()?;
    let mut values: Vec<T> = Vec::with_capacity(rows.len().checked_mul(per_item)?);
    if per_item == 1 {
        for &(c, r) in rows {
            values.push(*leaves.get(c)?.get(r)?);
        }
    } else {
        for &(c, r) in rows {
            let start = r.checked_mul(per_item)?;
            values.extend_from_slice(leaves.get(c)?.get(start..start.checked_add(per_item)?)?);
        }
    }
    Some(Buffer::from_vec(values))
}

/// A list column of `num_cells` cells of one instance each, its items' primitive values in
/// `values` (see [`gather_single_values`] and the write buffer's columns).
pub(super) fn single_values_list(
    item_field: &FieldRef,
    leaf_type: &DataType,
    fixed_size: Option<usize>,
    num_cells: i32,
    values: Buffer,
    nulls: Option<NullBuffer>,
) -> Result<ArrayRef, ChunkError> {
    // `0, 1, .., n`: ascending by construction, and Arrow still checks it, in one pass.
    let offsets = OffsetBuffer::new((0..=num_cells).collect::<ScalarBuffer<i32>>());
    let num_cells = offsets.len() - 1;
    // Checked against `values` by Arrow: a wrong length is an error, not a misread.
    let leaf_len = num_cells.saturating_mul(fixed_size.unwrap_or(1));
    let leaf = ArrayData::try_new(leaf_type.clone(), leaf_len, None, 0, vec![values], vec![])?;
    let items = match fixed_size {
        None => leaf,
        Some(_) => ArrayData::try_new(
            item_field.data_type().clone(),
            num_cells,
            None,
            0,
            vec![],
            vec![leaf],
        )?,
    };
    let list = ListArray::try_new(Arc::clone(item_field), offsets, make_array(items), nulls)?;
    Ok(Arc::new(list))
}

/// The chunk positions `rows` refer to, in order of first use, and `rows` renumbered into
/// that list; O(rows), whatever the number of chunks.
fn used_chunks(num_chunks: usize, rows: &[RowSource]) -> (Vec<usize>, Vec<RowSource>) {
    if num_chunks <= 1 {
        return (vec![0; num_chunks], rows.to_vec());
    }
    // Sized up front: a merge of a full fan uses every one of its chunks, and growing
    // one push at a time reallocated five times per merge.
    let mut used: Vec<usize> = Vec::with_capacity(num_chunks.min(rows.len()));
    // A table by chunk position while it is no bigger than a few times the rows (a merge of
    // small chunks, where hashing each row's chunk cost more than the copy); a hash map for
    // one piece of a rewrite of thousands of chunks, which a table per piece would make
    // quadratic again.
    let renumbered = if num_chunks <= 4 * rows.len() {
        let mut table = vec![usize::MAX; num_chunks];
        rows.iter()
            .map(|&(c, r)| {
                if table[c] == usize::MAX {
                    table[c] = used.len();
                    used.push(c);
                }
                (table[c], r)
            })
            .collect()
    } else {
        let mut local: ahash::HashMap<usize, usize> = ahash::HashMap::default();
        rows.iter()
            .map(|&(c, r)| {
                let position = *local.entry(c).or_insert_with(|| {
                    used.push(c);
                    used.len() - 1
                });
                (position, r)
            })
            .collect()
    };
    (used, renumbered)
}

#[cfg(test)]
mod tests {
    use super::used_chunks;

    #[test]
    fn rows_are_renumbered_into_the_chunks_they_use() {
        let (used, rows) = used_chunks(1000, &[(7, 0), (3, 2), (7, 1), (999, 0)]);
        assert_eq!(used, vec![7, 3, 999]);
        assert_eq!(rows, vec![(0, 0), (1, 2), (0, 1), (2, 0)]);
        assert_eq!(used_chunks(1, &[(0, 4)]), (vec![0], vec![(0, 4)]));
        // Both ways of numbering (a table for few chunks, a hash map for many) agree.
        let (used, rows) = used_chunks(8, &[(7, 0), (3, 2), (7, 1), (5, 0)]);
        assert_eq!(used, vec![7, 3, 5]);
        assert_eq!(rows, vec![(0, 0), (1, 2), (0, 1), (2, 0)]);
    }
}
