//! Model test: random operation sequences run against two stores (compaction off, and
//! compaction with tiny thresholds) and against a deliberately naive model that keeps every
//! row in a list and scans it for every answer. After every step, answers must be
//! identical, `sanity_check()` must pass, and replaying every event returned so far must
//! give exactly the store's chunks.
//!
//! The operations: temporal inserts on any subset of three timelines (a sequence, a
//! duration and a timestamp timeline), with out-of-order, overlapping and duplicate times,
//! times at both extremes of `i64`, null cells, empty cells, and three component types
//! (floats, strings, fixed-size lists of integers); static inserts; flat and recursive
//! Clears, temporal and static, one to three in a chunk, at any depth of a tree of
//! entities up to five levels deep;
//! chunks inserted again (the same chunk, or its rows under a new id, after compaction has
//! had every chance to absorb them), rows reusing row ids with other contents, and chunks
//! reusing another chunk's id; garbage collections with random targets, orders and
//! protections; drops of time ranges and of entities; on-demand compaction; runs of 20 to
//! 40 chunks in time order past the small times, which turn an index into a sequence
//! (`index/mod.rs`) that overlapping chunks never form. Latest-at and range queries run
//! between them.
//!
//! The named properties of the lifecycle (SEMANTICS.md sections 6 to 8) reuse the same
//! generator and harness, each in its own test.
//!
//! Size: `PROPTEST_CASES` sets the cases of every property (default [`NUM_CASES`] for the
//! main one, [`PROPERTY_CASES`] for the others), `CHUNKSTORE_MODEL_OPS` the longest
//! sequence (default [`MAX_OPS`]). The defaults apply about 110,000 operations to stores in
//! one `cargo test --test model` (34 s in a release build here, 21 s before the runs);
//! `CHUNKSTORE_MODEL_REPORT=1 cargo test --test model -- --nocapture` prints the count.
//! A longer run: `PROPTEST_CASES=5000 CHUNKSTORE_MODEL_OPS=100 cargo test --release --test
//! model`.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::cast_possible_truncation,
    clippy::cast_precision_loss,
    reason = "tests fail loudly on unexpected values; test values are small integers, exact in f64"
)]

mod checks;
mod chunks;
#[path = "../common/mod.rs"]
mod common;
mod dataframe;
mod harness;
mod naive;
mod ops;

use std::collections::{BTreeSet, HashMap, HashSet};
use std::sync::Arc;

use arrow_array::builder::{
    FixedSizeListBuilder, Float64Builder, Int32Builder, ListBuilder, StringBuilder,
};
use arrow_array::cast::AsArray;
use arrow_array::types::{DurationNanosecondType, TimestampNanosecondType};
use arrow_array::types::{Float64Type, Int32Type};
use arrow_array::{Array, ArrayRef, BooleanArray, Int64Array, PrimitiveArray};
use chunkstore::{
    Chunk, ChunkId, ChunkStore, ComponentName, DataframeQuery, DeletionReason, EntityPathFilter,
    GcOptions, GcOrder, GcTarget, InsertError, LatestAtQuery, RangeQuery, RowId, Snapshot,
    StoreConfig, StoreEvent, StoreView, TimeInt, TimeRange, TimeType, Timeline,
};
use common::{bool_list, path, t};
use proptest::prelude::*;

use checks::*;
use chunks::*;
use dataframe::*;
use harness::*;
use naive::*;
use ops::*;

/// Number of random sequences per run; the closing note quotes it. `PROPTEST_CASES` in the
/// environment overrides it (and [`PROPERTY_CASES`]) for a longer run.
const NUM_CASES: u32 = 512;

/// Cases per run of each named property (each case runs a whole sequence).
const PROPERTY_CASES: u32 = 192;

/// `default`, or `PROPTEST_CASES` from the environment.
fn cases(default: u32) -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|cases| cases.parse().ok())
        .unwrap_or(default)
}

/// A store with compaction on insert off but tiny thresholds, so that `compact()` cuts
/// nearly every set of chunks into several.
const TINY_ON_DEMAND: StoreConfig = CONFIGS[1].with_compact_on_insert(false);

