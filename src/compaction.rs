//! Compaction (SEMANTICS.md section 6): merging small temporal chunks into bigger ones and
//! splitting oversized ones, without changing any query's answer.
//!
//! **On insert**, every entity keeps, per chunk layout, the chunks still small enough to
//! grow, bucketed by *level*: `⌊log_K(rows)⌋` with `K` = [`StoreConfig::merge_fanout`].
//! A chunk enters
//! the bucket of its level; when a bucket holds `K` chunks, they are merged into one,
//! whose level is at least one higher, and the cascade goes on from there. A row is
//! therefore copied at most `log_K(max_rows)` times (3 with the defaults), unlike the
//! re-copy of one growing chunk on every insert that costs `O(max_rows)` copies per row.
//! A chunk stops growing once it holds half of a threshold: merging it again could not
//! double it.
//!
//! Every rewrite orders its rows by `(time on the first timeline, row id)`, so merged
//! chunks are time-sorted whenever their rows allow it, then cuts them into equal pieces
//! that respect the thresholds ([`StoreConfig`]).
//!
//! **On demand**, [`ChunkStore::compact`] rewrites, per entity and layout, every set of
//! chunks that is not already as few time-sorted, non-overlapping chunks as the thresholds
//! allow.

use std::sync::Arc;

use crate::chunk::RowSource;
use crate::error::{ChunkError, ConfigError};
use crate::store::{DeletionReason, StoredChunk};
use crate::{Chunk, ChunkId, ChunkStore, EntityPath, StoreEvent, StoreStats};

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

    fn max_rows_for(&self, sorted: bool) -> usize {
        if sorted {
            self.max_rows
        } else {
            self.max_rows_unsorted
        }
    }

    /// Does the chunk exceed a threshold (and can be split)?
    fn is_oversized(&self, chunk: &Chunk) -> bool {
        chunk.num_rows() > 1
            && (chunk.num_rows() > self.max_rows_for(is_time_sorted(chunk))
                || chunk.payload_bytes() > self.max_bytes)
    }

    /// Could the chunk still double without exceeding a threshold?
    fn can_grow(&self, chunk: &Chunk) -> bool {
        chunk.num_rows() * 2 <= self.max_rows_for(is_time_sorted(chunk))
            && chunk.payload_bytes() * 2 <= self.max_bytes
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
    fn level(&self, num_rows: usize) -> usize {
        num_rows.max(1).ilog(self.merge_fanout.max(2)) as usize
    }
}

/// Which on-demand rewrite made a chunk, and how many chunks it made.
///
/// `compact()` leaves alone a group of chunks that is exactly what one of its rewrites
/// made: rewriting them again would make the same chunks. (The size figures cannot tell:
/// rows of different sizes cut into pieces of equal row counts can leave a piece above the
/// byte threshold, and payloads change by a byte or two when validity bitmaps are cut
/// differently, so a check by size alone would rewrite such a group on every call.)
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct RewriteMark {
    /// The rewrite, numbered per store.
    pub rewrite: u64,
    /// How many chunks it made.
    pub num_pieces: usize,
}

/// The chunks of one entity still waiting to grow, per layout and level.
#[derive(Clone, Debug, Default)]
pub(crate) struct PendingGroups {
    /// One group per layout; never empty.
    groups: Vec<PendingGroup>,
}

#[derive(Clone, Debug, Default)]
struct PendingGroup {
    /// `levels[l]`: chunks of level `l`, oldest first; fewer than the fanout between
    /// merges.
    levels: Vec<Vec<Arc<Chunk>>>,
}

impl PendingGroup {
    fn any_chunk(&self) -> Option<&Arc<Chunk>> {
        self.levels.iter().flatten().next()
    }

    fn is_empty(&self) -> bool {
        self.levels.iter().all(Vec::is_empty)
    }
}

impl PendingGroups {
    fn group_position(&self, chunk: &Chunk) -> Option<usize> {
        self.groups
            .iter()
            .position(|g| g.any_chunk().is_some_and(|c| c.has_same_layout(chunk)))
    }

