//! Examples of the lifecycle rules (SEMANTICS.md sections 6 to 8): compaction on insert
//! and on demand, garbage collection (targets, orders, protections, time budget), drops,
//! events and statistics. The model test checks the same rules on random sequences; these
//! pin down one case each, readably.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::float_cmp,
    clippy::cast_precision_loss,
    clippy::cast_sign_loss,
    reason = "tests fail loudly on unexpected values; test values are small integers, exact in f64"
)]

use crate::common;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use arrow_array::{ArrayRef, Int64Array};
use chunkstore::{
    Chunk, ChunkId, ChunkStore, ConfigError, DeletionReason, GcOptions, GcOrder, GcTarget,
    LatestAtQuery, RangeQuery, StoreConfig, StoreEvent, TimeRange, Timeline,
};
use common::{clear, first_f64, path, scalar, scalars, static_scalar, t};

fn off() -> ChunkStore {
    ChunkStore::with_config(StoreConfig::COMPACTION_OFF).unwrap()
}

fn latest(store: &ChunkStore, entity: &str, at: i64) -> Option<f64> {
    store
        .latest_at(&LatestAtQuery::new("frame", t(at)), &path(entity), "x")
        .map(|cell| first_f64(&cell.cell()))
}

fn range_values(store: &ChunkStore, entity: &str) -> Vec<(i64, f64)> {
    store
        .range(&RangeQuery::everything("frame"), &path(entity), "x")
        .iter()
        .map(|row| (row.time().unwrap().as_i64(), first_f64(&row.cell())))
        .collect()
}

/// Ten chunks of ten rows at frames `10c..10c+9`, values = frame, row ids in order.
fn ten_by_ten(store: &mut ChunkStore, entity: &str) {
    for c in 0..10i64 {
        let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..10)
            .map(|r| {
                let frame = 10 * c + r;
                (frame, frame as u128 + 1, Some(vec![frame as f64]))
            })
            .collect();
        store.insert(scalars(entity, "x", &rows)).unwrap();
    }
}

/// `num_frames` one-row chunks at frames `num_frames - 1` down to 0 (values = frame), in
/// that order, row ids ascending as they arrive.
fn newest_first(store: &mut ChunkStore, entity: &str, num_frames: i64) {
    for frame in (0..num_frames).rev() {
        let row_id = (num_frames - frame) as u128;
        store
            .insert(scalar(entity, "x", frame, row_id, frame as f64))
            .unwrap();
    }
}

fn deleted(events: &[StoreEvent], reason: DeletionReason) -> Vec<Arc<Chunk>> {
    events
        .iter()
        .filter_map(|e| match e {
            StoreEvent::Deletion { chunk, reason: r } if *r == reason => Some(Arc::clone(chunk)),
            _ => None,
        })
        .collect()
}

#[test]
fn config_rejects_zero_thresholds_and_fanouts_below_two() {
    let zero_rows = StoreConfig::DEFAULT.with_max_rows(0);
    assert_eq!(
        ChunkStore::with_config(zero_rows).unwrap_err(),
        ConfigError::ZeroThreshold { field: "max_rows" }
    );
    let fanout = StoreConfig::DEFAULT.with_merge_fanout(1);
    let error = ChunkStore::with_config(fanout).unwrap_err();
    assert!(error.to_string().contains("merge_fanout"), "{error}");
}

#[test]
fn streaming_rows_merge_into_sorted_chunks_copying_each_row_a_few_times() {
    let mut store = ChunkStore::new();
    for frame in 0..10_000i64 {
        let events = store
            .insert(scalar("s", "x", frame, frame as u128 + 1, frame as f64))
            .unwrap();
        // Every merge reports the merged chunks as deletions and the result as addition.
        for event in &events[1..] {
            match event {
                StoreEvent::Deletion { reason, .. } => {
                    assert_eq!(*reason, DeletionReason::Compaction);
                }
                StoreEvent::Addition(chunk) => assert!(chunk.num_rows() > 1),
                other => panic!("an event of an unknown kind: {other:?}"),
            }
        }
    }
    let stats = store.stats();
    // log_8(4096) = 4 copies per row at most.
    assert!(stats.rows_copied_by_compaction <= 4 * stats.rows_inserted);
    assert!(
        store.num_chunks() <= 2 + 4 * 7,
        "{} chunks",
        store.num_chunks()
    );
    for chunk in store.chunks_unordered() {
        assert!(chunk.time_column("frame").unwrap().is_sorted());
        assert!(chunk.num_rows() <= StoreConfig::DEFAULT.max_rows);
    }
    assert_eq!(latest(&store, "s", 5_000), Some(5_000.0));
    assert_eq!(range_values(&store, "s").len(), 10_000);
}

#[test]
fn out_of_order_rows_merge_into_time_sorted_chunks() {
    let mut store = ChunkStore::new();
    // A permutation of 0..1000 (multiplying by a unit mod 1000).
    for k in 0..1000i64 {
        let frame = (k * 337) % 1000;
        store
            .insert(scalar("o", "x", frame, k as u128 + 1, frame as f64))
            .unwrap();
    }
    assert!(store.num_chunks() < 50, "{} chunks", store.num_chunks());
    assert!(
        store
            .chunks_unordered()
            .all(|c| c.time_column("frame").unwrap().is_sorted())
    );
    for at in [0, 1, 499, 999] {
        assert_eq!(latest(&store, "o", at), Some(at as f64));
    }
}

