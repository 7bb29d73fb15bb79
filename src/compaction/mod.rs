//! Compaction (SEMANTICS.md section 6): merging small temporal chunks into bigger ones and
//! splitting oversized ones, without changing any query's answer.
//!
//! **On insert**, every entity keeps, per chunk layout, the chunks still small enough to
//! grow, bucketed by *level*: `⌊log_K(rows)⌋` with `K` = [`StoreConfig::merge_fanout`].
//! A chunk enters the bucket of its level; when a bucket holds `K` chunks, they are merged
//! into one, whose level is at least one higher, and the cascade goes on from there. A row is
//! therefore copied at most `log_K(max_rows)` times (3 with the defaults), unlike the
//! re-copy of one growing chunk on every insert that costs `O(max_rows)` copies per row.
//! A chunk stops growing once it holds half of a threshold: merging it again could not
//! double it.
//!
//! The first level, chunks of fewer than `K` rows, is the **write buffer**: rows that
//! arrive one or a few at a time. Its chunks are the store's like any other (in the chunk
//! map, the figures, the events: a subscriber sees each one's addition on insert, then,
//! when its fan fills, the deletion of the fan's chunks for [`DeletionReason::Compaction`]
//! and the addition of the sealed chunk, all in the events of the insert that filled it),
//! but they enter no temporal index and no other compaction group: the entity's view
//! holds them (`store/buffer.rs`, grouped by layout and summarized so that a latest-at
//! past a group's newest row reads one summary), every query reads them beside the
//! indices (at most `K - 1` per layout, a few rows each), and the push that fills a
//! group's fan hands the group back whole, to be merged. A row that arrives in its own
//! chunk thus costs a push and its share of one merge, not an entry in every (timeline,
//! component) index it has cells for, taken out again a few inserts later. Snapshots
//! share the buffer with the rest of the entity's view (copied on write, at most `K - 1`
//! handles per layout). [`ChunkStore::compact`] seals every buffer; a result of
//! `compact()` too small for the second level stays as it is (the buffer holds only
//! chunks as they arrive).
//!
//! A chunk that no longer grows *settles*, and settled chunks join their entity's *runs*
//! (per layout, by *tier*, the level of a run's rows): sets of chunks that overlap none of
//! each other on the first timeline. A full fan of `K` runs in one tier merges into one run:
//! chunks that overlap none of the others are kept as they are (an in-order stream's runs
//! merge without a copy), and each cluster of overlapping ones is rewritten into sorted
//! pieces. Without runs, an out-of-order stream's settled chunks each spanned nearly all of
//! time and a latest-at searched every one of them, a cost linear in the stream's length;
//! with them, at most `K - 1` runs per tier and `K - 1` waiting chunks per level straddle
//! any time, and a row is copied once more per tier it climbs.
//!
//! Every rewrite orders its rows by `(time on the first timeline, row id)`, so merged
//! chunks are time-sorted whenever their rows allow it, then cuts them into equal pieces
//! that respect the thresholds ([`StoreConfig`]).
//!
//! **On demand**, [`ChunkStore::compact`] rewrites, per entity and layout, every set of
//! chunks that is not already compact: time-sorted and non-overlapping on the first
//! timeline, each within the thresholds, and no two neighbours that would fit in one
//! chunk (so at most about twice the fewest chunks the thresholds allow). It decides
//! first ([`ChunkStore::plan_compaction`], from `&self`: which groups, which chunks, why)
//! and applies second ([`ChunkStore::apply_compaction`]), as garbage collection does.
//!
//! The modules: [`plan`] decides, [`apply`] carries a plan out, [`on_insert`] is the
//! cascade of compaction on insert (waiting chunks, then runs), and [`rewrite`] is the row
//! rewrite all of them share.

mod apply;
mod on_insert;
mod plan;
mod rewrite;

#[cfg(doc)]
use crate::{ChunkStore, DeletionReason, StoreConfig};

pub use plan::{CompactionGroup, CompactionPlan, CompactionReason};