    /// Adds a chunk to its layout's group; returns the group's position and the chunk's
    /// level, which [`PendingGroups::take_full_fan`] takes back (so a chunk's layout is
    /// compared once per push, not again per level).
    fn push(&mut self, chunk: Arc<Chunk>, config: &StoreConfig) -> (usize, usize) {
        let position = self.group_position(&chunk).unwrap_or_else(|| {
            self.groups.push(PendingGroup::default());
            self.groups.len() - 1
        });
        let level = config.level(chunk.num_rows());
        let levels = &mut self.groups[position].levels;
        if levels.len() <= level {
            levels.resize_with(level + 1, Vec::new);
        }
        levels[level].push(chunk);
        (position, level)
    }

    /// If `level` of the group at `position` (as [`PendingGroups::push`] returned them)
    /// holds a full fan of chunks, takes them out.
    fn take_full_fan(
        &mut self,
        position: usize,
        level: usize,
        config: &StoreConfig,
    ) -> Option<Vec<Arc<Chunk>>> {
        let chunks = self.groups.get_mut(position)?.levels.get_mut(level)?;
        if chunks.len() < config.merge_fanout {
            return None;
        }
        let fan = chunks.drain(..config.merge_fanout).collect();
        if self.groups[position].is_empty() {
            self.groups.swap_remove(position);
        }
        Some(fan)
    }

    /// Every waiting chunk.
    pub fn chunks(&self) -> impl Iterator<Item = &Arc<Chunk>> {
        self.groups.iter().flat_map(|g| g.levels.iter().flatten())
    }

    /// Forgets a chunk that left the store (or was merged). Only the chunk's own level is
    /// searched: a merge removes each of its inputs, which have already left their level.
    pub fn remove(&mut self, chunk: &Chunk, config: &StoreConfig) {
        let id = chunk.id();
        let level = config.level(chunk.num_rows());
        let found = self.groups.iter().position(|group| {
            group
                .levels
                .get(level)
                .is_some_and(|l| l.iter().any(|c| c.id() == id))
        });
        if let Some(position) = found {
            self.groups[position].levels[level].retain(|c| c.id() != id);
            if self.groups[position].is_empty() {
                self.groups.swap_remove(position);
            }
        }
    }

    pub fn sanity_check(
        &self,
        path: &EntityPath,
        chunks: &ahash::HashMap<ChunkId, StoredChunk>,
        config: &StoreConfig,
    ) -> Result<(), String> {
        for group in &self.groups {
            let Some(first) = group.any_chunk() else {
                return Err(format!("{path}: no empty compaction group"));
            };
            for (l, members) in group.levels.iter().enumerate() {
                if members.len() >= config.merge_fanout {
                    return Err(format!("{path}: a full fan at level {l} was merged"));
                }
                for chunk in members {
                    let stored = chunks.get(&chunk.id());
                    if stored.is_none_or(|s| !Arc::ptr_eq(&s.chunk, chunk))
                        || chunk.is_static()
                        || chunk.entity_path() != path
                        || !chunk.has_same_layout(first)
                        || config.level(chunk.num_rows()) != l
                        || !config.can_grow(chunk)
                    {
                        return Err(format!(
                            "{path}: waiting chunk {} is a small temporal chunk of the \
                             store, in its layout's group at its level",
                            chunk.id()
                        ));
                    }
                }
            }
        }
        Ok(())
    }
}

/// A chunk position or row of a rewrite's input, as a sort key's half.
#[expect(
    clippy::cast_possible_truncation,
    reason = "rows < 2^32 (checked in Chunk::from_raw); 2^32 input chunks would not fit in memory"
)]
fn source_u32(position: usize) -> u32 {
    debug_assert!(u32::try_from(position).is_ok());
    position as u32
}