/// The most chunks of `entity` whose span on `frame` strictly contains one time: how many
/// a latest-at there must search.
fn most_straddling(store: &ChunkStore, entity: &str, times: impl Iterator<Item = i64>) -> usize {
    let spans: Vec<(i64, i64)> = store
        .chunks_unordered()
        .filter(|c| c.entity_path() == &path(entity))
        .map(|c| {
            let range = c.time_column("frame").unwrap().time_range();
            (range.min().as_i64(), range.max().as_i64())
        })
        .collect();
    times
        .map(|at| {
            spans
                .iter()
                .filter(|&&(lo, hi)| lo <= at && at < hi)
                .count()
        })
        .max()
        .unwrap_or(0)
}

/// A store with small thresholds, so that many chunks settle: at most 8 rows a chunk, fans
/// of 4.
fn small_chunks() -> ChunkStore {
    let config = StoreConfig::DEFAULT
        .with_max_rows(8)
        .with_max_rows_unsorted(4)
        .with_merge_fanout(4);
    ChunkStore::with_config(config).unwrap()
}

#[test]
fn an_out_of_order_stream_keeps_few_chunks_over_any_time() {
    let mut store = small_chunks();
    let n = 4_000i64;
    for k in 0..n {
        let frame = (k * 1_337) % n; // a permutation: 1,337 is a unit mod 4,000
        store
            .insert(scalar("o", "x", frame, k as u128 + 1, frame as f64))
            .unwrap();
    }
    store.sanity_check().unwrap();
    // Settled chunks of an out-of-order stream each span nearly all of time; without runs
    // every one of the ~500 would straddle a time in the middle. With them, at most
    // fanout - 1 runs per tier (and waiting chunks per level) do.
    let most = most_straddling(&store, "o", (0..n).step_by(7));
    assert!(most <= 3 * 8, "{most} chunks straddle one time");
    assert!(store.num_chunks() >= 500, "{} chunks", store.num_chunks());
    for at in (0..n).step_by(97) {
        assert_eq!(latest(&store, "o", at), Some(at as f64));
    }
    assert_eq!(range_values(&store, "o").len(), 4_000);
}

#[test]
fn an_in_order_stream_forms_runs_without_copying_again() {
    let mut store = small_chunks();
    let n = 4_000i64;
    for frame in 0..n {
        store
            .insert(scalar("i", "x", frame, frame as u128 + 1, frame as f64))
            .unwrap();
    }
    store.sanity_check().unwrap();
    // Each row is copied by the waiting levels alone (log_4(8) rounded up: 2 merges), never
    // by a merge of runs, whose chunks do not overlap.
    let stats = store.stats();
    assert!(
        stats.rows_copied_by_compaction <= 2 * stats.rows_inserted,
        "{} rows copied",
        stats.rows_copied_by_compaction
    );
    assert!(most_straddling(&store, "i", 0..n) <= 1);
    assert_eq!(latest(&store, "i", 1_234), Some(1_234.0));
}

#[test]
fn merged_rows_of_one_time_are_ordered_by_row_id() {
    let mut store = ChunkStore::new();
    // Sixteen one-row chunks (one full fan): eight frames, two rows each, the greater row
    // id of each frame arriving first.
    for k in 0..16u8 {
        let frame = i64::from(k / 2);
        let row_id = 100 + u128::from(2 * (k / 2) + 1 - k % 2);
        store
            .insert(scalar("tie", "x", frame, row_id, frame as f64))
            .unwrap();
    }
    assert_eq!(store.num_chunks(), 1);
    let chunk = store.chunks_unordered().next().unwrap();
    let expected: Vec<u128> = (100..116).collect();
    let row_ids: Vec<u128> = chunk.row_ids().iter().map(|r| r.as_u128()).collect();
    assert_eq!(row_ids, expected);
}

#[test]
fn an_oversized_sorted_chunk_is_split_into_slices_without_copying() {
    let mut store = ChunkStore::new();
    let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..10_000)
        .map(|i| (i, i as u128 + 1, Some(vec![i as f64])))
        .collect();
    let events = store.insert(scalars("big", "x", &rows)).unwrap();
    assert_eq!(events.len(), 3, "three additions of ≤ 4096 rows");
    assert!(store.chunks_unordered().all(|c| c.num_rows() <= 4096));
    assert_eq!(store.stats().rows_copied_by_compaction, 0);
    // The slices share the input's buffers, which the store counts once.
    let per_chunk: u64 = store.chunks_unordered().map(|c| c.heap_size_bytes()).sum();
    assert!(store.stats().heap_bytes < per_chunk);
    assert_eq!(range_values(&store, "big").len(), 10_000);
}

#[test]
fn an_oversized_unsorted_chunk_is_sorted_then_sized_as_sorted() {
    let mut store = ChunkStore::new();
    let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..3000)
        .map(|i| ((i * 7) % 3000, i as u128 + 1, Some(vec![i as f64])))
        .collect();
    store.insert(scalars("u", "x", &rows)).unwrap();
    // 3000 rows exceed the unsorted threshold (1024) but fit the sorted one (4096).
    assert_eq!(store.num_chunks(), 1);
    assert!(
        store
            .chunks_unordered()
            .all(|c| c.time_column("frame").unwrap().is_sorted())
    );
}

#[test]
fn compact_rewrites_a_fragmented_store_and_then_has_nothing_to_do() {
    let mut store = off();
    newest_first(&mut store, "f", 1000);
    let before = range_values(&store, "f");
    let events = store.compact();
    assert_eq!(deleted(&events, DeletionReason::Compaction).len(), 1000);
    assert_eq!(store.num_chunks(), 1);
    assert_eq!(range_values(&store, "f"), before);
    assert!(store.compact().is_empty());
}

