//! Comparing chunks and rows by what they hold: whether two chunks can share rows
//! (compaction merges only those), whether two are the same chunk (the store refuses a
//! second chunk under a held id), and whether a chunk holds a given row of another
//! (idempotent ingest, SEMANTICS.md section 6).

use std::sync::Arc;

use arrow_array::{Array, ListArray};

use super::data_types::same_data_type;
use super::{Chunk, ComponentColumn};

impl Chunk {
    /// Can rows of `self` and `other` live in one chunk? Same entity; same timelines with
    /// the same types, in the same order; same components with the same Arrow types and
    /// fields, in the same order; same schema metadata.
    pub(crate) fn has_same_layout(&self, other: &Self) -> bool {
        self.entity_path == other.entity_path
            && self.time_columns.len() == other.time_columns.len()
            && self.components.len() == other.components.len()
            && self
                .time_columns
                .iter()
                .zip(&other.time_columns)
                .all(|(a, b)| {
                    a.timeline == b.timeline
                        && same_data_type(&a.data_type, &b.data_type)
                        && a.field_metadata == b.field_metadata
                })
            && self.components.iter().zip(&other.components).all(|(a, b)| {
                a.descriptor == b.descriptor
                    && match (&a.field, &b.field) {
                        (None, None) => true,
                        (Some(a), Some(b)) => Arc::ptr_eq(a, b) || a == b,
                        _ => false,
                    }
                    && same_data_type(a.list.data_type(), b.list.data_type())
            })
            && self.extra_metadata == other.extra_metadata
    }

    /// Is `other` this very chunk: the same id, layout, rows, times and cells? (What a
    /// second insert of one chunk looks like, even decoded again from its file.)
    pub(crate) fn has_same_contents(&self, other: &Self) -> bool {
        self.id == other.id
            && self.row_ids == other.row_ids
            && self.has_same_layout(other)
            && self
                .time_columns
                .iter()
                .zip(&other.time_columns)
                .all(|(a, b)| a.times == b.times)
            && self
                .components
                .iter()
                .zip(&other.components)
                .all(|(a, b)| a.list == b.list)
    }

    /// Does this chunk hold a row equal to `other`'s row `row`: the same row id, the same
    /// time on every timeline and the same cell in every component? The two chunks must
    /// have the same layout ([`Chunk::has_same_layout`]).
    ///
    /// Cost: a search of the first timeline's `(time, row id)` order, then the rows of
    /// equal index; for a static chunk, a scan of its row ids.
    pub(crate) fn holds_row_of(&self, other: &Self, row: usize) -> bool {
        debug_assert!(
            self.has_same_layout(other),
            "rows compare within one layout"
        );
        let row_id = other.row_ids[row];
        let Some((first, other_first)) = self.time_columns.first().zip(other.time_columns.first())
        else {
            return (0..self.num_rows())
                .any(|mine| self.row_ids[mine] == row_id && self.row_equals(mine, other, row));
        };
        let time = other_first.times[row];
        let (start, end) = (
            first.num_positions_before(time),
            first.num_positions_at_or_before(time),
        );
        (start..end)
            .map(|position| first.row_at(position))
            .any(|mine| self.row_ids[mine] == row_id && self.row_equals(mine, other, row))
    }

    /// Are row `mine` of this chunk and row `theirs` of `other` (same layout) equal in
    /// every time and cell? (Row ids are the caller's to compare.)
    fn row_equals(&self, mine: usize, other: &Self, theirs: usize) -> bool {
        self.time_columns
            .iter()
            .zip(&other.time_columns)
            .all(|(a, b)| a.times[mine] == b.times[theirs])
            && self
                .components
                .iter()
                .zip(&other.components)
                .all(|(a, b)| cells_equal(a, mine, b, theirs))
    }

    /// Does some row have a null cell in every component? Such a row is in no index (no
    /// query sees it), so finding where it is held takes a scan.
    pub(crate) fn has_rows_without_cells(&self) -> bool {
        if self.components.iter().any(|c| c.list.null_count() == 0) {
            return false;
        }
        (0..self.num_rows()).any(|row| self.components.iter().all(|c| c.list.is_null(row)))
    }
}

/// Are two cells of columns of one type equal: both null, or both valid with equal
/// instances? Columns of primitives (or fixed-size lists of them) without null instances
/// compare their bytes; others go through Arrow's logical equality.
fn cells_equal(a: &ComponentColumn, row_a: usize, b: &ComponentColumn, row_b: usize) -> bool {
    let (list_a, list_b): (&ListArray, &ListArray) = (&a.list, &b.list);
    match (list_a.is_valid(row_a), list_b.is_valid(row_b)) {
        (false, false) => true,
        (true, true) => match (a.leaf_bytes(row_a), b.leaf_bytes(row_b)) {
            (Some(bytes_a), Some(bytes_b)) => bytes_a == bytes_b,
            _ => list_a.value(row_a).as_ref() == list_b.value(row_b).as_ref(),
        },
        _ => false,
    }
}
