//! Deciding what `compact()` rewrites: a [`CompactionPlan`] computed from `&self`, which
//! names each group of chunks to rewrite and why. Nothing here mutates; applying a plan is
//! [`super::apply`]'s job.

use std::sync::Arc;

use crate::store::StoreConfig;
use crate::{Chunk, ChunkId, ChunkStore, EntityPath};

/// Why a group of chunks is rewritten.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum CompactionReason {
    /// On the first timeline, a chunk is not sorted by time or two chunks overlap: a
    /// rewrite puts the rows in sequence.
    OutOfSequence,
    /// A chunk exceeds a threshold of the [`StoreConfig`].
    Oversized,
    /// The group has more chunks than the thresholds require.
    Fragmented,
}

/// The temporal chunks of one entity and layout that a compaction rewrites together.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct CompactionGroup {
    /// Their entity.
    pub entity_path: EntityPath,
    /// The chunks, by least time on their first timeline, then id: the order the rewrite
    /// reads them in.
    pub chunk_ids: Vec<ChunkId>,
    /// Why they are rewritten (the first reason that applies, in the order of
    /// [`CompactionReason`]'s variants).
    pub reason: CompactionReason,
}

/// What one on-demand compaction rewrites: made by [`ChunkStore::plan_compaction`],
/// carried out by [`ChunkStore::apply_compaction`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct CompactionPlan {
    /// The groups to rewrite, by entity.
    pub groups: Vec<CompactionGroup>,
    /// Groups of one entity and layout left as they are: already compact, or exactly
    /// what an earlier compaction made of them.
    pub num_groups_left_alone: usize,
}

impl CompactionPlan {
    /// Does the plan rewrite nothing?
    pub fn is_empty(&self) -> bool {
        self.groups.is_empty()
    }

    /// How many chunks the plan rewrites.
    pub fn num_chunks(&self) -> usize {
        self.groups.iter().map(|g| g.chunk_ids.len()).sum()
    }
}

impl ChunkStore {
    /// Chooses what [`ChunkStore::compact`] rewrites, without changing anything: per
    /// entity and layout, the temporal chunks that are not already as few time-sorted,
    /// non-overlapping chunks as the thresholds allow, nor exactly the chunks an earlier
    /// compaction made of them.
    ///
    /// ```
    /// # use std::sync::Arc;
    /// # use arrow_array::{ArrayRef, Float64Array};
    /// # use chunkstore::*;
    /// let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF)?;
    /// let entity = EntityPath::parse("/e").unwrap();
    /// for frame in 0..3 {
    ///     let value = Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
    ///     let chunk = ChunkBuilder::new(ChunkId::new(), entity.clone())
    ///         .with_row(RowId::new(), [(Timeline::sequence("frame"), frame)], [("x", value)])
    ///         .build()?;
    ///     store.insert(chunk)?;
    /// }
    /// let plan = store.plan_compaction();
    /// assert_eq!(plan.groups.len(), 1);
    /// assert_eq!(plan.groups[0].reason, CompactionReason::Fragmented);
    /// store.apply_compaction(&plan);
    /// assert_eq!(store.num_chunks(), 1);
    /// assert!(store.plan_compaction().is_empty());
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn plan_compaction(&self) -> CompactionPlan {
        let mut plan = CompactionPlan::default();
        for chunks in self.groups_by_entity_and_layout() {
            let reason = if self.is_one_rewrite(&chunks) {
                None
            } else {
                reason_to_rewrite(&chunks, &self.config)
            };
            match reason {
                Some(reason) => plan.groups.push(CompactionGroup {
                    entity_path: chunks[0].entity_path().clone(),
                    chunk_ids: chunks.iter().map(|c| c.id()).collect(),
                    reason,
                }),
                None => plan.num_groups_left_alone += 1,
            }
        }
        plan
    }

    /// The temporal chunks, grouped per entity and layout; groups by entity, chunks by
    /// least time on the first timeline, then id (a deterministic order).
    fn groups_by_entity_and_layout(&self) -> Vec<Vec<Arc<Chunk>>> {
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
        groups
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
}

/// Why `chunks` (one layout, sorted by least time on the first timeline) are not already
/// what a rewrite would make of them (in sequence on the first timeline, each within the
/// thresholds, and no more of them than the thresholds require); `None` if they are. A
/// group that needs no rewrite is left alone, which also makes `compact()` idempotent.
fn reason_to_rewrite(chunks: &[Arc<Chunk>], config: &StoreConfig) -> Option<CompactionReason> {
    let in_sequence_on = |t: usize| {
        chunks.iter().all(|c| c.time_columns()[t].is_sorted())
            && chunks.windows(2).all(|w| {
                w[0].time_columns()[t].time_range().1 <= w[1].time_columns()[t].time_range().0
            })
    };
    if !in_sequence_on(0) {
        return Some(CompactionReason::OutOfSequence);
    }
    if chunks.iter().any(|c| config.is_oversized(c)) {
        return Some(CompactionReason::Oversized);
    }
    let sorted = (1..chunks[0].time_columns().len()).all(in_sequence_on);
    let num_rows: usize = chunks.iter().map(|c| c.num_rows()).sum();
    let payload: u64 = chunks.iter().map(|c| c.payload_bytes()).sum();
    let fewest = num_rows
        .div_ceil(config.max_rows_for(sorted))
        .max(usize::try_from(payload.div_ceil(config.max_bytes)).unwrap_or(usize::MAX))
        .max(1);
    (chunks.len() > fewest).then_some(CompactionReason::Fragmented)
}