/// A compaction that rewrites most of the store sets the store-wide orders aside and
/// rebuilds them once at the end: they must hold exactly the chunks they held piece by
/// piece (the sanity check compares them with orders made from scratch), and garbage
/// collection, which walks them, must still take the oldest rows first.
#[test]
fn compacting_most_of_a_store_keeps_its_orders_for_gc_and_time_ranges() {
    let mut store = off();
    // 1,000 one-row chunks of `f`, newest first: every one is rewritten.
    newest_first(&mut store, "f", 1000);
    // 50 entities with one compact chunk each, later in time: left as they are.
    for e in 0..50u128 {
        let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..10)
            .map(|r| (5000 + r, 10_000 + 10 * e + r as u128, Some(vec![r as f64])))
            .collect();
        store.insert(scalars(&format!("k{e}"), "x", &rows)).unwrap();
    }
    let time_range = store.time_range("frame");
    let events = store.compact();
    assert_eq!(deleted(&events, DeletionReason::Compaction).len(), 1000);
    store.sanity_check().unwrap();
    assert_eq!(store.time_range("frame"), time_range);

    let survivors_before_gc: Vec<ChunkId> = store.chunks_unordered().map(|c| c.id()).collect();
    let events = store
        .gc(&GcOptions::everything().with_target(GcTarget::drop_at_least_fraction(0.5).unwrap()));
    store.sanity_check().unwrap();
    let collected = deleted(&events, DeletionReason::Gc);
    assert!(!collected.is_empty());
    // Oldest rows first: every collected chunk's rows are older than every kept chunk's.
    let newest_collected = collected.iter().map(|c| c.row_id_range().1).max().unwrap();
    let oldest_kept = store
        .chunks_unordered()
        .map(|c| c.row_id_range().0)
        .min()
        .unwrap();
    assert!(newest_collected < oldest_kept);
    assert!(
        collected
            .iter()
            .all(|c| survivors_before_gc.contains(&c.id()))
    );
}

/// A collection that leaves few chunks rebuilds the store-wide orders from the survivors
/// (instead of taking each collected chunk out of them): the survivors must be exactly
/// what the orders hold, and what the next collection and the time range read.
#[test]
fn collecting_almost_everything_keeps_the_orders_of_what_is_left() {
    let mut store = off();
    ten_by_ten(&mut store, "a"); // frames 0..100, ten chunks
    for frame in 0..200i64 {
        store
            .insert(scalar("b", "x", frame, 1000 + frame as u128, frame as f64))
            .unwrap();
    }
    // Everything but the chunks touching frames 95..=96: a's last chunk, b's two rows.
    let options =
        GcOptions::everything().with_protected_time_range("frame", TimeRange::new(t(95), t(96)));
    let events = store.gc(&options);
    assert_eq!(deleted(&events, DeletionReason::Gc).len(), 9 + 198);
    store.sanity_check().unwrap();
    assert_eq!(store.num_chunks(), 3);
    assert_eq!(
        store.time_range("frame"),
        Some(TimeRange::new(t(90), t(99)))
    );
    // The next collection walks the rebuilt orders and takes the rest.
    let events = store.gc(&GcOptions::everything());
    assert_eq!(deleted(&events, DeletionReason::Gc).len(), 3);
    store.sanity_check().unwrap();
    assert_eq!(store.time_range("frame"), None);
}

#[test]
fn compact_group_by_group_hands_over_each_group_and_ends_where_compact_ends() {
    let fill = |store: &mut ChunkStore| {
        for entity in ["a", "b", "c"] {
            for frame in (0..300i64).rev() {
                store
                    .insert(scalar(
                        entity,
                        "x",
                        frame,
                        1000 - frame as u128,
                        frame as f64,
                    ))
                    .unwrap();
            }
        }
    };
    let (mut whole, mut stepwise) = (off(), off());
    fill(&mut whole);
    fill(&mut stepwise);
    let num_groups = stepwise.plan_compaction().groups.len();
    assert_eq!(num_groups, 3);
    let versions = (whole.snapshot().version(), stepwise.snapshot().version());
    let whole_events = whole.compact();
    let mut calls = Vec::new();
    stepwise.compact_group_by_group(|events| {
        calls.push(deleted(&events, DeletionReason::Compaction).len());
    });
    // One mutation each, however many groups.
    assert_eq!(whole.snapshot().version(), versions.0 + 1);
    assert_eq!(stepwise.snapshot().version(), versions.1 + 1);
    assert_eq!(
        calls,
        [300, 300, 300],
        "one call per group, with its deletions"
    );
    assert_eq!(
        deleted(&whole_events, DeletionReason::Compaction).len(),
        900
    );
    assert_eq!(stepwise.num_chunks(), whole.num_chunks());
    for entity in ["a", "b", "c"] {
        assert_eq!(
            range_values(&stepwise, entity),
            range_values(&whole, entity)
        );
    }
    stepwise.sanity_check().unwrap();
    let mut again = 0;
    stepwise.compact_group_by_group(|_| again += 1);
    assert_eq!(again, 0, "nothing left to compact");
}

