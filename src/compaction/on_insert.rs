//! Compaction on insert: a temporal chunk is split if oversized, else added; a small one
//! waits among its entity's waiting chunks (`store/pending.rs`) and full fans of them are
//! merged, level after level; what settles joins its entity's runs, and full tiers of runs
//! are merged, tier after tier, rewriting only chunks that overlap. What happens to a
//! chunk is decided by [`placement`] (a pure function of the configuration and the chunk)
//! and by the waiting groups' own `take_full_fan` and `take_full_tier`; the cascade here
//! carries it out.

use std::sync::Arc;

use crate::chunk::RowColumns;
use crate::store::{Joining, SettledRun, StoreConfig};
use crate::{Chunk, ChunkStore, EntityPath, StoreEvent};

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
                self.settle_run(SettledRun::new(pieces), events);
                return;
            }
        }
        let waits = placement == Placement::Wait;
        // The first level (a few rows) is the write buffer, out of the store-wide orders
        // and the indices: a buffered chunk that fills its group's fan comes back with the
        // fan (so the chunk itself is not needed after: no handle is cloned, two atomic
        // operations a row), and one that does not is done.
        if waits && config.level(chunk.num_rows()) == 0 {
            if let Some(fan) = self.buffer_chunk(chunk, events)
                && let Some(path) = fan.chunks.first().map(|c| c.entity_path().clone())
            {
                self.merge_fans(&path, fan.chunks, fan.columns, events);
            }
            return;
        }
        // A chunk that will wait to be merged stays out of the store-wide orders.
        if waits {
            self.add_chunk_to_orders(Arc::clone(&chunk), Joining::Waiting, events);
            self.merge_cascade(chunk, events);
        } else {
            self.add_chunk_to_orders(Arc::clone(&chunk), Joining::Settled, events);
            self.settle_run(SettledRun::new(vec![chunk]), events);
        }
    }

    /// Adds a small chunk (of level one or more) to its entity's waiting chunks and merges
    /// every full fan this completes.
    pub(super) fn merge_cascade(&mut self, member: Arc<Chunk>, events: &mut Vec<StoreEvent>) {
        let config = self.config;
        let path = member.entity_path().clone();
        let Some(entity) = self.entities.get_mut(&path) else {
            self.settle_in_global_orders(member.id());
            return;
        };
        let (group, level) = entity.pending.push(member, &config);
        // The entity just found answers the first question (most pushes complete no fan).
        if let Some(fan) = entity.pending.take_full_fan(group, level, &config) {
            self.merge_fans(&path, fan, None, events);
        }
    }

    /// Merges a full fan of waiting chunks of the entity at `path` (out of their groups or
    /// write buffer already; a write buffer's fan may come with its rows in `columns`),
    /// then every full fan the result completes, level after level.
    fn merge_fans(
        &mut self,
        path: &EntityPath,
        fan: Vec<Arc<Chunk>>,
        columns: Option<RowColumns>,
        events: &mut Vec<StoreEvent>,
    ) {
        let config = self.config;
        let mut full_fan = Some(fan);
        let mut columns = columns;
        while let Some(fan) = full_fan.take() {
            // The merge's events at once: growing one push at a time reallocated the
            // vector four times per merge.
            events.reserve(fan.len() + 1);
            let from_columns = columns
                .take()
                .and_then(|columns| self.merge_from_columns(columns, &fan));
            let Some(pieces) =
                from_columns.or_else(|| self.rewrite_held(&fan, "merging a fan of waiting chunks"))
            else {
                // The fan stays in the store as it is, no longer waiting.
                self.settle_fan(&fan);
                return;
            };
            // Remove before adding: the result covers the fan's times, so adding it first
            // would overlap them and turn an in-order entity's sequence index into the
            // general one. (If the fan was all the entity held, the entity goes and comes
            // back with the result; it had nothing else waiting.)
            self.remove_merged(&fan, events);
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
                let joining = if waits {
                    Joining::Waiting
                } else {
                    Joining::Settled
                };
                self.add_chunk_to_orders(piece, joining, events);
            }
            let Some(next) = grown else {
                self.settle_run(SettledRun::new(settled), events);
                return;
            };
            let Some(entity) = self.entities.get_mut(path) else {
                self.settle_in_global_orders(next.id());
                return;
            };
            let (group, level) = entity.pending.push(next, &config);
            full_fan = entity.pending.take_full_fan(group, level, &config);
        }
    }
}