/// Every answer of the full sweep, in order (a range sorted as in [`check_range`]).
fn all_answers(store: &ChunkStore) -> Vec<Vec<Answer>> {
    let mut answers = Vec::new();
    for entity in 0..ENTITIES.len() {
        for component in 0..COMPONENTS.len() {
            for timeline in 0..TIMELINES.len() {
                for at in query_times() {
                    answers.push(
                        latest_at_answer(store, entity, component, timeline, at)
                            .into_iter()
                            .collect(),
                    );
                }
                for (min, max) in RANGES {
                    let mut range = range_answer(store, entity, component, timeline, min, max);
                    range.sort();
                    answers.push(range);
                }
            }
        }
    }
    answers
}

/// Latest-at at `+∞` of every (entity, component, timeline).
fn answers_at_infinity(store: &ChunkStore) -> Vec<Option<Answer>> {
    let mut answers = Vec::new();
    for entity in 0..ENTITIES.len() {
        for component in 0..COMPONENTS.len() {
            for timeline in 0..TIMELINES.len() {
                answers.push(latest_at_answer(
                    store,
                    entity,
                    component,
                    timeline,
                    i64::MAX,
                ));
            }
        }
    }
    answers
}

/// `(row id, time per timeline)` of every row the store holds; static rows have none.
fn rows_held(store: &ChunkStore) -> Vec<(u128, [Option<i64>; 3])> {
    let mut rows: Vec<_> = store
        .chunks_unordered()
        .flat_map(|chunk| {
            (0..chunk.num_rows()).map(move |row| {
                let times =
                    TIMELINES.map(|(name, _)| chunk.time_column(name).map(|c| c.times()[row]));
                (chunk.row_ids()[row].as_u128(), times)
            })
        })
        .collect();
    rows.sort_unstable();
    rows
}

/// Most operations in one random sequence by default; `CHUNKSTORE_MODEL_OPS` in the
/// environment overrides it. Sequences are 1 to this long, uniformly, so a run of `N`
/// cases applies about `N × (this + 1) / 2` operations per property.
const MAX_OPS: usize = 60;

/// [`MAX_OPS`], or `CHUNKSTORE_MODEL_OPS` from the environment.
fn max_ops() -> usize {
    std::env::var("CHUNKSTORE_MODEL_OPS")
        .ok()
        .and_then(|ops| ops.parse().ok())
        .filter(|&ops| ops >= 1)
        .unwrap_or(MAX_OPS)
}

/// Operations applied to a store so far by this test binary, every property together (an
/// operation run on two stores counts twice): see [`count_op`].
static OPS_APPLIED: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

fn ops() -> impl Strategy<Value = Vec<Op>> {
    prop::collection::vec(op(), 1..=max_ops())
}

