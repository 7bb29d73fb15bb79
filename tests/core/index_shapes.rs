//! The temporal index changes shape with its contents: a small sorted vector, an in-order
//! sequence of chunks that do not overlap, or three ordered views. Every shape, and every
//! change from one to another (on insert, GC from either end, drops in the middle), must
//! answer like a brute-force scan of the rows the store holds.

#![allow(
    clippy::unwrap_used,
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_precision_loss,
    clippy::float_cmp,
    reason = "test code: small, non-negative test values, exact in f64"
)]

use crate::common;

use chunkstore::{
    ChunkStore, GcOptions, GcOrder, GcTarget, LatestAtQuery, RangeQuery, StoreConfig, TimeRange,
};
use common::{first_f64, path, scalars, t};

const ENTITY: &str = "e";
const COMPONENT: &str = "x";

/// Builds chunks with increasing row ids.
struct Rows(u128);

impl Rows {
    /// A chunk of `(time, cell)` rows; a `None` cell is null.
    fn chunk(&mut self, rows: &[(i64, Option<f64>)]) -> chunkstore::Chunk {
        let rows: Vec<_> = rows
            .iter()
            .map(|&(time, value)| {
                self.0 += 1;
                (time, self.0, value.map(|v| vec![v]))
            })
            .collect();
        scalars(ENTITY, COMPONENT, &rows)
    }
}

/// Every non-null `(time, row id)` the store holds for the component, sorted.
fn rows_held(store: &ChunkStore) -> Vec<(i64, u128)> {
    let mut rows = Vec::new();
    for chunk in store.chunks_unordered() {
        let times = chunk.time_column("frame").unwrap().times();
        let column = chunk.component(COMPONENT).unwrap();
        for (row, (&time, row_id)) in times.iter().zip(chunk.row_ids()).enumerate() {
            if column.is_valid(row) {
                rows.push((time, row_id.as_u128()));
            }
        }
    }
    rows.sort_unstable();
    rows
}

/// Latest-at at every time around the data, and ranges of several widths, against a scan.
fn check(store: &ChunkStore) {
    store.sanity_check().unwrap();
    let rows = rows_held(store);
    let (Some(&(first, _)), Some(&(last, _))) = (rows.first(), rows.last()) else {
        return;
    };
    let entity = path(ENTITY);
    for at in first - 2..=last + 2 {
        let expected = rows.iter().rev().find(|&&(time, _)| time <= at).copied();
        let answer = store.latest_at(&LatestAtQuery::new("frame", t(at)), &entity, COMPONENT);
        let answer = answer.map(|a| (a.time().unwrap().as_i64(), a.row_id().as_u128()));
        assert_eq!(answer, expected, "latest-at at {at}");
        if let Some(answer) =
            store.latest_at(&LatestAtQuery::new("frame", t(at)), &entity, COMPONENT)
        {
            // Values are the time: the cell is the one of that row.
            assert_eq!(
                first_f64(&answer.cell()),
                answer.time().unwrap().as_i64() as f64
            );
        }
    }
    for width in [0, 3, 40] {
        for min in (first - 5..=last + 5).step_by(7) {
            let max = min + width;
            let expected: Vec<_> = rows
                .iter()
                .filter(|&&(time, _)| (min..=max).contains(&time))
                .copied()
                .collect();
            let result = store.range(
                &RangeQuery::new("frame", TimeRange::new(t(min), t(max))),
                &entity,
                COMPONENT,
            );
            let answer: Vec<_> = result
                .iter()
                .map(|r| (r.time().unwrap().as_i64(), r.row_id().as_u128()))
                .collect();
            assert_eq!(answer, expected, "range [{min}, {max}]");
        }
    }
}

fn store() -> ChunkStore {
    ChunkStore::with_config(StoreConfig::COMPACTION_OFF).unwrap()
}

/// Drops at least one chunk, in `order`; returns how many went.
fn collect_one(store: &mut ChunkStore, order: GcOrder) -> usize {
    let before = store.num_chunks();
    store.gc(&GcOptions::everything()
        .with_target(GcTarget::DropAtLeastBytes(1))
        .with_order(order));
    before - store.num_chunks()
}

#[test]
fn an_in_order_sequence_grows_at_both_ends_then_an_overlap_makes_it_general() {
    let mut rows = Rows(0);
    let mut store = store();
    // 60 chunks at 10k, 10k + 1, 10k + 2 (the middle cell null in every third chunk).
    for k in 1..=60 {
        let base = k * 10;
        let middle = (k % 3 != 0).then_some((base + 1) as f64);
        store
            .insert(rows.chunk(&[
                (base, Some(base as f64)),
                (base + 1, middle),
                (base + 2, Some((base + 2) as f64)),
            ]))
            .unwrap();
        if k % 10 == 0 || k == 17 {
            check(&store);
        }
    }
    // Older data arriving later, each chunk before all others.
    for k in (1..=5).rev() {
        store
            .insert(rows.chunk(&[(-k * 10, Some((-k * 10) as f64))]))
            .unwrap();
    }
    check(&store);
    // One chunk reaching across many: the index keeps every view from now on.
    store
        .insert(rows.chunk(&[(105, Some(105.0)), (333, Some(333.0))]))
        .unwrap();
    check(&store);
    // Collected oldest first down to a handful, checked on the way.
    while store.num_chunks() > 3 {
        assert!(collect_one(&mut store, GcOrder::OldestRowIdsFirst) > 0);
        if store.num_chunks().is_multiple_of(7) {
            check(&store);
        }
    }
    check(&store);
}