/// Rewrites the rows of `inputs` (one layout) into as few chunks as the thresholds allow,
/// ordered by `(time on the first timeline, row id)`. Counts what it copies in `stats`.
fn rewrite(
    inputs: &[&Chunk],
    config: &StoreConfig,
    stats: &mut StoreStats,
) -> Result<Vec<Chunk>, ChunkError> {
    let num_rows: usize = inputs.iter().map(|c| c.num_rows()).sum();
    let payload: u64 = inputs.iter().map(|c| c.payload_bytes()).sum();

    // Chunks whose rows are already in `(time, row id)` order on the first timeline,
    // each following the last, need no sort. (Times alone are not enough: rows of one
    // time would keep their input order.)
    let in_sequence = inputs
        .iter()
        .all(|c| c.time_columns()[0].index_order().is_none())
        && inputs.windows(2).all(|w| {
            let (last, first) = (
                w[0].time_columns()[0].time_range().1,
                w[1].time_columns()[0].time_range().0,
            );
            // Row ids only on a tie, as they live in another allocation.
            last < first
                || (last == first
                    && w[0].index_of_row(0, w[0].num_rows() - 1) <= w[1].index_of_row(0, 0))
        });
    let rows: Vec<RowSource> = if in_sequence {
        // Sized up front: a flattening collect knows no length and regrows.
        let mut rows = Vec::with_capacity(num_rows);
        for (c, chunk) in inputs.iter().enumerate() {
            rows.extend((0..chunk.num_rows()).map(|r| (c, r)));
        }
        rows
    } else {
        // Times read once into one array of 16-byte keys, then sorted: a sort calling
        // back into the chunks for every comparison cost a tenth of out-of-order
        // inserts, and keys carrying the row id were three times as large to move.
        // Row ids are read only to break a tie of times; the sort is stable, so equal
        // (time, row id) pairs keep input order.
        let mut keyed: Vec<(i64, u32, u32)> = Vec::with_capacity(num_rows);
        for (c, chunk) in inputs.iter().enumerate() {
            let times = chunk.time_columns()[0].times();
            for (r, &time) in times.iter().enumerate() {
                keyed.push((time, source_u32(c), source_u32(r)));
            }
        }
        let row_id = |&(_, c, r): &(i64, u32, u32)| inputs[c as usize].row_ids()[r as usize];
        keyed.sort_by(|a, b| a.0.cmp(&b.0).then_with(|| row_id(a).cmp(&row_id(b))));
        keyed
            .into_iter()
            .map(|(_, c, r)| (c as usize, r as usize))
            .collect()
    };
    // Rows are now in order on the first timeline; the others are checked.
    let sorted = (1..inputs[0].time_columns().len()).all(|t| {
        rows.windows(2).all(|w| {
            let time = |(c, r): RowSource| inputs[c].time_columns()[t].times()[r];
            time(w[0]) <= time(w[1])
        })
    });

    let max_rows = config.max_rows_for(sorted);
    let by_rows = num_rows.div_ceil(max_rows);
    let by_bytes = usize::try_from(payload.div_ceil(config.max_bytes)).unwrap_or(usize::MAX);
    let num_pieces = by_rows.max(by_bytes).clamp(1, num_rows.max(1));
    let pieces_rows = balanced_pieces(num_rows, num_pieces);

    let mut pieces = Vec::with_capacity(num_pieces);
    if let [single] = inputs
        && in_sequence
    {
        // Splitting a sorted chunk: slices share its buffers, nothing is copied.
        for piece in pieces_rows {
            pieces.push(single.slice(piece.start, piece.len())?);
        }
        return Ok(pieces);
    }
    for piece in pieces_rows {
        let piece = Chunk::gather(inputs, &rows[piece])?;
        stats.rows_copied_by_compaction += piece.num_rows() as u64;
        stats.payload_bytes_copied_by_compaction += piece.payload_bytes();
        pieces.push(piece);
    }
    Ok(pieces)
}