fn shuffles() -> impl Strategy<Value = Vec<u64>> {
    prop::collection::vec(any::<u64>(), 1..16)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(NUM_CASES), max_shrink_iters: 4096, failure_persistence: common::seed_file("model/main.txt"), ..ProptestConfig::default() })]

    #[test]
    fn store_answers_like_the_naive_model(ops in ops(), shuffles in shuffles()) {
        run(&ops, &shuffles)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(PROPERTY_CASES), max_shrink_iters: 4096, failure_persistence: common::seed_file("model/main.txt"), ..ProptestConfig::default() })]

    /// Compaction on insert (tiny thresholds) and on demand (tiny and default thresholds)
    /// answer every query exactly as the store without compaction. Left out: garbage
    /// collection (which chunks it drops depends on how rows are chunked), reusing a
    /// chunk's id (refused only while the store holds that chunk as itself, which
    /// compaction decides) and reusing row ids (rows of one index answer in either order).
    /// Chunks inserted again are in: ingest is idempotent.
    #[test]
    fn compaction_preserves_all_queries(ops in ops(), shuffles in shuffles()) {
        let ops: Vec<Op> = ops
            .into_iter()
            .filter(|op| !matches!(op, Op::Gc(_) | Op::ReuseId { .. }))
            .map(|op| match op {
                // Rows reusing a row id at one time tie, and a tie may answer with either.
                Op::Temporal { entity, timelines, rows, .. } => {
                    Op::Temporal { entity, timelines, rows, reuse_row_ids: None }
                }
                other => other,
            })
            .collect();
        let plain = run_with(StoreConfig::COMPACTION_OFF, &ops, &shuffles)?.store;
        let expected = all_answers(&plain);
        let compacting = run_with(CONFIGS[1], &ops, &shuffles)?.store;
        prop_assert_eq!(&all_answers(&compacting), &expected);
        for config in [TINY_ON_DEMAND, StoreConfig::COMPACTION_OFF] {
            let mut store = run_with(config, &ops, &shuffles)?.store;
            store.compact();
            store.sanity_check().map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert_eq!(&all_answers(&store), &expected, "after compact() with {:?}", config);
            // A second pass finds nothing left to do.
            let again = store.compact();
            prop_assert!(again.is_empty(), "compact() is idempotent; second pass: {:?}", again);
        }
    }

    /// Inserting every chunk a second time, after everything else, changes nothing: no
    /// event, no answer (SEMANTICS.md section 6), with compaction on or off.
    #[test]
    fn inserting_everything_again_changes_nothing(ops in ops(), shuffles in shuffles()) {
        for config in CONFIGS {
            let mut harness = run_with(config, &ops, &shuffles)?;
            let answers = all_answers(&harness.store);
            let listing = harness.store.to_string();
            // Every chunk the store accepted: with nothing dropped or collected, it holds
            // all their rows already. (A refused chunk may go in now: the chunk under its id
            // may have been compacted away since.)
            for inserted in harness.history.clone().into_iter().filter(|i| i.accepted) {
                let events = harness.store.insert(Arc::clone(&inserted.chunk));
                match events {
                    Ok(events) => prop_assert_eq!(!events.is_empty(), harness.model.insert(&inserted.model)),
                    Err(InsertError::ChunkIdConflict { .. }) => {}
                    Err(other) => return Err(TestCaseError::fail(format!("{other}"))),
                }
            }
            // Nothing dropped or collected since: every row was held already.
            if !ops.iter().any(|op| matches!(op, Op::Gc(_) | Op::DropTimeRange { .. } | Op::DropEntity { .. } | Op::Retain { .. })) {
                prop_assert_eq!(harness.store.to_string(), listing);
            }
            harness.full_sweep()?;
            if !ops.iter().any(|op| matches!(op, Op::Gc(_) | Op::DropTimeRange { .. } | Op::DropEntity { .. } | Op::Retain { .. })) {
                prop_assert_eq!(all_answers(&harness.store), answers);
            }
        }
    }

    /// Whatever the options, garbage collection drops no static chunk, no chunk touching a
    /// protected range and none of the latest `n` (checked by brute force inside
    /// `Harness::apply`), and frees something when anything is collectable.
    #[test]
    fn gc_never_removes_static_or_protected(
        ops in ops(),
        shuffles in shuffles(),
        gc in prop::collection::vec(op(), 1..4),
    ) {
        for config in CONFIGS {
            let mut harness = run_with(config, &ops, &shuffles)?;
            let statics_before: Vec<u128> = static_row_ids(&harness.store);
            let mut randomness = shuffles.iter().copied().cycle();
            for op in gc.iter().filter(|op| matches!(op, Op::Gc(_))) {
                harness.apply(op, &mut randomness)?;
            }
            prop_assert_eq!(static_row_ids(&harness.store), statics_before);
            harness.full_sweep()?;
        }
    }

    /// With `protect_latest ≥ 1`, every latest-at at `+∞` answers as before, whatever the
    /// target and order.
    #[test]
    fn gc_protect_latest_keeps_latest_at_infinity(
        ops in ops(),
        shuffles in shuffles(),
        protect_latest in 1usize..3,
        cursor in prop::option::of((0..3usize, query_time())),
    ) {
        for config in CONFIGS {
            let mut store = run_with(config, &ops, &shuffles)?.store;
            let before = answers_at_infinity(&store);
            let options = GcOp { target: 0, protect_latest, cursor, protected: None, zero_budget: false }.options();
            store.gc(&options);
            store.sanity_check().map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert_eq!(answers_at_infinity(&store), before);
        }
    }

    /// Replaying every event, as returned and as a subscriber saw them, on an empty set of
    /// chunks gives exactly the store's chunks (the same `Arc`s), compaction included.
    #[test]
    fn events_replay_to_store_contents(ops in ops(), shuffles in shuffles()) {
        for config in CONFIGS {
            let mut harness = Harness::new(config);
            let seen = Arc::new(std::sync::Mutex::new(HashMap::<ChunkId, Arc<Chunk>>::new()));
            let sink = Arc::clone(&seen);
            harness.store.subscribe(move |events| {
                let mut seen = sink.lock().unwrap();
                for event in events {
                    match event {
                        StoreEvent::Addition(chunk) => { seen.insert(chunk.id(), Arc::clone(chunk)); }
                        StoreEvent::Deletion { chunk, .. } => { seen.remove(&chunk.id()); }
                        other => panic!("an event of an unknown kind: {other:?}"),
                    }
                }
            });
            let mut randomness = shuffles.iter().copied().cycle();
            for op in &ops {
                harness.apply(op, &mut randomness)?;
            }
            let held: HashMap<ChunkId, Arc<Chunk>> =
                harness.store.chunks_unordered().map(|c| (c.id(), Arc::clone(c))).collect();
            for replayed in [&harness.replayed, &*seen.lock().unwrap()] {
                prop_assert_eq!(replayed.len(), held.len());
                for (id, chunk) in replayed {
                    prop_assert!(held.get(id).is_some_and(|h| Arc::ptr_eq(h, chunk)), "{} replays to the held chunk", id);
                }
            }
        }
    }

    /// `drop_time_range` removes exactly the rows whose time on the timeline is in the
    /// range (with all their timelines) and keeps every other row, static ones included.
    #[test]
    fn drop_time_range_removes_exactly_the_range(
        ops in ops(),
        shuffles in shuffles(),
        timeline in 0..3usize,
        min in time(),
        len in 0..6i64,
    ) {
        for config in CONFIGS {
            let mut harness = run_with(config, &ops, &shuffles)?;
            let before = rows_held(&harness.store);
            let max = min.saturating_add(len);
            let op = Op::DropTimeRange { timeline, min, max };
            harness.apply(&op, &mut shuffles.iter().copied().cycle())?;
            let expected: Vec<_> = before
                .into_iter()
                .filter(|(_, times)| !times[timeline].is_some_and(|t| min <= t && t <= max))
                .collect();
            prop_assert_eq!(rows_held(&harness.store), expected);
            harness.full_sweep()?;
        }
    }

    /// Retention keeps exactly the rows at `newest − span` or later on the timeline (and
    /// every row without it, static ones included), where `newest` is the latest time any
    /// held row has there.
    #[test]
    fn retain_recent_keeps_exactly_the_last_span(
        ops in ops(),
        shuffles in shuffles(),
        timeline in 0..3usize,
        span in 0..8u64,
    ) {
        for config in CONFIGS {
            let mut harness = run_with(config, &ops, &shuffles)?;
            let before = rows_held(&harness.store);
            harness.apply(&Op::Retain { timeline, span }, &mut shuffles.iter().copied().cycle())?;
            let expected = retained(before, &[(timeline, span)]);
            prop_assert_eq!(rows_held(&harness.store), expected);
            harness.full_sweep()?;
        }
    }

    /// Retention on two timelines at once: a row stays only if no rule removes it, each
    /// rule's newest time measured before anything went (the rules' order does not matter).
    #[test]
    fn retain_recent_on_measures_every_rule_before_removing(
        ops in ops(),
        shuffles in shuffles(),
        first in 0..3usize,
        second in 0..3usize,
        spans in (0..8u64, 0..8u64),
    ) {
        for config in CONFIGS {
            let mut harness = run_with(config, &ops, &shuffles)?;
            let before = rows_held(&harness.store);
            let rules = [(first, spans.0), (second, spans.1)];
            let named: Vec<(&str, u64)> = rules.iter().map(|&(t, span)| (TIMELINES[t].0, span)).collect();
            let events = harness.store.retain_recent_on(&named);
            harness.store.sanity_check().map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert_eq!(events.is_empty(), rows_held(&harness.store) == before);
            let expected = retained(before, &rules);
            prop_assert_eq!(rows_held(&harness.store), expected.clone());
            let mut named = named;
            named.reverse();
            let mut reversed = run_with(config, &ops, &shuffles)?;
            reversed.store.retain_recent_on(&named);
            prop_assert_eq!(rows_held(&reversed.store), expected);
        }
    }
}

