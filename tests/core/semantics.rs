//! One example test per rule of SEMANTICS.md sections 2 to 5.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::float_cmp,
    clippy::cast_precision_loss,
    clippy::cast_sign_loss,
    reason = "tests fail loudly on unexpected values; test values are small non-negative integers, exact in f64"
)]

use crate::common;

use chunkstore::{ChunkStore, LatestAtQuery, RangeQuery, TimeRange};
use common::*;

fn store_with(chunks: impl IntoIterator<Item = chunkstore::Chunk>) -> ChunkStore {
    let mut store = ChunkStore::new();
    for chunk in chunks {
        store.insert(chunk).unwrap();
        store.sanity_check().unwrap();
    }
    store
}

fn at(time: i64) -> LatestAtQuery {
    LatestAtQuery::new("frame", t(time))
}

/// `(time, value)` of a latest-at answer.
fn latest(
    store: &ChunkStore,
    entity: &str,
    component: &str,
    time: i64,
) -> Option<(Option<i64>, f64)> {
    store
        .latest_at(&at(time), &path(entity), component)
        .map(|a| {
            (
                a.time().map(chunkstore::TimeInt::as_i64),
                first_f64(&a.cell()),
            )
        })
}

fn range(
    store: &ChunkStore,
    entity: &str,
    component: &str,
    min: i64,
    max: i64,
) -> Vec<(i64, u128, f64)> {
    store
        .range(
            &RangeQuery::new("frame", TimeRange::new(t(min), t(max))),
            &path(entity),
            component,
        )
        .iter()
        .map(|r| {
            (
                r.time().unwrap().as_i64(),
                r.row_id().as_u128(),
                first_f64(&r.cell()),
            )
        })
        .collect()
}

// --- Section 2: chunks ---

#[test]
fn unsorted_rows_are_answered_correctly() {
    let chunk = scalars(
        "e",
        "c",
        &[
            (5, 3, Some(vec![5.0])),
            (1, 1, Some(vec![1.0])),
            (3, 2, Some(vec![3.0])),
        ],
    );
    assert!(
        !chunk.time_column("frame").unwrap().is_sorted(),
        "the chunk records it is unsorted"
    );
    let store = store_with([chunk]);
    assert_eq!(latest(&store, "e", "c", 4), Some((Some(3), 3.0)));
    assert_eq!(latest(&store, "e", "c", 0), None);
    assert_eq!(
        range(&store, "e", "c", 0, 10),
        [(1, 1, 1.0), (3, 2, 3.0), (5, 3, 5.0)]
    );
}

#[test]
fn null_cells_are_invisible_to_queries() {
    let store = store_with([scalars("e", "c", &[(1, 1, Some(vec![1.0])), (2, 2, None)])]);
    assert_eq!(
        latest(&store, "e", "c", 2),
        Some((Some(1), 1.0)),
        "the null at 2 is skipped"
    );
    assert_eq!(range(&store, "e", "c", 0, 5).len(), 1);
}

#[test]
fn empty_list_is_a_real_answer_that_shadows_older_data() {
    let store = store_with([scalars(
        "e",
        "c",
        &[(1, 1, Some(vec![1.0])), (2, 2, Some(vec![]))],
    )]);
    let answer = store.latest_at(&at(3), &path("e"), "c").unwrap();
    assert_eq!(cell_len(&answer.cell()), 0);
    assert_eq!(answer.time(), Some(t(2)));
}

#[test]
fn a_chunk_without_time_columns_is_static() {
    let chunk = static_scalar("e", "c", 1, 1.0);
    assert!(chunk.is_static());
    assert!(!scalar("e", "c", 1, 1, 1.0).is_static());
}

// --- Section 3: latest-at ---

#[test]
fn static_shadows_temporal_on_every_timeline_at_every_time() {
    let store = store_with([
        scalar("e", "c", 10, 5, 10.0),
        static_scalar("e", "c", 1, 99.0),
    ]);
    for time in [-100, 0, 10, 1000] {
        assert_eq!(latest(&store, "e", "c", time), Some((None, 99.0)));
    }
    let other = store
        .latest_at(&LatestAtQuery::new("never_used", t(0)), &path("e"), "c")
        .unwrap();
    assert!(
        other.is_static(),
        "a timeline the entity never used still sees static data"
    );
}

