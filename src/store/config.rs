//! [`StoreConfig`]: how a store sizes its chunks, and the size tests compaction decides by.

use crate::Chunk;
use crate::error::ConfigError;

/// How a store sizes its chunks. Thresholds bound every chunk compaction writes; chunks
/// inserted whole are split when they exceed them (unless compaction on insert is off).
///
/// The defaults ([`StoreConfig::DEFAULT`]) and the measurements behind them are
/// documented in `docs/PERFORMANCE.md`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StoreConfig {
    /// Merge small chunks and split big ones on insert.
    pub compact_on_insert: bool,
    /// Most rows of a chunk whose rows are sorted by time on every timeline.
    pub max_rows: usize,
    /// Most rows of a chunk whose rows are not (a query must search it through a sort
    /// order, so it stays smaller).
    pub max_rows_unsorted: usize,
    /// Most payload bytes ([`Chunk::payload_bytes`]) of a chunk.
    pub max_bytes: u64,
    /// How many waiting chunks of one level compaction on insert merges at once (at
    /// least 2). Larger fans copy each row fewer times (`log_K(max_rows)`) but leave more
    /// small chunks waiting (up to `K − 1` per level). The default, 16, copies a row at
    /// most 3 times under the default thresholds and keeps at most 45 chunks waiting per
    /// entity and layout, whose time ranges do not overlap when data arrives in order.
    pub merge_fanout: usize,
}

impl StoreConfig {
    /// Compaction on insert, with the thresholds we measured best (see
    /// `docs/PERFORMANCE.md`).
    pub const DEFAULT: Self = Self {
        compact_on_insert: true,
        max_rows: 4096,
        max_rows_unsorted: 1024,
        max_bytes: 384 * 1024,
        merge_fanout: 16,
    };

    /// Chunks are stored exactly as inserted; [`ChunkStore::compact`] still uses the
    /// default thresholds.
    pub const COMPACTION_OFF: Self = Self {
        compact_on_insert: false,
        ..Self::DEFAULT
    };

    /// Checks that every chunk could hold a row.
    ///
    /// # Errors
    /// The first threshold that is zero.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (field, value) in [
            ("max_rows", self.max_rows as u64),
            ("max_rows_unsorted", self.max_rows_unsorted as u64),
            ("max_bytes", self.max_bytes),
        ] {
            if value == 0 {
                return Err(ConfigError::ZeroThreshold { field });
            }
        }
        if self.merge_fanout < 2 {
            return Err(ConfigError::FanoutBelowTwo {
                merge_fanout: self.merge_fanout,
            });
        }
        Ok(())
    }

    pub(crate) fn max_rows_for(&self, sorted: bool) -> usize {
        if sorted {
            self.max_rows
        } else {
            self.max_rows_unsorted
        }
    }

    /// Does the chunk exceed a threshold (and can be split)?
    pub(crate) fn is_oversized(&self, chunk: &Chunk) -> bool {
        chunk.num_rows() > 1
            && (chunk.num_rows() > self.max_rows_for(is_time_sorted(chunk))
                || chunk.payload_bytes() > self.max_bytes)
    }

    /// Could the chunk still double without exceeding a threshold?
    pub(crate) fn can_grow(&self, chunk: &Chunk) -> bool {
        chunk.num_rows() * 2 <= self.max_rows_for(is_time_sorted(chunk))
            && chunk.payload_bytes() * 2 <= self.max_bytes
    }
}

impl Default for StoreConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

pub(crate) fn is_time_sorted(chunk: &Chunk) -> bool {
    chunk
        .time_columns()
        .iter()
        .all(crate::TimeColumn::is_sorted)
}

impl StoreConfig {
    pub(crate) fn level(&self, num_rows: usize) -> usize {
        num_rows.max(1).ilog(self.merge_fanout.max(2)) as usize
    }
}
