//! How fast could any store be on the two query workloads of
//! `../shared/bench/WORKLOADS.md` whose answers are large: `latest_at_batch` (1,000 points
//! per answer) and `range_scalar` (10,000 rows per answer)?
//!
//! ```text
//! cargo run --release --example visit_floor
//! ```
//!
//! Both workloads make the caller visit every value of every answer, and both implementations
//! (ours and the reference's anchor) visit with the same loop and the same arithmetic
//! (`f32`/`f64` → `u64` conversions, as WORKLOADS.md's checksums are defined). This program
//! builds the workloads' stores with the generator `examples/workloads.rs` uses, runs every query
//! **before** the timer, and then times only the visiting loops over the stored answers:
//! what the phase would cost with a lookup that took no time at all. The reference's
//! ns/op divided by this floor bounds the speed-up any store can show on the phase. It
//! prints, per workload, the floor and the full phase (lookups included) measured in the
//! same process, as min and median of 7 runs.
#![allow(
    clippy::cast_precision_loss,
    clippy::cast_possible_truncation,
    clippy::cast_possible_wrap,
    clippy::cast_sign_loss,
    reason = "benchmark arithmetic on small counts and exact small float values"
)]
#![allow(
    clippy::expect_used,
    reason = "a measurement program: its own generated inputs are valid, and a failure should stop it loudly"
)]

#[path = "../benches/common/mod.rs"]
mod common;

use std::hint::black_box;
use std::sync::Arc;
use std::time::Instant;

use chunkstore::{EntityPath, LatestAtQuery, QueryCell, RangeQuery, StoreConfig, TimeRange};
use common::{
    FRAME, POSITION3D, RowIds, SCALAR, at, entities, point_batch_queries, point_batches, points,
    range_series, range_series_queries, store_with, sum_of_xy, visit_range_scalars,
};

const RUNS: usize = 7;

/// Runs `f` (which returns `(ops, checksum)`) `RUNS` times; `(min, median)` ns per op.
fn time(mut f: impl FnMut() -> (u64, u64)) -> (f64, f64, u64) {
    let mut per_op = Vec::with_capacity(RUNS);
    let mut checksum = None;
    for _ in 0..RUNS {
        let start = Instant::now();
        let (ops, sum) = black_box(f());
        per_op.push(start.elapsed().as_nanos() as f64 / ops.max(1) as f64);
        assert_eq!(*checksum.get_or_insert(sum), sum, "runs agree");
    }
    per_op.sort_by(f64::total_cmp);
    (
        per_op[0],
        per_op[RUNS / 2],
        checksum.expect("at least one run"),
    )
}

fn report(workload: &str, what: &str, (min, median, checksum): (f64, f64, u64)) {
    println!(
        "{workload:<16} {what:<28} min {min:>9.1} ns/op   median {median:>9.1} ns/op   \
         checksum {checksum}"
    );
}

fn latest_at_batch() {
    let entity = EntityPath::parse("points").expect("a valid path");
    let store = store_with(
        StoreConfig::COMPACTION_OFF,
        &point_batches(&mut RowIds::new(), &entity),
    );
    let queries = point_batch_queries();
    let frame: Arc<str> = FRAME.into();
    let latest = |t: i64| {
        store.latest_at(
            &LatestAtQuery::new(Arc::clone(&frame), at(t)),
            &entity,
            POSITION3D,
        )
    };

    // The answer at every frame a query can ask for, looked up before the timer.
    let answers: Vec<Option<QueryCell>> = (0..1000).map(latest).collect();
    let floor = time(|| {
        let mut sum = 0u64;
        for &t in &queries {
            if let Some(cell) = &answers[black_box(t) as usize] {
                sum = sum.wrapping_add(sum_of_xy(points(cell.component(), cell.row())));
            }
        }
        (queries.len() as u64, sum)
    });
    let full = time(|| {
        let mut sum = 0u64;
        for &t in &queries {
            if let Some(cell) = latest(t) {
                sum = sum.wrapping_add(sum_of_xy(points(cell.component(), cell.row())));
            }
        }
        (queries.len() as u64, sum)
    });
    assert_eq!(floor.2, full.2, "the floor visits the same values");
    report("latest_at_batch", "visit only (floor)", floor);
    report("latest_at_batch", "lookup + visit (phase)", full);
}

fn range_scalar() {
    let entities = entities(10, |e| format!("series/{e}"));
    let store = store_with(
        StoreConfig::COMPACTION_OFF,
        &range_series(&mut RowIds::new(), &entities),
    );
    let queries = range_series_queries();
    let frame: Arc<str> = FRAME.into();
    let range = |(e, start): (usize, i64)| {
        let query = RangeQuery::new(
            Arc::clone(&frame),
            TimeRange::new(at(start), at(start + 9_999)),
        );
        store.range(&query, &entities[e], SCALAR)
    };

    let answers: Vec<_> = queries.iter().map(|&q| range(q)).collect();
    let floor = time(|| {
        let (mut rows, mut sum) = (0u64, 0u64);
        for result in &answers {
            visit_range_scalars(black_box(result), &mut rows, &mut sum);
        }
        (rows, sum)
    });
    let full = time(|| {
        let (mut rows, mut sum) = (0u64, 0u64);
        for &q in &queries {
            visit_range_scalars(&range(q), &mut rows, &mut sum);
        }
        (rows, sum)
    });
    assert_eq!(floor.2, full.2, "the floor visits the same values");
    report("range_scalar", "visit only (floor), per row", floor);
    report("range_scalar", "lookup + visit (phase)", full);
}

fn main() {
    latest_at_batch();
    range_scalar();
}
