//! New chunks from the rows of existing ones: the copies compaction, splitting and drops
//! make. Every function here builds through [`Chunk::from_raw`], so a rewritten chunk is
//! validated and indexed exactly like an inserted one.

use std::sync::Arc;

use arrow_array::{Array, ArrayRef};
use arrow_buffer::ScalarBuffer;

use super::{Chunk, RawComponentColumn, RawTimeColumn, RawTimes};
use crate::error::ChunkError;
use crate::{ChunkId, RowId};

/// Rows of several chunks with one layout: `(chunk position, row)`.
pub(crate) type RowSource = (usize, usize);

impl Chunk {
    /// A new chunk holding `rows` of `chunks` (which share one layout), in that order.
    ///
    /// # Errors
    /// Only if Arrow fails to copy, which would be a bug in this crate.
    pub(crate) fn gather(chunks: &[&Self], rows: &[RowSource]) -> Result<Self, ChunkError> {
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
                let lists: Vec<&dyn Array> = used
                    .iter()
                    .map(|&c| &chunks[c].components[position].list as &dyn Array)
                    .collect();
                let array = arrow_select::interleave::interleave(&lists, &local_rows)?;
                Ok(first.components[position].rebuilt(array))
            })
            .collect::<Result<Vec<_>, ChunkError>>()?;
        Self::from_raw(
            ChunkId::new(),
            first.entity_path.clone(),
            row_ids,
            times,
            components,
            first.extra_metadata.clone(),
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
        )
    }
}

impl super::TimeColumn {
    /// This column's timeline, type and metadata around other times.
    fn rebuilt(&self, times: ScalarBuffer<i64>) -> RawTimeColumn {
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
    fn rebuilt(&self, array: ArrayRef) -> RawComponentColumn {
        RawComponentColumn {
            descriptor: self.descriptor.clone(),
            array,
            field: self.field.clone(),
        }
    }
}

/// The chunk positions `rows` refer to, in order of first use, and `rows` renumbered into
/// that list; O(rows), whatever the number of chunks.
fn used_chunks(num_chunks: usize, rows: &[RowSource]) -> (Vec<usize>, Vec<RowSource>) {
    if num_chunks <= 1 {
        return (vec![0; num_chunks], rows.to_vec());
    }
    let mut used: Vec<usize> = Vec::new();
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