#[test]
fn static_winner_is_the_greatest_row_id_whatever_the_insert_order() {
    for order in [[1u128, 2], [2, 1]] {
        let chunks = order.map(|r| static_scalar("e", "c", r, r as f64));
        let store = store_with(chunks);
        assert_eq!(latest(&store, "e", "c", 0), Some((None, 2.0)));
        assert_eq!(
            store.num_chunks(),
            1,
            "the shadowed static chunk is dropped as overwritten"
        );
    }
}

#[test]
fn latest_at_takes_greatest_time_then_greatest_row_id() {
    let store = store_with([
        scalars(
            "e",
            "c",
            &[(5, 10, Some(vec![1.0])), (5, 30, Some(vec![3.0]))],
        ),
        scalar("e", "c", 5, 20, 2.0),
        scalar("e", "c", 6, 1, 6.0),
    ]);
    assert_eq!(latest(&store, "e", "c", 5), Some((Some(5), 3.0)));
    assert_eq!(
        latest(&store, "e", "c", 6),
        Some((Some(6), 6.0)),
        "time beats row id"
    );
    assert_eq!(latest(&store, "e", "c", 4), None, "nothing at or before 4");
}

/// A chunk of `e` holding one `c` cell at `frame = 5` with row id 7, and with `more`, a
/// second timeline, so that it never merges with the other layout on insert.
fn tied(value: f64, more: bool) -> chunkstore::Chunk {
    use std::sync::Arc;
    let frame = || Arc::new(arrow_array::Int64Array::from(vec![5])) as arrow_array::ArrayRef;
    let mut times = vec![(chunkstore::Timeline::sequence("frame"), frame())];
    if more {
        times.push((chunkstore::Timeline::sequence("other"), frame()));
    }
    chunkstore::Chunk::try_new(
        chunkstore::ChunkId::new(),
        path("e"),
        vec![rid(7)],
        times,
        vec![("c".into(), f64_list(&[Some(vec![value])]))],
    )
    .unwrap()
}

#[test]
fn rows_that_tie_on_their_index_answer_from_the_greater_chunk_id() {
    use chunkstore::{GcOptions, StoreConfig};
    for config in [StoreConfig::DEFAULT, StoreConfig::COMPACTION_OFF] {
        for older_first in [true, false] {
            for filler in [0, 40] {
                // `newer` has the greater chunk id; insert order, the write buffer and the
                // index's shape (40 more chunks make it large) must not change the answer.
                let older = tied(1.0, true);
                let newer = tied(2.0, false);
                let mut store = ChunkStore::with_config(config).unwrap();
                for i in 0..filler {
                    store
                        .insert(scalar("e", "c", i - 100, 1000 + i as u128, 0.0))
                        .unwrap();
                }
                let (first, second) = if older_first {
                    (older, newer)
                } else {
                    (newer, older)
                };
                store.insert(first).unwrap();
                store.insert(second).unwrap();
                store.sanity_check().unwrap();
                let case = format!("{config:?}, older first: {older_first}, filler: {filler}");
                assert_eq!(latest(&store, "e", "c", 5), Some((Some(5), 2.0)), "{case}");
                assert_eq!(
                    latest(&store, "e", "c", i64::MAX),
                    Some((Some(5), 2.0)),
                    "{case}"
                );
                // Section 7: protecting the latest chunk keeps this answer.
                store.gc(&GcOptions::everything().with_protect_latest(1));
                store.sanity_check().unwrap();
                assert_eq!(
                    latest(&store, "e", "c", i64::MAX),
                    Some((Some(5), 2.0)),
                    "{case}"
                );
            }
        }
    }
}

#[test]
fn latest_at_with_overlapping_and_out_of_order_chunks() {
    // A long chunk spanning 0..=1000, short chunks inside it, inserted in any order.
    let long = scalars(
        "e",
        "c",
        &[
            (0, 1, Some(vec![0.0])),
            (500, 2, Some(vec![500.0])),
            (1000, 3, Some(vec![1000.0])),
        ],
    );
    let short = (0..20).map(|i| {
        scalar(
            "e",
            "c",
            100 + i * 30,
            100 + i as u128,
            (100 + i * 30) as f64,
        )
    });
    let store = store_with(short.rev().chain([long]));
    assert_eq!(latest(&store, "e", "c", 99), Some((Some(0), 0.0)));
    assert_eq!(latest(&store, "e", "c", 499), Some((Some(490), 490.0)));
    assert_eq!(
        latest(&store, "e", "c", 500),
        Some((Some(500), 500.0)),
        "the long chunk's inner row"
    );
    assert_eq!(latest(&store, "e", "c", 999), Some((Some(670), 670.0)));
    assert_eq!(
        latest(&store, "e", "c", i64::MAX),
        Some((Some(1000), 1000.0))
    );
}