#[test]
fn gc_plans_without_changing_anything_and_applies_exactly_its_plan() {
    let mut store = off();
    ten_by_ten(&mut store, "g");
    let listing = store.to_string();
    let options =
        GcOptions::everything().with_target(GcTarget::drop_at_least_fraction(0.3).unwrap());
    let plan = store.plan_gc(&options);
    assert_eq!(store.to_string(), listing, "planning changes nothing");
    assert_eq!(store.plan_gc(&options), plan, "planning is deterministic");
    assert!(!plan.chunk_ids.is_empty());
    let heap_before = store.stats().heap_bytes;
    let events = store.apply_gc(&plan);
    let dropped: Vec<ChunkId> = deleted(&events, DeletionReason::Gc)
        .iter()
        .map(|c| c.id())
        .collect();
    assert_eq!(dropped, plan.chunk_ids);
    assert_eq!(heap_before - store.stats().heap_bytes, plan.bytes_to_free);
    assert!(
        plan.bytes_to_free * 10 >= heap_before * 3,
        "the target is met"
    );
    // Oldest row ids first: frames 0..=9 went first.
    assert_eq!(range_values(&store, "g")[0].0 % 10, 0);
    assert!(latest(&store, "g", 5).is_none());
}

#[test]
fn gc_furthest_from_a_cursor_drops_the_far_chunks_first() {
    let mut store = off();
    ten_by_ten(&mut store, "g");
    let options = GcOptions::everything()
        .with_target(GcTarget::DropAtLeastBytes(1))
        .with_order(GcOrder::furthest_from("frame", t(52)));
    // [0, 9] ends 43 before the cursor; [90, 99] starts 38 after it.
    let first = store.gc(&options);
    assert_eq!(
        deleted(&first, DeletionReason::Gc)[0].row_ids()[0].as_u128(),
        1
    );
    let second = store.gc(&options);
    assert_eq!(
        deleted(&second, DeletionReason::Gc)[0].row_ids()[0].as_u128(),
        91
    );
    // The chunk holding the cursor goes last.
    let rest =
        store.gc(&GcOptions::everything().with_order(GcOrder::furthest_from("frame", t(52))));
    let last = deleted(&rest, DeletionReason::Gc).pop().unwrap();
    assert_eq!(last.row_ids()[0].as_u128(), 51);
}

#[test]
fn gc_never_touches_static_data_and_keeps_the_protected() {
    let mut store = off();
    ten_by_ten(&mut store, "g");
    store.insert(static_scalar("s", "x", 1000, 7.0)).unwrap();
    let events = store.gc(&GcOptions::everything()
        .with_protect_latest(1)
        .with_protected_time_range("frame", TimeRange::new(t(35), t(35))));
    assert_eq!(deleted(&events, DeletionReason::Gc).len(), 8);
    assert_eq!(store.stats().num_static_chunks, 1);
    let frames: Vec<i64> = range_values(&store, "g").iter().map(|r| r.0).collect();
    assert_eq!(frames, (30..40).chain(90..100).collect::<Vec<_>>());
    assert_eq!(latest(&store, "s", 0), Some(7.0));
}

/// A collection that takes every temporal chunk of an entity empties its temporal
/// structures at once (not entry by entry): whatever shape its indices had (a sequence, the
/// large index of overlapping chunks, the write buffer and waiting chunks of compaction on
/// insert), what is left is exactly its static data, and the entity takes temporal data again.
#[test]
fn gc_of_all_temporal_chunks_of_an_entity_leaves_exactly_its_static_data() {
    let configs = [StoreConfig::COMPACTION_OFF, StoreConfig::DEFAULT];
    for (config, overlapping) in configs.iter().flat_map(|c| [(*c, false), (*c, true)]) {
        let mut store = ChunkStore::with_config(config).unwrap();
        let mut static_only = ChunkStore::with_config(config).unwrap();
        for s in [&mut store, &mut static_only] {
            s.insert(static_scalar("e", "s", 1, 7.0)).unwrap();
        }
        // 40 chunks of 1 to 3 rows: in order, or each spanning nearly all of time.
        for c in 0..40i64 {
            let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..=c % 3)
                .map(|r| {
                    let frame = if overlapping {
                        (c * 7 + r * 100) % 300
                    } else {
                        10 * c + r
                    };
                    (frame, (c * 3 + r) as u128 + 10, Some(vec![frame as f64]))
                })
                .collect();
            store.insert(scalars("e", "x", &rows)).unwrap();
        }
        store.insert(clear("e", Some(50), 1000, false)).unwrap();
        let events = store.gc(&GcOptions::everything());
        assert!(!deleted(&events, DeletionReason::Gc).is_empty());
        store.sanity_check().unwrap();
        assert_eq!(latest(&store, "e", 1000), None, "{config:?} {overlapping}");
        assert!(range_values(&store, "e").is_empty());
        let static_cell = store.latest_at(&LatestAtQuery::new("frame", t(5)), &path("e"), "s");
        assert_eq!(static_cell.map(|c| first_f64(&c.cell())), Some(7.0));
        let (kept, expected) = (
            store.entity_stats(&path("e")).unwrap(),
            static_only.entity_stats(&path("e")).unwrap(),
        );
        assert_eq!(
            (kept.num_temporal_chunks, kept.heap_bytes),
            (0, expected.heap_bytes)
        );
        assert_eq!(store.stats().heap_bytes, static_only.stats().heap_bytes);
        store
            .insert(scalars("e", "x", &[(3, 5000, Some(vec![3.0]))]))
            .unwrap();
        store.sanity_check().unwrap();
        assert_eq!(latest(&store, "e", 10), Some(3.0));
    }
}

#[test]
fn protect_latest_keeps_a_recursive_clear_behind_a_newer_flat_one() {
    let mut store = off();
    store.insert(scalar("p/c", "x", 5, 1, 1.0)).unwrap();
    store.insert(clear("p", Some(10), 2, true)).unwrap();
    store.insert(clear("p", Some(20), 3, false)).unwrap();
    assert_eq!(latest(&store, "p/c", 100), None);
    store.gc(&GcOptions::everything().with_protect_latest(1));
    // The recursive Clear is not the latest Clear of `p`, but it is the latest recursive
    // one: dropping it would make the child's value reappear at +∞.
    assert_eq!(latest(&store, "p/c", 100), None);
}