#[test]
fn a_sequence_collected_from_both_ends_around_a_cursor() {
    let mut rows = Rows(0);
    let mut store = store();
    for k in 0..100 {
        store
            .insert(rows.chunk(&[
                (k * 4, Some((k * 4) as f64)),
                (k * 4 + 2, Some((k * 4 + 2) as f64)),
            ]))
            .unwrap();
    }
    check(&store);
    let cursor = GcOrder::FurthestFrom {
        timeline: "frame".into(),
        time: t(200),
    };
    while store.num_chunks() > 2 {
        assert!(collect_one(&mut store, cursor.clone()) > 0);
        if store.num_chunks().is_multiple_of(9) {
            check(&store);
        }
    }
    check(&store);
}

#[test]
fn a_drop_in_the_middle_of_a_long_sequence() {
    let mut rows = Rows(0);
    let mut store = store();
    for k in 0..300 {
        store
            .insert(rows.chunk(&[(k * 3, Some((k * 3) as f64))]))
            .unwrap();
    }
    check(&store);
    store.drop_time_range("frame", TimeRange::new(t(450), t(452)));
    check(&store);
    store.drop_time_range("frame", TimeRange::new(t(3), t(5)));
    check(&store);
    store.drop_time_range("frame", TimeRange::new(t(0), t(600)));
    check(&store);
}

#[test]
fn chunks_that_touch_or_arrive_out_of_order_are_not_a_sequence() {
    // Each chunk starts where the previous one ends: a shared time, so no sequence.
    let mut rows = Rows(0);
    let mut store = store();
    for k in 0..40 {
        store
            .insert(rows.chunk(&[
                (k * 2, Some((k * 2) as f64)),
                (k * 2 + 2, Some((k * 2 + 2) as f64)),
            ]))
            .unwrap();
    }
    check(&store);
    // Shuffled arrival.
    let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).unwrap();
    for k in (0..50).map(|k| (k * 37) % 50) {
        store
            .insert(rows.chunk(&[(k * 5, Some((k * 5) as f64))]))
            .unwrap();
    }
    check(&store);
    while store.num_chunks() > 1 {
        collect_one(&mut store, GcOrder::OldestRowIdsFirst);
    }
    check(&store);
}

/// Latest-at answers of `view` at every time in `times`, as `(time, row id)`.
fn answers(
    view: &chunkstore::StoreView,
    times: std::ops::RangeInclusive<i64>,
) -> Vec<Option<(i64, u128)>> {
    let entity = path(ENTITY);
    times
        .map(|at| {
            view.latest_at(&LatestAtQuery::new("frame", t(at)), &entity, COMPONENT)
                .map(|a| (a.time().unwrap().as_i64(), a.row_id().as_u128()))
        })
        .collect()
}

#[test]
fn many_chunks_of_one_index_leave_at_once_from_every_shape() {
    // Every index shape (a small vector, an in-order sequence, the three views), losing a
    // part, most or all of its chunks in one collection or one drop: the removals are made
    // together (the survivors indexed afresh where most go), and must answer as a scan
    // does, while a snapshot taken before still answers as it did.
    type Shape = fn(i64) -> Vec<(i64, Option<f64>)>;
    let shapes: [(&str, i64, Shape); 3] = [
        ("small", 24, |k| vec![(k * 10, Some((k * 10) as f64))]),
        ("sequence", 120, |k| {
            vec![(k * 10, Some((k * 10) as f64)), (k * 10 + 5, None)]
        }),
        // Each chunk reaches past the next one's start: the three views.
        ("views", 120, |k| {
            vec![
                (k * 10, Some((k * 10) as f64)),
                (k * 10 + 25, Some((k * 10 + 25) as f64)),
            ]
        }),
    ];
    for (shape, num_chunks, rows_of) in shapes {
        for fraction in [0.3, 0.6, 1.0] {
            for by_drop in [false, true] {
                let mut rows = Rows(0);
                let mut store = store();
                // Out of time order for the views (odd chunks first), so none is a
                // sequence by accident.
                let order: Vec<i64> = if shape == "views" {
                    (0..num_chunks)
                        .filter(|k| k % 2 == 1)
                        .chain((0..num_chunks).filter(|k| k % 2 == 0))
                        .collect()
                } else {
                    (0..num_chunks).collect()
                };
                for k in order {
                    store.insert(rows.chunk(&rows_of(k))).unwrap();
                }
                check(&store);
                let span = -5..=num_chunks * 10 + 30;
                let snapshot = store.snapshot();
                let before = answers(&snapshot, span.clone());
                let held = store.num_chunks();
                if by_drop {
                    let last = (num_chunks as f64 * 10.0 * fraction) as i64;
                    store.drop_time_range("frame", TimeRange::new(t(0), t(last)));
                } else {
                    store.gc(&GcOptions::everything()
                        .with_target(GcTarget::drop_at_least_fraction(fraction).unwrap()));
                }
                let what = format!(
                    "{shape}, {fraction} by {}",
                    if by_drop { "drop" } else { "gc" }
                );
                assert!(store.num_chunks() < held, "{what}: something left");
                check(&store);
                assert_eq!(
                    answers(&snapshot, span),
                    before,
                    "{what}: the snapshot changed"
                );
                // The index keeps growing and answering after its rebuild.
                for k in 0..40 {
                    store
                        .insert(rows.chunk(&rows_of(num_chunks + (k * 7) % 40)))
                        .unwrap();
                }
                check(&store);
            }
        }
    }
}