#[test]
fn answer_says_which_chunk_and_row_it_came_from() {
    let chunk = scalars(
        "e",
        "c",
        &[(1, 1, Some(vec![1.0])), (2, 2, Some(vec![2.0]))],
    );
    let id = chunk.id();
    let store = store_with([chunk]);
    let answer = store.latest_at(&at(1), &path("e"), "c").unwrap();
    assert_eq!(
        (answer.chunk_id(), answer.row(), answer.row_id()),
        (id, 0, rid(1))
    );
}

// --- Section 4: range ---

#[test]
fn range_of_static_data_is_exactly_the_static_winner() {
    let store = store_with([scalar("e", "c", 1, 1, 1.0), static_scalar("e", "c", 2, 7.0)]);
    let result = store.range(
        &RangeQuery::new("frame", TimeRange::new(t(100), t(200))),
        &path("e"),
        "c",
    );
    let rows: Vec<_> = result.iter().collect();
    assert_eq!(rows.len(), 1);
    assert!(rows[0].time().is_none());
    assert_eq!(first_f64(&rows[0].cell()), 7.0);
}

#[test]
fn range_is_in_global_time_row_id_order_across_overlapping_chunks() {
    let store = store_with([
        scalars(
            "e",
            "c",
            &[
                (1, 1, Some(vec![1.0])),
                (3, 3, Some(vec![3.0])),
                (5, 5, Some(vec![5.0])),
            ],
        ),
        scalars(
            "e",
            "c",
            &[
                (2, 2, Some(vec![2.0])),
                (4, 4, Some(vec![4.0])),
                (3, 1, Some(vec![3.5])),
            ],
        ),
        scalar("e", "c", 9, 9, 9.0),
    ]);
    let rows = range(&store, "e", "c", 2, 9);
    let keys: Vec<(i64, u128)> = rows.iter().map(|r| (r.0, r.1)).collect();
    assert_eq!(keys, [(2, 2), (3, 1), (3, 3), (4, 4), (5, 5), (9, 9)]);
}

#[test]
fn range_bounds_are_inclusive_and_empty_ranges_are_empty() {
    let store = store_with([scalars(
        "e",
        "c",
        &[
            (1, 1, Some(vec![1.0])),
            (2, 2, Some(vec![2.0])),
            (3, 3, Some(vec![3.0])),
        ],
    )]);
    assert_eq!(range(&store, "e", "c", 2, 3).len(), 2);
    assert_eq!(range(&store, "e", "c", 4, 10).len(), 0);
    assert_eq!(range(&store, "e", "c", 3, 2).len(), 0, "min > max is empty");
}

#[test]
fn clears_do_not_filter_ranges() {
    let store = store_with([scalar("e", "c", 1, 1, 1.0), clear("e", Some(2), 2, true)]);
    assert_eq!(range(&store, "e", "c", 0, 10).len(), 1);
    assert_eq!(latest(&store, "e", "c", 10), None);
}

// --- Section 5: Clear ---

#[test]
fn flat_clear_hides_its_own_entity_but_not_children() {
    let store = store_with([
        scalar("a", "c", 1, 1, 1.0),
        scalar("a/b", "c", 1, 2, 2.0),
        clear("a", Some(5), 3, false),
    ]);
    assert_eq!(
        latest(&store, "a", "c", 4),
        Some((Some(1), 1.0)),
        "not visible yet at 4"
    );
    assert_eq!(latest(&store, "a", "c", 5), None);
    assert_eq!(latest(&store, "a/b", "c", 5), Some((Some(1), 2.0)));
}

#[test]
fn recursive_clear_hides_the_whole_subtree() {
    let store = store_with([
        scalar("a/b/c", "x", 1, 1, 1.0),
        scalar("other", "x", 1, 2, 2.0),
        clear("a", Some(5), 3, true),
    ]);
    assert_eq!(latest(&store, "a/b/c", "x", 5), None);
    assert_eq!(latest(&store, "other", "x", 5), Some((Some(1), 2.0)));
}

