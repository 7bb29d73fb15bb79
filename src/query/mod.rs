//! Queries: latest-at (SEMANTICS.md section 3, with Clears of section 5 applied) and range
//! (section 4). Answers point into the stored chunks: no cell is copied.

mod cursor;
mod latest_at;
mod range;

use std::sync::Arc;

use arrow_array::ArrayRef;

use crate::{Chunk, ChunkId, ComponentColumn, RowId, TimeInt};

pub(crate) use cursor::{CURSOR_BLOCK, RangeCursor};
pub use latest_at::LatestAtQuery;
pub use range::{RangeQuery, RangeResult, RangeRow, RangeRun, RunRows};

/// One cell a query answered with: the chunk and row it lives in, and its index.
#[derive(Clone, Debug)]
pub struct QueryCell {
    chunk: Arc<Chunk>,
    component_column: u32,
    row: u32,
    time: Option<TimeInt>,
}

impl QueryCell {
    /// The chunk holding the cell.
    pub fn chunk(&self) -> &Arc<Chunk> {
        &self.chunk
    }

    /// The id of the chunk holding the cell.
    pub fn chunk_id(&self) -> ChunkId {
        self.chunk.id()
    }

    /// The cell's row within its chunk.
    pub fn row(&self) -> usize {
        self.row as usize
    }

    /// The cell's time on the queried timeline; `None` for static data.
    pub fn time(&self) -> Option<TimeInt> {
        self.time
    }

    /// Is this static data?
    pub fn is_static(&self) -> bool {
        self.time.is_none()
    }

    /// The cell's row id (read from the chunk when asked: most readers never do, and it
    /// is a cache line of its own).
    pub fn row_id(&self) -> RowId {
        self.chunk.row_ids()[self.row as usize]
    }

    /// The component column the cell belongs to.
    pub fn column(&self) -> &ComponentColumn {
        &self.chunk.components()[self.component_column as usize]
    }

    /// The position of the cell's column among its chunk's components.
    pub(crate) fn component_column_index(&self) -> u32 {
        self.component_column
    }

    /// The cell's instances: a slice of the chunk's array, sharing its buffers.
    pub fn cell(&self) -> ArrayRef {
        self.column().list_array().value(self.row as usize)
    }
}
