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
//! Every rewrite orders its rows by `(time on the first timeline, row id)`, so merged
//! chunks are time-sorted whenever their rows allow it, then cuts them into equal pieces
//! that respect the thresholds ([`StoreConfig`]).
//!
//! **On demand**, [`ChunkStore::compact`] rewrites, per entity and layout, every set of
//! chunks that is not already as few time-sorted, non-overlapping chunks as the thresholds
//! allow. It decides first ([`ChunkStore::plan_compaction`], from `&self`: which groups,
//! which chunks, why) and applies second ([`ChunkStore::apply_compaction`]), as garbage
//! collection does.
//!
//! The modules: [`plan`] decides, [`apply`] carries a plan out, [`on_insert`] is the
//! cascade of compaction on insert, and [`rewrite`] is the row rewrite all of them share.

mod apply;
mod on_insert;
mod plan;
mod rewrite;

#[cfg(doc)]
use crate::{ChunkStore, StoreConfig};

pub use plan::{CompactionGroup, CompactionPlan, CompactionReason};