/// The naive answer of retention: of `rows` (`rows_held`), those that no `(timeline,
/// span)` rule removes, each rule's newest time taken from all of `rows` first.
fn retained(
    rows: Vec<(u128, [Option<i64>; 3])>,
    rules: &[(usize, u64)],
) -> Vec<(u128, [Option<i64>; 3])> {
    let cutoffs: Vec<(usize, Option<i128>)> = rules
        .iter()
        .map(|&(timeline, span)| {
            let newest = rows.iter().filter_map(|(_, times)| times[timeline]).max();
            (timeline, newest.map(|n| i128::from(n) - i128::from(span)))
        })
        .collect();
    rows.into_iter()
        .filter(|(_, times)| {
            cutoffs.iter().all(|&(timeline, cutoff)| {
                times[timeline].is_none_or(|t| cutoff.is_none_or(|c| i128::from(t) >= c))
            })
        })
        .collect()
}

fn static_row_ids(store: &ChunkStore) -> Vec<u128> {
    let mut ids: Vec<u128> = store
        .chunks_unordered()
        .filter(|c| c.is_static())
        .flat_map(|c| c.row_ids().iter().map(|r| r.as_u128()))
        .collect();
    ids.sort_unstable();
    ids
}

/// Wide time spans next to short ones: exercises the span classes of the index with
/// chunks that straddle query times by a lot.
#[test]
fn wide_and_narrow_chunks_answer_like_the_model() {
    let mut ops = Vec::new();
    for (i, entity) in (0..30i64).zip((0..3usize).cycle()) {
        let rows = vec![
            (
                [i % 13, 12 - i % 13, if i % 5 == 0 { i64::MAX } else { i }],
                [Some(vec![i]), None, Some(vec![i, 1])],
            ),
            (
                [(i * 7) % 13, i % 5, i64::MIN + 1 + i],
                [Some(vec![]), Some(vec![1]), None],
            ),
        ];
        ops.push(Op::Temporal {
            entity,
            timelines: 7,
            rows,
            reuse_row_ids: None,
        });
    }
    run(&ops, &[7, 3, 999, 1]).unwrap();
}