#[test]
fn a_zero_time_budget_still_frees_a_chunk_past_the_protected_ones() {
    let mut store = off();
    ten_by_ten(&mut store, "g");
    // The oldest eight chunks are protected, so the walk skips them before finding one.
    let options = GcOptions::everything()
        .with_protected_time_range("frame", TimeRange::new(t(0), t(79)))
        .with_time_budget(Duration::ZERO);
    let plan = store.plan_gc(&options);
    assert_eq!(
        plan.chunk_ids.len(),
        1,
        "exactly one: then the budget is spent"
    );
    assert!(plan.out_of_time);
    let events = store.apply_gc(&plan);
    assert_eq!(deleted(&events, DeletionReason::Gc).len(), 1);
    // When nothing is collectable, nothing is dropped however long it may take.
    let everything_protected =
        options.with_protected_time_range("frame", TimeRange::new(t(0), t(99)));
    assert!(store.gc(&everything_protected).is_empty());
}

#[test]
fn drop_time_range_rewrites_a_chunk_that_straddles_the_range() {
    let mut store = off();
    ten_by_ten(&mut store, "g");
    let events = store.drop_time_range("frame", TimeRange::new(t(15), t(24)));
    // [10, 19] and [20, 29] each lose half: two deletions, two additions.
    assert_eq!(deleted(&events, DeletionReason::Drop).len(), 2);
    assert_eq!(
        events
            .iter()
            .filter(|e| matches!(e, StoreEvent::Addition(_)))
            .count(),
        2
    );
    let frames: Vec<i64> = range_values(&store, "g").iter().map(|r| r.0).collect();
    assert_eq!(frames, (0..15).chain(25..100).collect::<Vec<_>>());
    assert_eq!(latest(&store, "g", 20), Some(14.0));
    assert!(
        store
            .drop_time_range("frame", TimeRange::new(t(5), t(4)))
            .is_empty(),
        "empty range"
    );
    assert!(
        store
            .drop_time_range("other", TimeRange::new(t(0), t(99)))
            .is_empty()
    );
}

#[test]
fn drop_time_range_removes_rows_from_all_their_timelines() {
    let mut store = off();
    let chunk = Chunk::try_new(
        ChunkId::new(),
        path("two"),
        vec![common::rid(1), common::rid(2)],
        vec![
            (
                Timeline::sequence("frame"),
                Arc::new(Int64Array::from(vec![1, 2])) as ArrayRef,
            ),
            (
                Timeline::sequence("tick"),
                Arc::new(Int64Array::from(vec![100, 200])) as ArrayRef,
            ),
        ],
        vec![(
            "x".into(),
            common::f64_list(&[Some(vec![1.0]), Some(vec![2.0])]),
        )],
    )
    .unwrap();
    store.insert(chunk).unwrap();
    store.drop_time_range("tick", TimeRange::new(t(150), t(250)));
    assert_eq!(range_values(&store, "two"), [(1, 1.0)]);
}

#[test]
fn drop_entity_removes_static_data_clears_and_optionally_descendants() {
    let mut store = off();
    store.insert(scalar("a", "x", 1, 1, 1.0)).unwrap();
    store.insert(static_scalar("a", "y", 2, 2.0)).unwrap();
    store.insert(scalar("a/b", "x", 1, 3, 3.0)).unwrap();
    store.insert(clear("a", Some(5), 4, true)).unwrap();
    assert_eq!(
        latest(&store, "a/b", 9),
        None,
        "hidden by a's recursive Clear"
    );

    let events = store.drop_entity(&path("a"), false);
    assert_eq!(deleted(&events, DeletionReason::Drop).len(), 3);
    assert!(store.entity_stats(&path("a")).is_none());
    // The Clear went with `a`: its child's value is visible again.
    assert_eq!(latest(&store, "a/b", 9), Some(3.0));

    store.insert(scalar("a", "x", 1, 5, 1.0)).unwrap();
    store.drop_entity(&path("a"), true);
    assert_eq!(store.num_chunks(), 0);
    assert_eq!(store.stats().heap_bytes, 0);
}

/// Queries look for an entity's path, and its ancestors', among the bits of a filter of the
/// entities holding Clears before walking the Clears' tree; bits stay set when Clears go
/// and are made again once they outnumber the entities. Whatever came and went, each
/// answer hides exactly what the Clears still held hide.
#[test]
fn clears_of_many_entities_that_come_and_go_hide_what_they_still_hold() {
    let mut store = off();
    let n = 300_u128;
    let mut row_id = 0;
    let mut next = || {
        row_id += 1;
        row_id
    };
    for i in 0..n {
        store
            .insert(scalar(&format!("e{i}/v"), "x", 1, next(), 1.0))
            .unwrap();
        store
            .insert(scalar(&format!("f{i}"), "x", 1, next(), 2.0))
            .unwrap();
        store
            .insert(scalar(&format!("f{i}/v"), "x", 1, next(), 3.0))
            .unwrap();
        store
            .insert(clear(&format!("e{i}"), Some(5), next(), true))
            .unwrap();
        store
            .insert(clear(&format!("f{i}"), Some(5), next(), false))
            .unwrap();
    }
    store.sanity_check().unwrap();
    let check = |store: &ChunkStore, gone: u128| {
        for i in (0..n)
            .step_by(7)
            .chain([gone.saturating_sub(1), gone, n - 1])
        {
            let kept = i >= gone;
            let e = format!("e{i}/v");
            let f = format!("f{i}");
            assert_eq!(latest(store, &e, 5), (!kept).then_some(1.0), "{e}");
            assert_eq!(latest(store, &e, 4), Some(1.0), "{e} before its Clear");
            assert_eq!(latest(store, &f, 5), None, "{f}");
            assert_eq!(latest(store, &f, 4), Some(2.0), "{f} before its Clear");
            // A flat Clear hides nothing below its entity.
            assert_eq!(latest(store, &format!("{f}/v"), 5), Some(3.0), "{f}/v");
        }
    };
    check(&store, 0);
    // Most of the recursive Clears go, one entity at a time (a drop of `e{i}` alone: its
    // value at `e{i}/v` stays), until their stale bits outnumber the entities left.
    for gone in 0..250 {
        store.drop_entity(&path(&format!("e{gone}")), false);
        store.sanity_check().unwrap();
        if gone % 50 == 49 {
            check(&store, gone + 1);
        }
    }
    // A Clear logged again after its entity's went is seen again.
    store.insert(clear("e3", Some(5), next(), true)).unwrap();
    store.sanity_check().unwrap();
    assert_eq!(latest(&store, "e3/v", 5), None);
}