/// `0..num_rows` cut into `num_pieces` consecutive ranges whose lengths differ by at most
/// one (the longer first): exactly as many pieces as the thresholds ask for, none of them a
/// small remainder.
fn balanced_pieces(
    num_rows: usize,
    num_pieces: usize,
) -> impl Iterator<Item = std::ops::Range<usize>> {
    let (base, longer) = (num_rows / num_pieces, num_rows % num_pieces);
    (0..num_pieces).scan(0, move |start, piece| {
        let len = base + usize::from(piece < longer);
        let range = *start..*start + len;
        *start += len;
        Some(range)
    })
}

/// Are `chunks` (one layout, sorted by least time on the first timeline) already what
/// [`rewrite`] would make of them: in sequence on the first timeline, each within the
/// thresholds, and no more of them than the thresholds require? Then `compact()` leaves
/// them alone, which also makes it idempotent.
fn is_compact(chunks: &[Arc<Chunk>], config: &StoreConfig) -> bool {
    let in_sequence_on = |t: usize| {
        chunks.iter().all(|c| c.time_columns()[t].is_sorted())
            && chunks.windows(2).all(|w| {
                w[0].time_columns()[t].time_range().1 <= w[1].time_columns()[t].time_range().0
            })
    };
    if !in_sequence_on(0) || chunks.iter().any(|c| config.is_oversized(c)) {
        return false;
    }
    let sorted = (1..chunks[0].time_columns().len()).all(in_sequence_on);
    let num_rows: usize = chunks.iter().map(|c| c.num_rows()).sum();
    let payload: u64 = chunks.iter().map(|c| c.payload_bytes()).sum();
    let fewest = num_rows
        .div_ceil(config.max_rows_for(sorted))
        .max(usize::try_from(payload.div_ceil(config.max_bytes)).unwrap_or(usize::MAX))
        .max(1);
    chunks.len() <= fewest
}

impl ChunkStore {
    /// Inserts a validated temporal chunk with compaction: splits it if it exceeds a
    /// threshold, else adds it and merges full fans, level after level.
    pub(crate) fn insert_compacting(&mut self, chunk: Arc<Chunk>, events: &mut Vec<StoreEvent>) {
        let config = self.config;
        if config.is_oversized(&chunk)
            && let Ok(pieces) = rewrite(&[&chunk], &config, &mut self.stats)
        {
            // The chunk itself never enters the store: its parts do.
            for piece in pieces {
                self.add_chunk(Arc::new(piece), events);
            }
            return;
        }
        // A chunk that will wait to be merged stays out of the store-wide orders.
        let waits = config.can_grow(&chunk);
        self.add_chunk_to_orders(Arc::clone(&chunk), !waits, events);
        if waits {
            self.merge_cascade(chunk, events);
        }
    }

    /// Adds a small chunk to its entity's waiting chunks and merges every full fan this
    /// completes.
    fn merge_cascade(&mut self, member: Arc<Chunk>, events: &mut Vec<StoreEvent>) {
        let config = self.config;
        let path = member.entity_path().clone();
        let Some(entity) = self.entities.get_mut(&path) else {
            self.settle_in_global_orders(member.id());
            return;
        };
        let (mut group, mut level) = entity.pending.push(member, &config);
        loop {
            let Some(entity) = self.entities.get_mut(&path) else {
                return;
            };
            let Some(fan) = entity.pending.take_full_fan(group, level, &config) else {
                return;
            };
            // The merge's events at once: growing one push at a time reallocated the
            // vector four times per merge.
            events.reserve(fan.len() + 1);
            let inputs: Vec<&Chunk> = fan.iter().map(AsRef::as_ref).collect();
            let Ok(pieces) = rewrite(&inputs, &config, &mut self.stats) else {
                // The fan stays in the store as it is, no longer waiting.
                for chunk in &fan {
                    self.settle_in_global_orders(chunk.id());
                }
                return;
            };
            // Remove before adding: the result covers the fan's times, so adding it first
            // would overlap them and turn an in-order entity's sequence index into the
            // general one. (If the fan was all the entity held, the entity goes and comes
            // back with the result; it had nothing else waiting.)
            for merged in &fan {
                self.remove_chunk(merged.id(), DeletionReason::Compaction, events);
            }
            let mut grown = None;
            let num_pieces = pieces.len();
            for piece in pieces {
                let piece = Arc::new(piece);
                let waits = num_pieces == 1 && config.can_grow(&piece);
                if waits {
                    grown = Some(Arc::clone(&piece));
                }
                self.add_chunk_to_orders(piece, !waits, events);
            }
            let Some(next) = grown else { return };
            let Some(entity) = self.entities.get_mut(&path) else {
                self.settle_in_global_orders(next.id());
                return;
            };
            (group, level) = entity.pending.push(next, &config);
        }
    }

