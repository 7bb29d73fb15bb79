//! Compaction on insert: a temporal chunk is split if oversized, else added; a small one
//! waits among its entity's waiting chunks (`store/pending.rs`) and full fans of them are
//! merged, level after level; what settles joins its entity's runs, and full tiers of runs
//! are merged, tier after tier, rewriting only chunks that overlap. What happens to a
//! chunk is decided by [`placement`] (a pure function of the configuration and the chunk)
//! and by the waiting groups' own `take_full_fan` and `take_full_tier`; the cascade here
//! carries it out.

use std::sync::Arc;

use crate::store::{DeletionReason, Run, StoreConfig};
use crate::{Chunk, ChunkStore, StoreEvent};

/// Where compaction on insert puts a temporal chunk.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Placement {
    /// It exceeds a threshold: its parts go in instead.
    Split,
    /// It could still double: it waits to be merged with others of its layout.
    Wait,
    /// It goes in as it is, for good.
    Settle,
}

/// Where compaction on insert puts `chunk`.
pub(crate) fn placement(config: &StoreConfig, chunk: &Chunk) -> Placement {
    if config.is_oversized(chunk) {
        Placement::Split
    } else if config.can_grow(chunk) {
        Placement::Wait
    } else {
        Placement::Settle
    }
}

impl ChunkStore {
    /// Inserts a validated temporal chunk with compaction: splits it if it exceeds a
    /// threshold, else adds it and merges full fans, level after level.
    pub(crate) fn insert_compacting(&mut self, chunk: Arc<Chunk>, events: &mut Vec<StoreEvent>) {
        let config = self.config;
        let placement = placement(&config, &chunk);
        if placement == Placement::Split {
            // Should the cut fail, the chunk goes in whole.
            if let Some(pieces) = self.rewrite_held(std::slice::from_ref(&chunk), "splitting") {
                // The chunk itself never enters the store: its parts do.
                let pieces: Vec<Arc<Chunk>> = pieces.into_iter().map(Arc::new).collect();
                for piece in &pieces {
                    self.add_chunk(Arc::clone(piece), events);
                }
                self.settle_run(Run::new(pieces), events);
                return;
            }
        }
        // A chunk that will wait to be merged stays out of the store-wide orders.
        let waits = placement == Placement::Wait;
        self.add_chunk_to_orders(Arc::clone(&chunk), !waits, events);
        if waits {
            self.merge_cascade(chunk, events);
        } else {
            self.settle_run(Run::new(vec![chunk]), events);
        }
    }

    /// Adds a small chunk to its entity's waiting chunks and merges every full fan this
    /// completes.
    pub(super) fn merge_cascade(&mut self, member: Arc<Chunk>, events: &mut Vec<StoreEvent>) {
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
            let Some(pieces) = self.rewrite_held(&fan, "merging a fan of waiting chunks") else {
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
            let mut settled = Vec::with_capacity(num_pieces);
            for piece in pieces {
                let piece = Arc::new(piece);
                let waits = num_pieces == 1 && config.can_grow(&piece);
                if waits {
                    grown = Some(Arc::clone(&piece));
                } else {
                    settled.push(Arc::clone(&piece));
                }
                self.add_chunk_to_orders(piece, !waits, events);
            }
            let Some(next) = grown else {
                self.settle_run(Run::new(settled), events);
                return;
            };
            let Some(entity) = self.entities.get_mut(&path) else {
                self.settle_in_global_orders(next.id());
                return;
            };
            (group, level) = entity.pending.push(next, &config);
        }
    }
}

impl ChunkStore {
    /// Hands a run of settled chunks (the store holds them, in the store-wide orders) to
    /// its entity's runs, and merges every full tier this completes, tier after tier.
    fn settle_run(&mut self, run: Run, events: &mut Vec<StoreEvent>) {
        let config = self.config;
        let mut run = run;
        loop {
            let Some(path) = run.first_entity_path() else {
                return;
            };
            let Some(entity) = self.entities.get_mut(&path) else {
                return;
            };
            let Some((group, tier)) = entity.pending.push_run(run, &config) else {
                return;
            };
            let Some(fan) = entity.pending.take_full_tier(group, tier, &config) else {
                return;
            };
            run = self.merge_runs(fan, events);
        }
    }

    /// One run of the chunks of `runs`: chunks overlapping none of the others on the first
    /// timeline are kept as they are, and each cluster of overlapping ones is rewritten
    /// into time-sorted pieces (which overlap nothing). Runs of an in-order stream merge
    /// without a copy.
    fn merge_runs(&mut self, runs: Vec<Run>, events: &mut Vec<StoreEvent>) -> Run {
        let mut chunks: Vec<Arc<Chunk>> = runs.into_iter().flat_map(Run::into_chunks).collect();
        chunks.sort_by_key(|c| (c.time_columns()[0].time_range().0, c.id()));
        let mut merged: Vec<Arc<Chunk>> = Vec::with_capacity(chunks.len());
        let mut cluster: Vec<Arc<Chunk>> = Vec::new();
        let mut cluster_end = crate::TimeInt::MIN;
        for chunk in chunks {
            let (least, greatest) = chunk.time_columns()[0].time_range();
            // Touching at one time is not overlapping: no time lies strictly inside both.
            if !cluster.is_empty() && least >= cluster_end {
                self.settle_cluster(std::mem::take(&mut cluster), &mut merged, events);
            }
            cluster_end = if cluster.is_empty() {
                greatest
            } else {
                cluster_end.max(greatest)
            };
            cluster.push(chunk);
        }
        self.settle_cluster(cluster, &mut merged, events);
        Run::new(merged)
    }

    /// Puts a cluster of overlapping chunks (or a lone chunk, as it is) into `merged`.
    fn settle_cluster(
        &mut self,
        cluster: Vec<Arc<Chunk>>,
        merged: &mut Vec<Arc<Chunk>>,
        events: &mut Vec<StoreEvent>,
    ) {
        if cluster.len() <= 1 {
            merged.extend(cluster);
            return;
        }
        let Some(pieces) = self.rewrite_held(&cluster, "merging overlapping settled chunks") else {
            return; // the cluster stays in the store as it is, in no run
        };
        events.reserve(cluster.len() + pieces.len());
        for chunk in &cluster {
            self.remove_chunk(chunk.id(), DeletionReason::Compaction, events);
        }
        for piece in pieces {
            let piece = Arc::new(piece);
            merged.push(Arc::clone(&piece));
            self.add_chunk(piece, events);
        }
    }
}