#[test]
fn stats_per_entity_add_up_and_follow_every_mutation() {
    let mut store = off();
    ten_by_ten(&mut store, "g");
    store.insert(static_scalar("h", "x", 1000, 1.0)).unwrap();
    let g = store.entity_stats(&path("g")).unwrap();
    let h = store.entity_stats(&path("h")).unwrap();
    assert_eq!((g.num_temporal_chunks, g.num_temporal_rows), (10, 100));
    assert_eq!((h.num_static_chunks, h.num_static_rows), (1, 1));
    let stats = store.stats();
    assert_eq!(stats.heap_bytes, g.heap_bytes + h.heap_bytes);
    assert_eq!(stats.num_chunks(), 11);
    store.gc(&GcOptions::everything());
    assert!(store.entity_stats(&path("g")).is_none());
    assert_eq!(store.stats().heap_bytes, h.heap_bytes);
}

#[test]
fn subscribers_see_every_mutation_and_clones_start_without_them() {
    let mut store = ChunkStore::new();
    let seen = Arc::new(Mutex::new(Vec::new()));
    let sink = Arc::clone(&seen);
    store.subscribe(move |events| sink.lock().unwrap().push(events.len()));
    store.insert(scalar("a", "x", 1, 1, 1.0)).unwrap();
    store.gc(&GcOptions::everything());
    assert_eq!(*seen.lock().unwrap(), [1, 1]);
    let mut clone = store.clone();
    clone.insert(scalar("a", "x", 2, 2, 2.0)).unwrap();
    assert_eq!(seen.lock().unwrap().len(), 2, "the clone has no subscriber");
    store.gc(&GcOptions::everything());
    assert_eq!(seen.lock().unwrap().len(), 2, "no events, no call");
}

/// Every row of every component of `entity` on `frame`, as `(time, row id, value)`.
fn rows_of(store: &ChunkStore, entity: &str) -> Vec<(i64, u128, f64)> {
    store
        .range(&RangeQuery::everything("frame"), &path(entity), "x")
        .iter()
        .map(|row| {
            (
                row.time().unwrap().as_i64(),
                row.row_id().as_u128(),
                first_f64(&row.cell()),
            )
        })
        .collect()
}

/// Issue 12, item 1: with the default configuration, 20 single-row chunks merge into 5;
/// inserting chunk #0 again used to add its row a second time.
#[test]
fn regression_reinserting_a_chunk_compaction_absorbed_changes_nothing() {
    let chunks: Vec<Arc<Chunk>> = (0..20)
        .map(|i| Arc::new(scalar("e", "x", i, i as u128 + 1, i as f64)))
        .collect();
    let mut store = ChunkStore::new();
    for chunk in &chunks {
        store.insert(Arc::clone(chunk)).unwrap();
    }
    assert_eq!(store.num_chunks(), 5, "16 merged into one, 4 waiting");
    assert!(
        store.chunk(chunks[0].id()).is_none(),
        "chunk #0 was absorbed"
    );
    let (listing, rows) = (store.to_string(), rows_of(&store, "e"));
    assert_eq!(rows.len(), 20);
    for chunk in &chunks {
        // As the very same chunk, and as a copy decoded again from its transport batch.
        let copy = Chunk::from_record_batch(&chunk.to_record_batch().unwrap()).unwrap();
        assert!(store.insert(Arc::clone(chunk)).unwrap().is_empty());
        assert!(store.insert(copy).unwrap().is_empty());
    }
    store.sanity_check().unwrap();
    assert_eq!(store.to_string(), listing);
    assert_eq!(rows_of(&store, "e"), rows);
}

/// A chunk split on insert (it exceeded a threshold) is held as its pieces: inserting it
/// again changes nothing.
#[test]
fn reinserting_a_chunk_that_was_split_changes_nothing() {
    let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..10)
        .map(|i| (i, i as u128 + 1, Some(vec![i as f64])))
        .collect();
    let chunk = Arc::new(scalars("e", "x", &rows));
    let mut store = ChunkStore::with_config(StoreConfig::DEFAULT.with_max_rows(4)).unwrap();
    assert_eq!(store.insert(Arc::clone(&chunk)).unwrap().len(), 3);
    assert!(store.insert(chunk).unwrap().is_empty());
    assert_eq!(rows_of(&store, "e").len(), 10);
    store.sanity_check().unwrap();
}

