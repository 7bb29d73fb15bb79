//! How fast could any store be on the query workloads of `../shared/bench/WORKLOADS.md`?
//!
//! ```text
//! cargo run --release --example visit_floor
//! ```
//!
//! Two workloads have large answers: `latest_at_batch` (1,000 points per answer) and
//! `range_scalar` (10,000 rows per answer). Both make the caller visit every value of every
//! answer, and both implementations (ours and the reference's anchor) visit with the same
//! loop and the same arithmetic. For these, this program builds the workloads' stores with
//! the generator `examples/workloads.rs` uses, runs every query **before** the timer, and
//! then times only the visiting loops over the stored answers: what the phase would cost
//! with a lookup that took no time at all.
//!
//! Two have small answers and many entities: `latest_at_mono` and `static_shadow`. Their
//! cost is the chain of dependent reads from the entity to the value, so their floor is an
//! *oracle layout*: the same rows in plain arrays indexed by entity number (no path to hash,
//! no component to look up, no chunks), queried with the same queries. No store can do with
//! fewer dependent reads than that layout; one that answers by entity path and keeps its
//! rows in chunks does more. Last, it times a walk of dependent reads through 1, 8 and 64
//! MiB, what one read of cold memory costs on this machine.
//!
//! The reference's ns/op divided by a floor bounds the speed-up any store can show on the
//! phase. Each line is the min and median of 7 runs; for the first two workloads, the full
//! phase (lookups included) is measured in the same process beside its floor.
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
    FRAME, POSITION3D, RowIds, SCALAR, SplitMix64, at, entities, point_batch_queries,
    point_batches, points, range_series, range_series_queries, store_with, sum_of_xy,
    visit_range_scalars,
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
                sum = sum.wrapping_add(sum_of_xy(points(cell.column(), cell.row())));
            }
        }
        (queries.len() as u64, sum)
    });
    let full = time(|| {
        let mut sum = 0u64;
        for &t in &queries {
            if let Some(cell) = latest(t) {
                sum = sum.wrapping_add(sum_of_xy(points(cell.column(), cell.row())));
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

/// The fewest dependent memory reads any store could answer `latest_at_mono` with: an
/// oracle layout of the same rows, with no entity path to hash, no component to look up and
/// no chunks. Entity `i` is slot `i` of an array; its 1,000 times and positions are two
/// arrays of its own, allocated in the workload's insertion order (chunk-major), so that the
/// entities' data is spread over the heap as a store's would be. A query probes the times
/// where `t` would be if they were evenly spread (they are: one probe finds the row), then
/// reads the row's position: two dependent reads of cold memory per query, the entity's
/// times and then its values. The checksum equals the workload's.
fn latest_at_mono() {
    struct Rows {
        times: Vec<i64>,
        positions: Vec<[f32; 3]>,
    }
    let mut rows: Vec<Rows> = (0..1000)
        .map(|_| Rows {
            times: Vec::new(),
            positions: Vec::new(),
        })
        .collect();
    // Chunk-major, as the workload inserts: each entity's arrays grow (and move) ten times.
    for c in 0..10i64 {
        for (i, entity) in rows.iter_mut().enumerate() {
            for r in 0..100 {
                entity.times.push(c * 100 + r);
                entity.positions.push([i as f32, (c * 100 + r) as f32, 0.0]);
            }
        }
    }
    let mut rng = SplitMix64::new();
    let queries: Vec<(usize, i64)> = (0..100_000)
        .map(|_| (rng.uniform_usize(1000), rng.uniform(1100) as i64))
        .collect();
    let floor = time(|| {
        let mut sum = 0u64;
        for &(i, t) in &queries {
            let entity = &rows[black_box(i)];
            let times = &entity.times;
            let (min, max) = (times[0], times[times.len() - 1]);
            let end = if t >= max {
                times.len()
            } else if t < min {
                0
            } else {
                // One probe where `t` would be in evenly spread times, then a binary
                // search inside the bracket it proves (empty here: the probe is exact).
                let guess = ((t - min) as usize * (times.len() - 1)) / (max - min) as usize;
                if times[guess] <= t {
                    guess + 1 + times[guess + 1..].partition_point(|&x| x <= t)
                } else {
                    times[..guess].partition_point(|&x| x <= t)
                }
            };
            if let Some(p) = end.checked_sub(1).map(|row| entity.positions[row]) {
                sum = sum.wrapping_add(p[0] as u64 + p[1] as u64);
            }
        }
        (queries.len() as u64, sum)
    });
    assert_eq!(floor.2, 104_506_789, "WORKLOADS.md's checksum");
    report("latest_at_mono", "oracle layout (floor)", floor);
}

/// The same floor for `static_shadow`: entity `i` is slot `i` of an array holding its static
/// `text` and its ten temporal rows (times, texts, scalars), allocated entity by entity as
/// the workload inserts them. A query reads the static text's length (static wins at every
/// time, so the temporal texts are never read) and the scalar at the greatest time at or
/// before `t`: one read of the entity's slot, then the text and the times side by side,
/// then the scalar.
fn static_shadow() {
    struct Prop {
        name: String,
        times: Vec<i64>,
        _texts: Vec<String>,
        scalars: Vec<f64>,
    }
    let props: Vec<Prop> = (0..10_000)
        .map(|i| Prop {
            name: format!("name-{i}"),
            times: (0..10).collect(),
            _texts: (0..10).map(|f| format!("t-{i}-{f}")).collect(),
            scalars: (0..10).map(f64::from).collect(),
        })
        .collect();
    let mut rng = SplitMix64::new();
    let queries: Vec<(usize, i64)> = (0..100_000)
        .map(|_| (rng.uniform_usize(10_000), rng.uniform(20) as i64))
        .collect();
    let floor = time(|| {
        let mut sum = 0u64;
        for &(i, t) in &queries {
            let prop = &props[black_box(i)];
            sum = sum.wrapping_add(prop.name.len() as u64);
            let end = prop.times.partition_point(|&x| x <= t);
            if let Some(v) = end.checked_sub(1).map(|row| prop.scalars[row]) {
                sum = sum.wrapping_add(v as u64);
            }
        }
        (queries.len() as u64, sum)
    });
    assert_eq!(floor.2, 1_566_231, "WORKLOADS.md's checksum");
    report("static_shadow", "oracle layout (floor)", floor);
}

/// What one dependent read of cold memory costs on this machine: a walk of a random cycle
/// through `mib` MiB of 64-byte lines, each line holding the next one's position.
fn dependent_read(mib: usize) {
    let lines = mib * 1024 * 1024 / 64;
    let mut rng = SplitMix64::new();
    let order = rng.permutation(lines);
    let mut next = vec![[0u64; 8]; lines];
    for (k, &line) in order.iter().enumerate() {
        next[line as usize][0] = order[(k + 1) % lines] as u64;
    }
    let steps = 2_000_000;
    let walk = time(|| {
        let mut at = 0u64;
        for _ in 0..steps {
            at = next[at as usize][0];
        }
        (steps, at)
    });
    report("memory", &format!("dependent read, {mib} MiB"), walk);
}

fn main() {
    latest_at_batch();
    range_scalar();
    latest_at_mono();
    static_shadow();
    for mib in [1, 8, 64] {
        dependent_read(mib);
    }
}
