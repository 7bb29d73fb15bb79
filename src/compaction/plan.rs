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
    /// Two neighbouring chunks of the group would fit in one within the thresholds.
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
    /// entity and layout, the temporal chunks that are not already compact (time-sorted
    /// and non-overlapping on the first timeline, each within the thresholds, no two
    /// neighbours that would fit in one chunk), nor exactly the chunks an earlier
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
        // Paths are compared per pair of entities, not per pair of chunks: sorting every
        // chunk by path was 43% of `compact()` on split chunks, where it only plans.
        let mut entities: Vec<_> = self.entities.iter().collect();
        entities.sort_unstable_by(|a, b| a.0.cmp(b.0));
        let mut temporal: Vec<&Arc<Chunk>> = Vec::new();
        for (_, entity) in entities {
            temporal.clear();
            if let Some(view) = self.view.entities.at(entity.slot) {
                temporal.extend(
                    entity
                        .held_chunks(view, &self.chunks)
                        .filter(|chunk| !chunk.is_static()),
                );
            }
            // Ids are unique, so an unstable sort is deterministic.
            temporal.sort_unstable_by_key(|c| (c.time_columns()[0].time_range().min(), c.id()));
            let entity_groups_start = groups.len();
            for chunk in &temporal {
                if let Some(group) = groups[entity_groups_start..]
                    .iter_mut()
                    .find(|g| g[0].has_same_layout(chunk))
                {
                    group.push(Arc::clone(chunk));
                } else {
                    groups.push(vec![Arc::clone(chunk)]);
                }
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
/// compact (in sequence on the first timeline, each within the thresholds, and no two
/// neighbours that would fit in one chunk); `None` if they are. A group that needs no
/// rewrite is left alone, which, with the marks of [`ChunkStore::is_one_rewrite`], makes
/// `compact()` idempotent.
fn reason_to_rewrite(chunks: &[Arc<Chunk>], config: &StoreConfig) -> Option<CompactionReason> {
    let in_sequence_on = |t: usize| {
        chunks.iter().all(|c| c.time_columns()[t].is_sorted())
            && chunks.windows(2).all(|w| {
                w[0].time_columns()[t].time_range().max()
                    <= w[1].time_columns()[t].time_range().min()
            })
    };
    if !in_sequence_on(0) {
        return Some(CompactionReason::OutOfSequence);
    }
    if chunks.iter().any(|c| config.is_oversized(c)) {
        return Some(CompactionReason::Oversized);
    }
    // Fragmented if two neighbours would fit in one chunk. Not "more chunks than the
    // fewest": chunks split on insert come in balanced pieces per source chunk, a few more
    // than the fewest for the whole group, and rewriting every row of a group to save
    // those few cost several loads. When no two neighbours fit together, the group has at
    // most twice the fewest chunks, plus one (a pair's rows or bytes exceed a threshold),
    // which is also what compaction on insert leaves: it settles chunks of more than half
    // a threshold.
    let sorted = (1..chunks[0].time_columns().len()).all(in_sequence_on);
    chunks
        .windows(2)
        .any(|w| {
            config.fits(
                w[0].num_rows() + w[1].num_rows(),
                w[0].payload_bytes() + w[1].payload_bytes(),
                sorted,
            )
        })
        .then_some(CompactionReason::Fragmented)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::{ArrayRef, Float64Array};

    use super::*;
    use crate::compaction::on_insert::{Placement, placement};
    use crate::{ChunkBuilder, RowId, Timeline};

    fn value() -> ArrayRef {
        Arc::new(Float64Array::from(vec![1.0]))
    }

    /// A chunk of `entity` with one row per frame of `frames`, in that order, under
    /// component `component`.
    fn chunk(entity: &str, component: &str, frames: &[i64]) -> Chunk {
        let mut builder = ChunkBuilder::new(ChunkId::new(), EntityPath::parse(entity).unwrap());
        for &frame in frames {
            builder = builder.with_row(
                RowId::new(),
                [(Timeline::sequence("frame"), frame)],
                [(component, value())],
            );
        }
        builder.build().unwrap()
    }

    fn store_of(chunks: Vec<Chunk>) -> (ChunkStore, Vec<ChunkId>) {
        let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).unwrap();
        let ids = chunks.iter().map(Chunk::id).collect();
        for chunk in chunks {
            store.insert(chunk).unwrap();
        }
        (store, ids)
    }

    #[test]
    fn small_chunks_in_sequence_are_one_fragmented_group_in_time_order() {
        let (store, ids) = store_of(vec![
            chunk("e", "x", &[2]),
            chunk("e", "x", &[0]),
            chunk("e", "x", &[1]),
        ]);
        let listing = store.to_string();
        let plan = store.plan_compaction();
        assert_eq!(store.to_string(), listing, "planning changes nothing");
        assert_eq!(plan.groups.len(), 1);
        let group = &plan.groups[0];
        assert_eq!(group.reason, CompactionReason::Fragmented);
        assert_eq!(group.entity_path, EntityPath::parse("e").unwrap());
        assert_eq!(group.chunk_ids, vec![ids[1], ids[2], ids[0]]);
        assert_eq!((plan.num_chunks(), plan.num_groups_left_alone), (3, 0));
    }

    #[test]
    fn overlapping_or_unsorted_chunks_are_out_of_sequence() {
        let (store, _) = store_of(vec![chunk("e", "x", &[0, 5]), chunk("e", "x", &[3, 8])]);
        let plan = store.plan_compaction();
        assert_eq!(plan.groups[0].reason, CompactionReason::OutOfSequence);
        let (store, _) = store_of(vec![chunk("e", "x", &[5, 1])]);
        assert_eq!(
            store.plan_compaction().groups[0].reason,
            CompactionReason::OutOfSequence
        );
    }

    #[test]
    fn a_chunk_over_a_threshold_is_oversized() {
        let frames: Vec<i64> = (0..10).collect();
        let config = StoreConfig::COMPACTION_OFF.with_max_rows(4);
        let mut store = ChunkStore::with_config(config).unwrap();
        store.insert(chunk("e", "x", &frames)).unwrap();
        let plan = store.plan_compaction();
        assert_eq!(plan.groups[0].reason, CompactionReason::Oversized);
        store.apply_compaction(&plan);
        assert_eq!(store.num_chunks(), 3, "10 rows in pieces of at most 4");
        assert!(store.plan_compaction().is_empty());
    }

    #[test]
    fn a_group_is_fragmented_only_where_two_neighbours_would_fit_in_one_chunk() {
        let config = StoreConfig::COMPACTION_OFF.with_max_rows(3);
        let plan_of = |frames: &[&[i64]]| {
            let mut store = ChunkStore::with_config(config).unwrap();
            for frames in frames {
                store.insert(chunk("e", "x", frames)).unwrap();
            }
            store.plan_compaction()
        };
        // Three chunks where two would do, but no two neighbours fit together (what a
        // split on insert leaves): left alone.
        let plan = plan_of(&[&[0, 1], &[2, 3], &[4, 5]]);
        assert!(plan.is_empty(), "{plan:?}");
        assert_eq!(plan.num_groups_left_alone, 1);
        // The middle one and either neighbour fit in three rows.
        let plan = plan_of(&[&[0, 1], &[2], &[4, 5]]);
        assert_eq!(plan.groups.len(), 1);
        assert_eq!(plan.groups[0].reason, CompactionReason::Fragmented);
        // Bytes count too: with room for one row's payload, no two rows fit.
        let (mut store, _) = store_of(vec![chunk("e", "x", &[0]), chunk("e", "x", &[1])]);
        let one_row = store.chunks_unordered().next().unwrap().payload_bytes();
        store.config = StoreConfig::COMPACTION_OFF.with_max_bytes(one_row);
        assert!(store.plan_compaction().is_empty());
        store.config = StoreConfig::COMPACTION_OFF.with_max_bytes(2 * one_row);
        assert_eq!(store.plan_compaction().groups.len(), 1);
    }

    #[test]
    fn compact_groups_and_one_rewrites_output_are_left_alone() {
        let (mut store, _) = store_of(vec![chunk("e", "x", &[0, 1, 2]), chunk("f", "x", &[0])]);
        let plan = store.plan_compaction();
        assert!(plan.is_empty());
        assert_eq!(plan.num_groups_left_alone, 2);

        store.insert(chunk("e", "x", &[3])).unwrap();
        let plan = store.plan_compaction();
        assert_eq!(plan.groups.len(), 1);
        let events = store.apply_compaction(&plan);
        assert_eq!(events.len(), 3, "two deletions, one addition");
        let again = store.plan_compaction();
        assert!(again.is_empty(), "{again:?}");
        assert!(store.compact().is_empty());
    }

    #[test]
    fn layouts_are_grouped_apart() {
        let (store, ids) = store_of(vec![
            chunk("e", "x", &[0]),
            chunk("e", "y", &[1]),
            chunk("e", "x", &[2]),
            chunk("e", "y", &[3]),
        ]);
        let plan = store.plan_compaction();
        let mut groups: Vec<Vec<ChunkId>> =
            plan.groups.iter().map(|g| g.chunk_ids.clone()).collect();
        groups.sort();
        let mut expected = vec![vec![ids[0], ids[2]], vec![ids[1], ids[3]]];
        expected.sort();
        assert_eq!(groups, expected);
    }

    #[test]
    fn a_stale_or_mixed_plan_changes_nothing_it_should_not() {
        let four_chunks = || {
            vec![
                chunk("e", "x", &[0]),
                chunk("e", "x", &[1]),
                chunk("f", "x", &[2]),
                chunk("e", "y", &[3]),
            ]
        };
        let (mut store, ids) = store_of(four_chunks());
        let stale = store.plan_compaction();
        store.drop_entity(&EntityPath::parse("e").unwrap(), false);
        let listing = store.to_string();
        assert!(store.apply_compaction(&stale).is_empty());
        assert_eq!(store.to_string(), listing);

        let (mut store, _) = store_of(four_chunks());
        let listing = store.to_string();
        let mixed = |chunk_ids: Vec<ChunkId>| CompactionPlan {
            groups: vec![CompactionGroup {
                entity_path: EntityPath::parse("e").unwrap(),
                chunk_ids,
                reason: CompactionReason::Fragmented,
            }],
            num_groups_left_alone: 0,
        };
        let of = |entity: &str, component: &str| -> Vec<ChunkId> {
            let mut ids: Vec<ChunkId> = store
                .chunks_unordered()
                .filter(|c| c.entity_path().to_string() == entity)
                .filter(|c| c.component(component).is_some())
                .map(|c| c.id())
                .collect();
            ids.sort();
            ids
        };
        let (e_x, f_x, e_y) = (of("/e", "x"), of("/f", "x"), of("/e", "y"));
        for bad in [
            vec![e_x[0], f_x[0]],
            vec![e_x[0], e_y[0]],
            vec![e_x[0], e_x[0]],
            vec![e_x[0], ids[0]],
        ] {
            assert!(store.apply_compaction(&mixed(bad)).is_empty());
            assert_eq!(store.to_string(), listing);
        }
        assert_eq!(store.apply_compaction(&mixed(e_x)).len(), 3);
    }

    #[test]
    fn placement_splits_the_oversized_keeps_the_small_waiting_and_settles_the_rest() {
        let config = StoreConfig::DEFAULT.with_max_rows(8);
        let sorted = |n: i64| chunk("e", "x", &(0..n).collect::<Vec<_>>());
        assert_eq!(placement(&config, &sorted(1)), Placement::Wait);
        assert_eq!(placement(&config, &sorted(4)), Placement::Wait);
        assert_eq!(placement(&config, &sorted(5)), Placement::Settle);
        assert_eq!(placement(&config, &sorted(8)), Placement::Settle);
        assert_eq!(placement(&config, &sorted(9)), Placement::Split);
        // Unsorted rows have their own, smaller threshold.
        let unsorted = config.with_max_rows_unsorted(2);
        assert_eq!(
            placement(&unsorted, &chunk("e", "x", &[3, 1, 2])),
            Placement::Split
        );
    }
}