/// After garbage collection removed a chunk, inserting it again brings it back; after a
/// range drop removed some of its rows, inserting it again brings back exactly those.
#[test]
fn a_removed_chunk_comes_back_and_a_cut_one_gets_back_only_its_dropped_rows() {
    for config in [StoreConfig::COMPACTION_OFF, StoreConfig::DEFAULT] {
        let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..6)
            .map(|i| (i, i as u128 + 1, Some(vec![i as f64])))
            .collect();
        let chunk = Arc::new(scalars("e", "x", &rows));
        let mut store = ChunkStore::with_config(config).unwrap();
        store.insert(Arc::clone(&chunk)).unwrap();
        let all = rows_of(&store, "e");

        store.drop_time_range("frame", TimeRange::new(t(2), t(3)));
        assert_eq!(rows_of(&store, "e").len(), 4);
        let events = store.insert(Arc::clone(&chunk)).unwrap();
        let added: Vec<usize> = events
            .iter()
            .filter_map(|e| match e {
                StoreEvent::Addition(c) => Some(c.num_rows()),
                _ => None,
            })
            .collect();
        assert_eq!(
            added,
            [2],
            "{config:?}: only the two dropped rows come back"
        );
        assert_eq!(rows_of(&store, "e"), all, "{config:?}");

        store.gc(&GcOptions::everything());
        assert!(rows_of(&store, "e").is_empty());
        assert!(!store.insert(Arc::clone(&chunk)).unwrap().is_empty());
        assert_eq!(rows_of(&store, "e"), all, "{config:?}");
        store.sanity_check().unwrap();
    }
}

/// Rows equal to held ones are held whatever chunk carried them: a re-chunked copy of a
/// recording adds nothing, and rows that differ in any cell or time are new.
#[test]
fn rows_equal_to_held_rows_are_not_stored_twice_whatever_their_chunk() {
    let mut store = off();
    store
        .insert(scalars(
            "e",
            "x",
            &[(1, 1, Some(vec![1.0])), (2, 2, Some(vec![2.0]))],
        ))
        .unwrap();
    // The same rows, one per chunk, under new chunk ids.
    assert!(
        store
            .insert(scalar("e", "x", 2, 2, 2.0))
            .unwrap()
            .is_empty()
    );
    assert!(
        store
            .insert(scalar("e", "x", 1, 1, 1.0))
            .unwrap()
            .is_empty()
    );
    // A reused row id with another value, another time, or at another entity: new rows.
    for chunk in [
        scalar("e", "x", 2, 2, 5.0),
        scalar("e", "x", 3, 2, 2.0),
        scalar("f", "x", 2, 2, 2.0),
    ] {
        assert_eq!(store.insert(chunk).unwrap().len(), 1);
    }
    assert_eq!(rows_of(&store, "e").len(), 4);
    store.sanity_check().unwrap();
}

/// Issue 12, item 2: a chunk under an id the store holds, with other contents, used to be
/// dropped silently; it is refused, naming both entities and the id.
#[test]
fn a_reused_chunk_id_with_other_contents_is_refused() {
    let held = scalar("e", "x", 1, 1, 1.0);
    let id = held.id();
    let mut store = ChunkStore::new();
    store.insert(held).unwrap();
    let listing = store.to_string();
    let other = Chunk::try_new(
        id,
        path("f"),
        vec![common::rid(2)],
        vec![(
            Timeline::sequence("frame"),
            Arc::new(Int64Array::from(vec![1])) as ArrayRef,
        )],
        vec![("x".into(), common::f64_list(&[Some(vec![1.0])]))],
    )
    .unwrap();
    let error = store.insert(other).unwrap_err();
    assert!(
        matches!(
            &error,
            chunkstore::InsertError::ChunkIdConflict { chunk_id, held_entity, incoming_entity }
                if *chunk_id == id && *held_entity == path("e") && *incoming_entity == path("f")
        ),
        "{error:?}"
    );
    let message = error.to_string();
    assert!(message.contains(&id.to_string()) && message.contains("/e") && message.contains("/f"));
    assert_eq!(store.to_string(), listing, "the store is unchanged");
}

/// Issue 12, item 5: fractions that cannot be met or mean nothing are refused where the
/// options are made.
#[test]
fn gc_fractions_outside_zero_one_are_refused() {
    for bad in [f64::NAN, 0.0, -0.5, 1.5, f64::INFINITY, f64::NEG_INFINITY] {
        assert!(
            matches!(
                GcTarget::drop_at_least_fraction(bad),
                Err(chunkstore::GcOptionsError::FractionOutOfRange { .. })
            ),
            "{bad}"
        );
        assert!(GcOptions::drop_at_least_fraction(bad).is_err(), "{bad}");
        assert!(chunkstore::GcFraction::try_from(bad).is_err(), "{bad}");
    }
    for good in [1e-9, 0.5, 1.0] {
        assert_eq!(
            chunkstore::GcFraction::new(good).unwrap().get(),
            good,
            "{good}"
        );
    }
}

/// `time_range` spans the data held on a timeline, whether compaction keeps chunks waiting
/// or not, and follows removals; `timelines` keeps listing a timeline once seen.
#[test]
fn time_range_spans_the_data_held_and_follows_removals() {
    for config in [StoreConfig::COMPACTION_OFF, StoreConfig::DEFAULT] {
        let mut store = ChunkStore::with_config(config).unwrap();
        assert_eq!(store.time_range("frame"), None);
        for frame in (5..=20).rev() {
            store
                .insert(scalar("e", "x", frame, 100 - frame as u128, 1.0))
                .unwrap();
        }
        store.insert(static_scalar("s", "x", 1, 1.0)).unwrap();
        assert_eq!(
            store.time_range("frame"),
            Some(TimeRange::new(t(5), t(20))),
            "{config:?}"
        );
        assert_eq!(store.time_range("other"), None);
        store.drop_time_range("frame", TimeRange::new(t(15), t(30)));
        assert_eq!(
            store.time_range("frame"),
            Some(TimeRange::new(t(5), t(14))),
            "{config:?}"
        );
        store.drop_time_range("frame", TimeRange::new(t(0), t(100)));
        assert_eq!(store.time_range("frame"), None, "{config:?}");
        let names: Vec<String> = store
            .timelines()
            .iter()
            .map(|t| t.name().to_owned())
            .collect();
        assert_eq!(names, ["frame"]);
    }
}

