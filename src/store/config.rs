//! [`StoreConfig`]: how a store sizes its chunks, and the size tests compaction decides by.

use std::fmt;

use crate::Chunk;

/// How a store sizes its chunks. Thresholds bound every chunk compaction writes; chunks
/// inserted whole are split when they exceed them (unless compaction on insert is off).
///
/// The defaults ([`StoreConfig::DEFAULT`]) and the measurements behind them are
/// documented in `docs/PERFORMANCE.md`.
///
/// Made from [`StoreConfig::DEFAULT`] or [`StoreConfig::COMPACTION_OFF`] and adjusted with
/// the `with_*` methods (so a field added later breaks no caller):
///
/// ```
/// use chunkstore::{ChunkStore, StoreConfig};
/// let config = StoreConfig::DEFAULT.with_max_rows(1024).with_merge_fanout(8);
/// let store = ChunkStore::with_config(config)?;
/// assert_eq!(store.config().max_rows, 1024);
/// assert!(ChunkStore::with_config(StoreConfig::DEFAULT.with_max_bytes(0)).is_err());
/// # Ok::<(), chunkstore::ConfigError>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
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

    /// Chunks are stored exactly as inserted; [`crate::ChunkStore::compact`] still uses the
    /// default thresholds.
    pub const COMPACTION_OFF: Self = Self {
        compact_on_insert: false,
        ..Self::DEFAULT
    };

    /// The same configuration, merging and splitting on insert or not.
    #[must_use]
    pub const fn with_compact_on_insert(mut self, compact_on_insert: bool) -> Self {
        self.compact_on_insert = compact_on_insert;
        self
    }

    /// The same configuration with [`StoreConfig::max_rows`] set.
    #[must_use]
    pub const fn with_max_rows(mut self, max_rows: usize) -> Self {
        self.max_rows = max_rows;
        self
    }

    /// The same configuration with [`StoreConfig::max_rows_unsorted`] set.
    #[must_use]
    pub const fn with_max_rows_unsorted(mut self, max_rows_unsorted: usize) -> Self {
        self.max_rows_unsorted = max_rows_unsorted;
        self
    }

    /// The same configuration with [`StoreConfig::max_bytes`] set.
    #[must_use]
    pub const fn with_max_bytes(mut self, max_bytes: u64) -> Self {
        self.max_bytes = max_bytes;
        self
    }

    /// The same configuration with [`StoreConfig::merge_fanout`] set.
    #[must_use]
    pub const fn with_merge_fanout(mut self, merge_fanout: usize) -> Self {
        self.merge_fanout = merge_fanout;
        self
    }

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

    /// Would a chunk of `rows` rows and `payload_bytes`, time-sorted or not, be within
    /// both thresholds? The one place the thresholds are compared with.
    pub(crate) fn fits(&self, rows: usize, payload_bytes: u64, sorted: bool) -> bool {
        rows <= self.max_rows_for(sorted) && payload_bytes <= self.max_bytes
    }

    /// Does the chunk exceed a threshold (and can be split)?
    pub(crate) fn is_oversized(&self, chunk: &Chunk) -> bool {
        chunk.num_rows() > 1
            && !self.fits(
                chunk.num_rows(),
                chunk.payload_bytes(),
                is_time_sorted(chunk),
            )
    }

    /// Could the chunk still double without exceeding a threshold?
    pub(crate) fn can_grow(&self, chunk: &Chunk) -> bool {
        self.fits(
            chunk.num_rows() * 2,
            chunk.payload_bytes() * 2,
            is_time_sorted(chunk),
        )
    }
}

impl Default for StoreConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

fn is_time_sorted(chunk: &Chunk) -> bool {
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

/// A [`crate::StoreConfig`] that cannot work.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum ConfigError {
    /// A threshold is zero: no chunk could hold a row.
    ZeroThreshold {
        /// The field.
        field: &'static str,
    },
    /// Compaction must merge at least two chunks at once.
    FanoutBelowTwo {
        /// The fanout given.
        merge_fanout: usize,
    },
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::ZeroThreshold { field } => {
                write!(f, "store config: {field} must be at least 1")
            }
            Self::FanoutBelowTwo { merge_fanout } => {
                write!(
                    f,
                    "store config: merge_fanout must be at least 2, not {merge_fanout}"
                )
            }
        }
    }
}

impl std::error::Error for ConfigError {}