    /// Are `chunks` (a group of one entity and layout) exactly the chunks one rewrite of
    /// `compact()` made?
    fn is_one_rewrite(&self, chunks: &[Arc<Chunk>]) -> bool {
        let mark = |chunk: &Arc<Chunk>| self.chunks.get(&chunk.id()).and_then(|s| s.rewritten_by);
        let Some(first) = chunks.first().and_then(mark) else {
            return false;
        };
        first.num_pieces == chunks.len() && chunks.iter().all(|c| mark(c) == Some(first))
    }

    /// Rewrites the store's temporal chunks into chunks near the thresholds: per entity
    /// and layout, every set of chunks that is not already as few time-sorted,
    /// non-overlapping chunks as the thresholds allow (nor exactly what an earlier call
    /// made of it) is merged, sorted and cut again. For a store filled with compaction
    /// off, or fragmented by garbage collection. Returns the deletions (reason
    /// [`DeletionReason::Compaction`]) and additions; no query answer changes, and a
    /// second call in a row changes nothing.
    pub fn compact(&mut self) -> Vec<StoreEvent> {
        let config = self.config;
        // Group per entity and layout, in a deterministic order.
        let mut groups: Vec<Vec<Arc<Chunk>>> = Vec::new();
        let mut by_entity: ahash::HashMap<EntityPath, Vec<usize>> = ahash::HashMap::default();
        let mut temporal: Vec<&Arc<Chunk>> = self.chunks().filter(|c| !c.is_static()).collect();
        temporal.sort_by_key(|c| {
            (
                c.entity_path().clone(),
                c.time_columns()[0].time_range().0,
                c.id(),
            )
        });
        for chunk in temporal {
            let positions = by_entity.entry(chunk.entity_path().clone()).or_default();
            if let Some(&p) = positions
                .iter()
                .find(|&&p| groups[p][0].has_same_layout(chunk))
            {
                groups[p].push(Arc::clone(chunk));
            } else {
                positions.push(groups.len());
                groups.push(vec![Arc::clone(chunk)]);
            }
        }

        let mut events = Vec::new();
        for chunks in groups {
            if self.is_one_rewrite(&chunks) || is_compact(&chunks, &config) {
                continue;
            }
            let inputs: Vec<&Chunk> = chunks.iter().map(AsRef::as_ref).collect();
            let Ok(pieces) = rewrite(&inputs, &config, &mut self.stats) else {
                continue;
            };
            // Removed first, as in `merge_cascade`: the pieces cover the same times.
            for chunk in &chunks {
                self.remove_chunk(chunk.id(), DeletionReason::Compaction, &mut events);
            }
            let mark = RewriteMark {
                rewrite: self.num_rewrites,
                num_pieces: pieces.len(),
            };
            self.num_rewrites += 1;
            let mut small = Vec::new();
            for piece in pieces {
                let piece = Arc::new(piece);
                if mark.num_pieces == 1 && config.can_grow(&piece) {
                    small.push(Arc::clone(&piece));
                }
                let id = piece.id();
                self.add_chunk(piece, &mut events);
                if let Some(stored) = self.chunks.get_mut(&id) {
                    stored.rewritten_by = Some(mark);
                }
            }
            // A lone small result may keep growing with later inserts.
            if config.compact_on_insert {
                for chunk in small {
                    self.merge_cascade(chunk, &mut events);
                }
            }
        }
        self.notify(events)
    }
}