/// Found by the `chunk_build` fuzz target: a static chunk whose cells are all null wins
/// nothing and leaves the store at once, but its component stayed known, with its type,
/// until compaction happened to rewrite every chunk of the entity. What the store lists and
/// accepts now depends only on the chunks it holds.
#[test]
fn regression_a_component_is_forgotten_with_the_last_chunk_holding_it() {
    for config in [StoreConfig::COMPACTION_OFF, StoreConfig::DEFAULT] {
        let mut store = ChunkStore::with_config(config).unwrap();
        store.insert(scalar("e", "x", 1, 1, 1.0)).unwrap();
        let all_null = Chunk::try_new(
            ChunkId::new(),
            path("e"),
            vec![common::rid(2)],
            vec![],
            vec![("y".into(), common::f64_list(&[None]))],
        )
        .unwrap();
        let events = store.insert(all_null).unwrap();
        assert_eq!(deleted(&events, DeletionReason::Overwrite).len(), 1);
        let names = |store: &ChunkStore| -> Vec<String> {
            store
                .component_names(&path("e"))
                .iter()
                .map(ToString::to_string)
                .collect()
        };
        assert_eq!(names(&store), ["x"], "{config:?}");
        assert_eq!(store.element_type(&path("e"), "y"), None);
        store.compact();
        assert_eq!(names(&store), ["x"], "{config:?}");
        // No chunk of `e` has a `y` column: a `y` of another type is welcome.
        let strings: ArrayRef = {
            let mut list =
                arrow_array::builder::ListBuilder::new(arrow_array::builder::StringBuilder::new());
            list.values().append_value("text");
            list.append(true);
            Arc::new(list.finish())
        };
        let text = Chunk::try_new(
            ChunkId::new(),
            path("e"),
            vec![common::rid(3)],
            vec![(
                Timeline::sequence("frame"),
                Arc::new(Int64Array::from(vec![2])) as ArrayRef,
            )],
            vec![("y".into(), strings)],
        )
        .unwrap();
        store.insert(text).unwrap();
        assert_eq!(names(&store), ["x", "y"], "{config:?}");
        store.sanity_check().unwrap();
    }
}

/// Found by the extended model test: with rows of different sizes and a byte threshold near
/// a row's size, `compact()` cut pieces of equal row counts, some above the threshold, and
/// then found its own output oversized and rewrote it on every call. It now leaves alone a
/// group that is exactly what one of its rewrites made.
#[test]
fn regression_compact_leaves_its_own_output_alone_when_rows_differ_in_size() {
    use arrow_array::builder::{ListBuilder, StringBuilder};
    let strings = |cells: &[Option<Vec<&str>>]| {
        let mut list = ListBuilder::new(StringBuilder::new());
        for cell in cells {
            for value in cell.iter().flatten() {
                list.values().append_value(value);
            }
            list.append(cell.is_some());
        }
        Arc::new(list.finish()) as ArrayRef
    };
    let chunk = |row_ids: [u128; 5], times: [i64; 5], cells: &[Option<Vec<&str>>]| {
        Chunk::try_new(
            ChunkId::new(),
            path("a"),
            row_ids.into_iter().map(common::rid).collect(),
            vec![(
                Timeline::sequence("frame"),
                Arc::new(Int64Array::from(times.to_vec())) as ArrayRef,
            )],
            vec![("s".into(), strings(cells))],
        )
        .unwrap()
    };
    for max_bytes in (40..300).step_by(7) {
        let mut store = ChunkStore::with_config(
            StoreConfig::COMPACTION_OFF
                .with_max_rows(4)
                .with_max_rows_unsorted(3)
                .with_max_bytes(max_bytes)
                .with_merge_fanout(2),
        )
        .unwrap();
        let long = Some(vec!["a long string value", "and another one"]);
        store
            .insert(chunk(
                [1, 2, 3, 4, 5],
                [0, 0, 0, 3, 0],
                &[long.clone(), None, long, None, Some(vec!["x"])],
            ))
            .unwrap();
        store
            .insert(chunk(
                [6, 7, 8, 9, 10],
                [1, 1, 2, 2, 2],
                &[None, Some(vec![]), None, None, None],
            ))
            .unwrap();
        let values = range_values_s(&store);
        assert!(
            !store.compact().is_empty(),
            "max_bytes {max_bytes}: the first pass rewrites"
        );
        let again = store.compact();
        assert!(
            again.is_empty(),
            "max_bytes {max_bytes}: a second pass rewrote {again:?}"
        );
        assert_eq!(range_values_s(&store), values);
        store.sanity_check().unwrap();
    }
}

/// `(time, row id)` of every row of `s` at `a`.
fn range_values_s(store: &ChunkStore) -> Vec<(i64, u128)> {
    store
        .range(&RangeQuery::everything("frame"), &path("a"), "s")
        .iter()
        .map(|row| (row.time().unwrap().as_i64(), row.row_id().as_u128()))
        .collect()
}