impl ChunkStore {
    /// Hands a run of settled chunks (the store holds them, in the store-wide orders) to
    /// its entity's runs, and merges every full tier this completes, tier after tier.
    fn settle_run(&mut self, run: SettledRun, events: &mut Vec<StoreEvent>) {
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
    fn merge_runs(&mut self, runs: Vec<SettledRun>, events: &mut Vec<StoreEvent>) -> SettledRun {
        let mut chunks: Vec<Arc<Chunk>> =
            runs.into_iter().flat_map(SettledRun::into_chunks).collect();
        chunks.sort_by_key(|c| (c.time_columns()[0].time_range().min(), c.id()));
        let mut merged: Vec<Arc<Chunk>> = Vec::with_capacity(chunks.len());
        let mut cluster: Vec<Arc<Chunk>> = Vec::new();
        let mut cluster_end = crate::TimeInt::MIN;
        for chunk in chunks {
            let bounds = chunk.time_columns()[0].time_range();
            let (least, greatest) = (bounds.min(), bounds.max());
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
        SettledRun::new(merged)
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
        self.remove_merged(&cluster, events);
        for piece in pieces {
            let piece = Arc::new(piece);
            merged.push(Arc::clone(&piece));
            self.add_chunk(piece, events);
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::{Array, ArrayRef, Float64Array};

    use crate::dataframe::DataframeQuery;
    use crate::query::{LatestAtQuery, RangeQuery};
    use crate::{
        ChunkBuilder, ChunkId, ChunkStore, DeletionReason, EntityPath, GcOptions, RowId,
        StoreEvent, StoreView, TimeInt, TimeRange, Timeline,
    };

    fn t(time: i64) -> TimeInt {
        TimeInt::new(time).unwrap()
    }

    fn one_row(entity: &EntityPath, frame: i64) -> Arc<crate::Chunk> {
        let value = Arc::new(Float64Array::from(vec![f64::from(
            i32::try_from(frame).unwrap(),
        )])) as ArrayRef;
        Arc::new(
            ChunkBuilder::new(ChunkId::new(), entity.clone())
                .with_row(
                    RowId::new(),
                    [(Timeline::sequence("frame"), frame)],
                    [("x", value)],
                )
                .build()
                .unwrap(),
        )
    }

    fn value_at(view: &StoreView, entity: &EntityPath, at: i64) -> Option<f64> {
        let cell = view.latest_at(&LatestAtQuery::new("frame", t(at)), entity, "x")?;
        let values = cell.cell();
        let list = values.as_any().downcast_ref::<Float64Array>()?;
        Some(list.value(0))
    }

    fn range_times(view: &StoreView, entity: &EntityPath, min: i64, max: i64) -> Vec<i64> {
        let query = RangeQuery::new("frame", TimeRange::new(t(min), t(max)));
        view.range(&query, entity, "x")
            .iter()
            .filter_map(|row| row.time().map(TimeInt::as_i64))
            .collect()
    }

    /// A row leaving the write buffer other than in a full fan (a range drop) leaves the
    /// writer's columns to be made again: the next fan merges exactly the rows held, from
    /// columns again, in time order whatever the arrival order.
    #[test]
    fn a_fan_merges_the_rows_held_after_a_buffered_row_is_dropped() {
        let entity = EntityPath::parse("e").unwrap();
        let config = crate::StoreConfig::DEFAULT.with_merge_fanout(4);
        let mut store = ChunkStore::with_config(config).unwrap();
        for frame in [3, 1, 2] {
            store.insert(one_row(&entity, frame)).unwrap();
        }
        store.drop_time_range("frame", TimeRange::new(t(2), t(2)));
        store.sanity_check().unwrap();
        for frame in [5, 0] {
            store.insert(one_row(&entity, frame)).unwrap();
        }
        store.sanity_check().unwrap();
        assert_eq!(store.num_chunks(), 1, "the fan of four merged");
        assert_eq!(range_times(&store, &entity, 0, 10), vec![0, 1, 3, 5]);
        let merged = &store.chunks()[0];
        assert_eq!(merged.time_columns()[0].times(), [0, 1, 3, 5]);
        // A fan that never saw a removal is built from the columns as well.
        for frame in [9, 8, 7, 6] {
            store.insert(one_row(&entity, frame)).unwrap();
        }
        store.sanity_check().unwrap();
        assert_eq!(
            range_times(&store, &entity, 0, 10),
            vec![0, 1, 3, 5, 6, 7, 8, 9]
        );
    }

    /// An entity's chunks are its chunk set and its write buffer together (the buffer's
    /// chunks enter no set): an entity holding only buffered rows is still held, counted,
    /// compacted and dropped whole, and a recursive drop takes the buffered rows of its
    /// descendants.
    #[test]
    fn buffered_chunks_belong_to_their_entity_though_in_no_chunk_set() {
        let (root, child, other) = (
            EntityPath::parse("a").unwrap(),
            EntityPath::parse("a/b").unwrap(),
            EntityPath::parse("c").unwrap(),
        );
        let mut store = ChunkStore::new();
        let fanout = i64::try_from(store.config().merge_fanout).unwrap();
        // `a`: only buffered rows. `a/b`: a sealed fan and buffered rows. `c`: buffered.
        for frame in 0..3 {
            store.insert(one_row(&root, frame)).unwrap();
        }
        for frame in 0..fanout + 2 {
            store.insert(one_row(&child, frame)).unwrap();
        }
        store.insert(one_row(&other, 0)).unwrap();
        store.sanity_check().unwrap();
        assert!(
            store.entities[&root].chunk_ids.is_empty(),
            "buffered: in no set"
        );
        assert_eq!(store.entities[&child].chunk_ids.len(), 1, "the sealed fan");
        assert_eq!(store.num_chunks(), 3 + 1 + 2 + 1);
        assert_eq!(
            store.entity_paths(),
            vec![root.clone(), child.clone(), other.clone()]
        );

        // `compact()` plans the buffered rows of every entity.
        let mut compacted = store.clone();
        compacted.compact();
        compacted.sanity_check().unwrap();
        assert_eq!(compacted.num_chunks(), 3, "one chunk per entity");

        // A recursive drop takes every buffered row under the path, and the entities go.
        let events = store.drop_entity(&root, true);
        assert_eq!(events.len(), 3 + 1 + 2);
        store.sanity_check().unwrap();
        assert_eq!(store.entity_paths(), vec![other.clone()]);
        assert_eq!(store.num_chunks(), 1);
        // An entity that comes back after its drop starts from nothing.
        store.insert(one_row(&root, 5)).unwrap();
        store.sanity_check().unwrap();
        assert_eq!(store.num_chunks(), 2);
    }

    /// Rows arriving one per chunk wait in the write buffer, in no index, and every
    /// question sees them: latest-at, range, dataframes, idempotent ingest, garbage
    /// collection's protection of the latest, snapshots. The fan's last chunk seals them
    /// into one sorted chunk, with the events of any merge.
    #[test]
    fn small_chunks_wait_in_the_write_buffer_and_every_question_sees_them() {
        let entity = EntityPath::parse("e").unwrap();
        let mut store = ChunkStore::new();
        let fanout = store.config().merge_fanout;
        let frames = [5, 2, 8, 0, 9, 1, 7, 3, 6, 4];
        let chunks: Vec<_> = frames.iter().map(|&f| one_row(&entity, f)).collect();
        for chunk in &chunks {
            assert_eq!(store.insert(Arc::clone(chunk)).unwrap().len(), 1);
        }
        let view = &store.view.entities[&entity];
        assert_eq!(view.buffered.len(), frames.len());
        assert!(
            view.temporal_per_timeline_per_component.is_empty(),
            "in no index"
        );
        store.sanity_check().unwrap();

        assert_eq!(value_at(&store, &entity, 4), Some(4.0));
        assert_eq!(value_at(&store, &entity, 100), Some(9.0));
        assert_eq!(value_at(&store, &entity, -1), None);
        assert_eq!(range_times(&store, &entity, 2, 6), vec![2, 3, 4, 5, 6]);
        let rows: usize = store
            .dataframe(&DataframeQuery::new("frame"))
            .unwrap()
            .map(|batch| batch.unwrap().num_rows())
            .sum();
        assert_eq!(rows, frames.len());
        assert_eq!(store.chunks_unordered().count(), frames.len());
        assert_eq!(store.time_range("frame"), Some(TimeRange::new(t(0), t(9))));

        // Idempotent ingest: a buffered chunk again, or its row under another id.
        assert!(store.insert(Arc::clone(&chunks[0])).unwrap().is_empty());
        let copy = ChunkBuilder::new(ChunkId::new(), entity.clone())
            .with_row(
                chunks[0].row_ids()[0],
                [(Timeline::sequence("frame"), 5)],
                [("x", Arc::new(Float64Array::from(vec![5.0])) as ArrayRef)],
            )
            .build()
            .unwrap();
        assert!(store.insert(copy).unwrap().is_empty());

        // Garbage collection keeps the latest buffered row when asked to.
        let plan = store.plan_gc(&GcOptions::everything().with_protect_latest(1));
        let latest = chunks[4].id(); // frame 9
        assert!(!plan.chunk_ids.contains(&latest));
        assert_eq!(plan.chunk_ids.len(), frames.len() - 1);

        // `compact()` seals the buffer (here on a copy of the store).
        let mut compacted = store.clone();
        compacted.compact();
        assert!(compacted.view.entities[&entity].buffered.is_empty());
        assert_eq!(compacted.num_chunks(), 1);
        compacted.sanity_check().unwrap();
        assert_eq!(
            range_times(&compacted, &entity, 0, 100),
            (0..10).collect::<Vec<_>>()
        );

        // A snapshot keeps seeing the buffer as it was when taken.
        let snapshot = store.snapshot();
        let mut last_events = Vec::new();
        let last = 10 + i64::try_from(fanout - frames.len()).unwrap() - 1;
        for frame in 10..=last {
            last_events = store.insert(one_row(&entity, frame)).unwrap();
        }
        let view = &store.view.entities[&entity];
        assert!(view.buffered.is_empty(), "a full fan seals the buffer");
        let deletions = last_events
            .iter()
            .filter(|e| {
                matches!(
                    e,
                    StoreEvent::Deletion {
                        reason: DeletionReason::Compaction,
                        ..
                    }
                )
            })
            .count();
        assert_eq!(deletions, fanout);
        assert!(matches!(last_events.first(), Some(StoreEvent::Addition(_))));
        assert!(
            matches!(last_events.last(), Some(StoreEvent::Addition(c)) if c.num_rows() == fanout)
        );
        assert_eq!(store.num_chunks(), 1);
        store.sanity_check().unwrap();
        assert_eq!(
            value_at(&store, &entity, 100),
            Some(f64::from(i32::try_from(last).unwrap()))
        );
        assert_eq!(
            range_times(&store, &entity, 0, 100),
            (0..=last).collect::<Vec<_>>()
        );
        assert_eq!(value_at(&snapshot, &entity, 100), Some(9.0));
        assert_eq!(
            range_times(&snapshot, &entity, 0, 100),
            (0..10).collect::<Vec<_>>()
        );
    }

    /// The write buffer is compaction's first level: chunks with the same column names but
    /// another layout (here an archetype) wait in a group of their own, each group is
    /// merged the moment it holds a full fan and not before, and nothing of it waits in
    /// the other compaction groups. A lone small result of `compact()` stays as it is while
    /// later rows fill the buffer.
    #[test]
    fn each_layout_waits_in_its_own_group_and_seals_at_its_full_fan() {
        let entity = EntityPath::parse("e").unwrap();
        let mut store = ChunkStore::new();
        let fanout = store.config().merge_fanout;
        let tagged = |frame: i64| {
            let value = Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
            let descriptor = crate::ComponentDescriptor::new("x").with_archetype("Tagged");
            Arc::new(
                ChunkBuilder::new(ChunkId::new(), entity.clone())
                    .with_row(
                        RowId::new(),
                        [(Timeline::sequence("frame"), frame)],
                        [(descriptor, value)],
                    )
                    .build()
                    .unwrap(),
            )
        };
        let frames: Vec<i64> = (0..i64::try_from(fanout).unwrap()).collect();
        let (last, first) = frames.split_last().unwrap();
        for &frame in first {
            store.insert(one_row(&entity, frame)).unwrap();
            store.insert(tagged(frame)).unwrap();
        }
        let view = &store.view.entities[&entity];
        assert_eq!(view.buffered.len(), 2 * (fanout - 1));
        assert_eq!(view.buffered.largest_group(), fanout - 1);
        assert!(store.entities[&entity].pending.is_empty(), "only buffered");
        store.sanity_check().unwrap();

        // The plain layout's fan fills: it alone is merged, into one chunk.
        let events = store.insert(one_row(&entity, *last)).unwrap();
        assert_eq!(events.len(), 1 + fanout + 1);
        assert_eq!(store.view.entities[&entity].buffered.len(), fanout - 1);
        assert_eq!(store.num_chunks(), 1 + (fanout - 1));
        store.sanity_check().unwrap();
        store.insert(tagged(*last)).unwrap();
        assert!(store.view.entities[&entity].buffered.is_empty());
        assert_eq!(store.num_chunks(), 2);
        store.sanity_check().unwrap();

        // Garbage collection takes buffered chunks out of the buffer.
        let mut collected = ChunkStore::new();
        for &frame in &frames[..3] {
            collected.insert(one_row(&entity, frame)).unwrap();
        }
        collected.gc(&GcOptions::everything());
        assert!(collected.entities.is_empty());
        collected.sanity_check().unwrap();

        // A compacted store of three rows: one small settled chunk, which later rows do
        // not wait beside.
        for &frame in &frames[..3] {
            collected.insert(one_row(&entity, frame)).unwrap();
        }
        collected.compact();
        assert_eq!(collected.num_chunks(), 1);
        for &frame in &frames[3..] {
            collected.insert(one_row(&entity, frame)).unwrap();
        }
        collected.sanity_check().unwrap();
        assert_eq!(collected.view.entities[&entity].buffered.len(), fanout - 3);
        assert_eq!(range_times(&collected, &entity, 0, 100), frames);
    }
}