/// A sequence the long run (`PROPTEST_CASES=600 CHUNKSTORE_MODEL_OPS=120`) found failing
/// `inserting_everything_again_changes_nothing`, as proptest shrank it (its many rows,
/// all alike, written through the helpers below, the counts in its order). A static
/// recursive Clear at `/` is overwritten by a flat one, and a temporal chunk at `/a` then
/// takes the overwritten chunk's id: the export took the Clear for held (a chunk held its
/// id) and left it out, so the `.rrd` read back answered `/a` where the Clear hides it.
#[test]
#[allow(
    clippy::unreadable_literal,
    reason = "the picks as proptest printed them"
)]
fn an_overwritten_static_clear_whose_chunk_id_is_reused_survives_export() {
    use Op::{Again, Clear, ReuseId, RrdRoundTrip, Static};
    // Every temporal row is at time 0 on `t1`, with null cells.
    let empty_rows = |n: usize| vec![([0, 0, 0], [None, None, None]); n];
    let temporal = |n: usize| Op::Temporal {
        entity: 0,
        timelines: 1,
        rows: empty_rows(n),
        reuse_row_ids: None,
    };
    let empty_static = || Static {
        entity: 0,
        rows: vec![[None, None, None]],
    };
    let static_clear = |recursive: bool| Clear {
        entity: 0,
        time: None,
        recursive: vec![recursive],
    };
    let mut ops: Vec<Op> = vec![
        empty_static(),
        temporal(2),
        ReuseId {
            pick: 0,
            entity: 0,
            rows: empty_rows(2),
        },
        static_clear(true),
    ];
    ops.extend([1, 1, 4, 6].map(temporal));
    ops.push(empty_static());
    ops.push(Again {
        pick: 2746927093305330480,
        new_id: false,
    });
    ops.extend([3, 1, 1, 5, 2, 6, 1, 4, 2, 3, 1].map(temporal));
    ops.push(static_clear(false));
    ops.extend([1, 1].map(temporal));
    ops.push(ReuseId {
        pick: 15307115233365890451,
        entity: 1,
        rows: vec![([0, 0, 0], [None, None, Some(vec![])])],
    });
    ops.push(RrdRoundTrip { at: 0 });
    let shuffles: Vec<u64> = vec![920045262147u64, 6485629690759153000u64, 0u64, 0u64];
    for config in CONFIGS {
        let mut harness = run_with(config, &ops, &shuffles).unwrap();
        for inserted in harness.history.clone().into_iter().filter(|i| i.accepted) {
            match harness.store.insert(Arc::clone(&inserted.chunk)) {
                Ok(events) => assert_eq!(!events.is_empty(), harness.model.insert(&inserted.model)),
                Err(InsertError::ChunkIdConflict { .. }) => {}
                Err(other) => panic!("{other}"),
            }
        }
        harness.full_sweep().unwrap();
    }
}