#[test]
fn recursive_clear_at_the_root_hides_everything() {
    let store = store_with([scalar("a/b", "x", 1, 1, 1.0), clear("/", Some(2), 2, true)]);
    assert_eq!(latest(&store, "a/b", "x", 2), None);
}

#[test]
fn clear_compares_full_indices_and_data_logged_after_is_visible_again() {
    // Clear at (5, row 10): data at (5, row 9) is hidden, (5, row 11) is not.
    let store = store_with([scalar("e", "c", 5, 9, 1.0), clear("e", Some(5), 10, false)]);
    assert_eq!(latest(&store, "e", "c", 5), None);
    let mut store = store;
    store.insert(scalar("e", "c", 5, 11, 2.0)).unwrap();
    assert_eq!(latest(&store, "e", "c", 5), Some((Some(5), 2.0)));
    store.insert(scalar("e", "c", 7, 12, 3.0)).unwrap();
    assert_eq!(latest(&store, "e", "c", 7), Some((Some(7), 3.0)));
}

#[test]
fn a_hidden_cell_does_not_fall_back_to_older_data() {
    let store = store_with([
        scalar("e", "c", 1, 1, 1.0),
        scalar("e", "c", 3, 3, 3.0),
        clear("e", Some(4), 4, false),
    ]);
    assert_eq!(
        latest(&store, "e", "c", 4),
        None,
        "neither the cell at 3 nor the one at 1"
    );
}

#[test]
fn clears_hide_per_component() {
    let store = store_with([
        scalar("e", "old", 1, 1, 1.0),
        clear("e", Some(2), 2, false),
        scalar("e", "new", 3, 3, 3.0),
    ]);
    assert_eq!(latest(&store, "e", "old", 5), None);
    assert_eq!(latest(&store, "e", "new", 5), Some((Some(3), 3.0)));
}

#[test]
fn static_clear_hides_all_temporal_data_and_older_static_data() {
    let store = store_with([
        scalar("e", "temporal", 100, 50, 1.0),
        static_scalar("e", "old_static", 1, 1.0),
        clear("e", None, 10, false),
        static_scalar("e", "new_static", 20, 2.0),
    ]);
    assert_eq!(
        latest(&store, "e", "temporal", 1000),
        None,
        "even temporal data with a greater row id"
    );
    assert_eq!(latest(&store, "e", "old_static", 0), None);
    assert_eq!(latest(&store, "e", "new_static", 0), Some((None, 2.0)));
}

#[test]
fn temporal_clear_never_hides_static_data() {
    let store = store_with([
        static_scalar("e", "c", 1, 1.0),
        clear("e", Some(5), 10, true),
    ]);
    assert_eq!(latest(&store, "e", "c", 100), Some((None, 1.0)));
}

#[test]
fn every_recursive_clear_counts_even_after_a_later_flat_clear() {
    // Differs from the reference: a later flat Clear on the ancestor brings nothing back.
    let store = store_with([
        scalar("a/b", "c", 1, 1, 1.0),
        clear("a", Some(2), 2, true),
        clear("a", Some(3), 3, false),
    ]);
    assert_eq!(latest(&store, "a/b", "c", 10), None);
}

#[test]
fn a_clear_is_only_visible_on_its_own_timelines() {
    let mut store = store_with([scalar("e", "c", 1, 1, 1.0)]);
    store.insert(clear("e", Some(2), 2, false)).unwrap();
    let other = chunkstore::Chunk::try_new(
        chunkstore::ChunkId::new(),
        path("e"),
        vec![rid(3)],
        vec![(
            chunkstore::Timeline::sequence("other"),
            std::sync::Arc::new(arrow_array::Int64Array::from(vec![0])) as arrow_array::ArrayRef,
        )],
        vec![("c".into(), f64_list(&[Some(vec![3.0])]))],
    )
    .unwrap();
    store.insert(other).unwrap();
    let on_other = store.latest_at(&LatestAtQuery::new("other", t(0)), &path("e"), "c");
    assert!(
        on_other.is_some(),
        "the Clear on `frame` is not visible on `other`"
    );
}

#[test]
fn clear_cells_themselves_are_never_hidden() {
    let store = store_with([clear("e", Some(2), 2, true)]);
    let answer = store.latest_at(
        &at(5),
        &path("e"),
        chunkstore::ComponentName::CLEAR_IS_RECURSIVE,
    );
    assert!(answer.is_some());
}
