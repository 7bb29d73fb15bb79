//! Model test: random operation sequences (temporal inserts on several timelines, with
//! out-of-order and overlapping chunks, null cells, empty lists and duplicate times; static
//! inserts; flat and recursive Clears, temporal and static, at random depths of a small
//! entity tree) interleaved with latest-at and range queries, run against the store and
//! against a deliberately naive model that scans every row. Answers must be identical,
//! and `sanity_check()` must pass after every insert.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::float_cmp,
    reason = "tests fail loudly on unexpected values; test values are small integers, exact in f64"
)]

mod common;

use std::sync::Arc;

use arrow_array::{ArrayRef, Float64Array, Int64Array};
use chunkstore::{
    Chunk, ChunkId, ChunkStore, ComponentName, LatestAtQuery, RangeQuery, RowId, TimeInt, Timeline,
};
use common::{bool_list, f64_list, path};
use proptest::prelude::*;

const ENTITIES: [&str; 6] = ["/", "a", "a/b", "a/b/c", "a/d", "e"];
const COMPONENTS: [&str; 2] = ["x", "y"];
const TIMELINES: [&str; 2] = ["t1", "t2"];
const MAX_TIME: i64 = 12;

/// A cell as the model sees it: `None` null, `Some(vec![])` empty, else instances.
type Cell = Option<Vec<f64>>;

#[derive(Clone, Debug)]
struct Row {
    /// Time per timeline; `None` when the chunk does not have that timeline.
    times: [Option<i64>; 2],
    cells: [Cell; 2],
}

#[derive(Clone, Debug)]
enum Op {
    /// A temporal chunk: which timelines it has (bit 0: t1, bit 1: t2) and its rows.
    Temporal {
        entity: usize,
        timelines: u8,
        rows: Vec<([i64; 2], [Cell; 2])>,
    },
    Static {
        entity: usize,
        rows: Vec<[Cell; 2]>,
    },
    Clear {
        entity: usize,
        time: Option<[i64; 2]>,
        recursive: bool,
    },
    LatestAt {
        entity: usize,
        component: usize,
        timeline: usize,
        at: i64,
    },
    Range {
        entity: usize,
        component: usize,
        timeline: usize,
        min: i64,
        max: i64,
    },
}

fn cell() -> impl Strategy<Value = Cell> {
    prop_oneof![
        2 => Just(None),
        1 => Just(Some(vec![])),
        4 => (0..100i32).prop_map(|v| Some(vec![f64::from(v)])),
        1 => (0..100i32, 0..100i32).prop_map(|(a, b)| Some(vec![f64::from(a), f64::from(b)])),
    ]
}

fn op() -> impl Strategy<Value = Op> {
    let entity = 0..ENTITIES.len();
    let times = [0..=MAX_TIME, 0..=MAX_TIME];
    let temporal = (
        entity.clone(),
        1u8..=3,
        prop::collection::vec((times.clone(), [cell(), cell()]), 1..8),
    )
        .prop_map(|(entity, timelines, rows)| Op::Temporal {
            entity,
            timelines,
            rows,
        });
    let statics = (
        entity.clone(),
        prop::collection::vec([cell(), cell()], 1..3),
    )
        .prop_map(|(entity, rows)| Op::Static { entity, rows });
    let clear = (
        entity.clone(),
        prop::option::weighted(0.85, times),
        any::<bool>(),
    )
        .prop_map(|(entity, time, recursive)| Op::Clear {
            entity,
            time,
            recursive,
        });
    let latest = (entity.clone(), 0..2usize, 0..2usize, -1..=MAX_TIME + 1).prop_map(
        |(entity, component, timeline, at)| Op::LatestAt {
            entity,
            component,
            timeline,
            at,
        },
    );
    let range = (
        entity,
        0..2usize,
        0..2usize,
        -1..=MAX_TIME + 1,
        0..=MAX_TIME,
    )
        .prop_map(|(entity, component, timeline, min, len)| Op::Range {
            entity,
            component,
            timeline,
            min,
            max: min + len,
        });
    prop_oneof![6 => temporal, 1 => statics, 2 => clear, 4 => latest, 2 => range]
}

/// What a query answers: `(time, row id, cell)` (time `None` for static).
type Answer = (Option<i64>, u128, Vec<f64>);

/// A Clear as the model keeps it: `(entity, row id, times, recursive)`; `times` is `None`
/// for a static Clear.
type ModelClear = (usize, u128, Option<[Option<i64>; 2]>, bool);

#[derive(Default)]
struct Model {
    /// `(entity, row id, row, is_static)`
    rows: Vec<(usize, u128, Row, bool)>,
    clears: Vec<ModelClear>,
}

fn is_strict_ancestor(ancestor: usize, of: usize) -> bool {
    let a = path(ENTITIES[ancestor]);
    a.is_ancestor_of(&path(ENTITIES[of]))
}

impl Model {
    /// The static row with the greatest row id and a non-null cell, as an answer.
    fn static_winner(&self, entity: usize, component: usize) -> Option<Answer> {
        self.rows
            .iter()
            .filter(|(e, _, row, is_static)| {
                *e == entity && *is_static && row.cells[component].is_some()
            })
            .max_by_key(|(_, row_id, ..)| *row_id)
            .map(|(_, row_id, row, _)| {
                (
                    None,
                    *row_id,
                    row.cells[component].clone().unwrap_or_default(),
                )
            })
    }

    fn latest_at(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
        at: i64,
    ) -> Option<Answer> {
        let answer = match self.static_winner(entity, component) {
            Some(winner) => winner,
            None => self
                .rows
                .iter()
                .filter(|(e, _, row, is_static)| {
                    *e == entity
                        && !is_static
                        && row.cells[component].is_some()
                        && row.times[timeline].is_some_and(|time| time <= at)
                })
                .max_by_key(|(_, row_id, row, _)| (row.times[timeline], *row_id))
                .map(|(_, row_id, row, _)| {
                    (
                        row.times[timeline],
                        *row_id,
                        row.cells[component].clone().unwrap_or_default(),
                    )
                })?,
        };
        (!self.is_hidden(entity, timeline, at, answer.0, answer.1)).then_some(answer)
    }

    fn is_hidden(
        &self,
        entity: usize,
        timeline: usize,
        at: i64,
        time: Option<i64>,
        row_id: u128,
    ) -> bool {
        self.clears
            .iter()
            .any(|&(clear_entity, clear_row_id, clear_times, recursive)| {
                let applies = clear_entity == entity
                    || (recursive && is_strict_ancestor(clear_entity, entity));
                if !applies {
                    return false;
                }
                match (clear_times, time) {
                    (None, None) => row_id <= clear_row_id,
                    (None, Some(_)) => true,
                    (Some(_), None) => false,
                    (Some(times), Some(time)) => match times[timeline] {
                        Some(clear_time) => {
                            clear_time <= at && (time, row_id) <= (clear_time, clear_row_id)
                        }
                        None => false,
                    },
                }
            })
    }

    fn range(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
        min: i64,
        max: i64,
    ) -> Vec<Answer> {
        if let Some(winner) = self.static_winner(entity, component) {
            return vec![winner];
        }
        let mut rows: Vec<Answer> = self
            .rows
            .iter()
            .filter(|(e, _, row, is_static)| {
                *e == entity
                    && !is_static
                    && row.cells[component].is_some()
                    && row.times[timeline].is_some_and(|time| min <= time && time <= max)
            })
            .map(|(_, row_id, row, _)| {
                (
                    row.times[timeline],
                    *row_id,
                    row.cells[component].clone().unwrap_or_default(),
                )
            })
            .collect();
        rows.sort_by_key(|(time, row_id, _)| (*time, *row_id));
        rows
    }
}

/// One `List<Float64>` column per component, from each row's cells.
fn component_columns(rows: &[&[Cell; 2]]) -> Vec<(chunkstore::ComponentDescriptor, ArrayRef)> {
    COMPONENTS
        .iter()
        .enumerate()
        .map(|(c, name)| {
            let cells: Vec<Cell> = rows.iter().map(|cells| cells[c].clone()).collect();
            ((*name).into(), f64_list(&cells))
        })
        .collect()
}

fn values(cell: &ArrayRef) -> Vec<f64> {
    cell.as_any()
        .downcast_ref::<Float64Array>()
        .unwrap()
        .values()
        .to_vec()
}

/// Unique row ids in random order: a random high part, a counter low part.
struct RowIds {
    counter: u128,
}

impl RowIds {
    fn next(&mut self, random: u64) -> u128 {
        self.counter += 1;
        (u128::from(random % 1000) << 64) | self.counter
    }
}

#[expect(
    clippy::too_many_lines,
    reason = "one match arm per operation, side by side with the model's"
)]
fn run(ops: &[Op], shuffles: &[u64]) -> Result<(), TestCaseError> {
    let mut store = ChunkStore::new();
    let mut model = Model::default();
    let mut row_ids = RowIds { counter: 0 };
    let mut randomness = shuffles.iter().copied().cycle();
    let mut next_row_id = || row_ids.next(randomness.next().unwrap_or(0));

    for op in ops {
        match op {
            Op::Temporal {
                entity,
                timelines,
                rows,
            } => {
                let ids: Vec<u128> = rows.iter().map(|_| next_row_id()).collect();
                let mut time_columns = Vec::new();
                for (i, name) in TIMELINES.iter().enumerate() {
                    if timelines & (1 << i) != 0 {
                        let times: Vec<i64> = rows.iter().map(|(times, _)| times[i]).collect();
                        time_columns.push((
                            Timeline::sequence(*name),
                            Arc::new(Int64Array::from(times)) as ArrayRef,
                        ));
                    }
                }
                let components =
                    component_columns(&rows.iter().map(|(_, cells)| cells).collect::<Vec<_>>());
                let chunk = Chunk::try_new(
                    ChunkId::new(),
                    path(ENTITIES[*entity]),
                    ids.iter().map(|&r| RowId::from_u128(r)).collect(),
                    time_columns,
                    components,
                )
                .unwrap();
                store.insert(chunk).unwrap();
                for (&row_id, (times, cells)) in ids.iter().zip(rows) {
                    let times = [0, 1].map(|i| (timelines & (1 << i) != 0).then_some(times[i]));
                    model.rows.push((
                        *entity,
                        row_id,
                        Row {
                            times,
                            cells: cells.clone(),
                        },
                        false,
                    ));
                }
            }
            Op::Static { entity, rows } => {
                let ids: Vec<u128> = rows.iter().map(|_| next_row_id()).collect();
                let components = component_columns(&rows.iter().collect::<Vec<_>>());
                let chunk = Chunk::try_new(
                    ChunkId::new(),
                    path(ENTITIES[*entity]),
                    ids.iter().map(|&r| RowId::from_u128(r)).collect(),
                    vec![],
                    components,
                )
                .unwrap();
                store.insert(chunk).unwrap();
                for (&row_id, cells) in ids.iter().zip(rows) {
                    model.rows.push((
                        *entity,
                        row_id,
                        Row {
                            times: [None, None],
                            cells: cells.clone(),
                        },
                        true,
                    ));
                }
            }
            Op::Clear {
                entity,
                time,
                recursive,
            } => {
                let row_id = next_row_id();
                let time_columns = time
                    .map(|times| {
                        TIMELINES
                            .iter()
                            .zip(times)
                            .map(|(name, time)| {
                                (
                                    Timeline::sequence(*name),
                                    Arc::new(Int64Array::from(vec![time])) as ArrayRef,
                                )
                            })
                            .collect()
                    })
                    .unwrap_or_default();
                let chunk = Chunk::try_new(
                    ChunkId::new(),
                    path(ENTITIES[*entity]),
                    vec![RowId::from_u128(row_id)],
                    time_columns,
                    vec![(
                        ComponentName::CLEAR_IS_RECURSIVE.into(),
                        bool_list(&[Some(*recursive)]),
                    )],
                )
                .unwrap();
                store.insert(chunk).unwrap();
                model
                    .clears
                    .push((*entity, row_id, time.map(|t| t.map(Some)), *recursive));
            }
            Op::LatestAt {
                entity,
                component,
                timeline,
                at,
            } => {
                check_latest_at(&store, &model, *entity, *component, *timeline, *at)?;
            }
            Op::Range {
                entity,
                component,
                timeline,
                min,
                max,
            } => {
                check_range(&store, &model, *entity, *component, *timeline, *min, *max)?;
            }
        }
        if let Err(broken) = store.sanity_check() {
            return Err(TestCaseError::fail(format!(
                "sanity_check after {op:?}: {broken}"
            )));
        }
    }
    // A final sweep of every query, so no sequence ends without being checked.
    for entity in 0..ENTITIES.len() {
        for component in 0..COMPONENTS.len() {
            for timeline in 0..TIMELINES.len() {
                for at in -1..=MAX_TIME + 1 {
                    check_latest_at(&store, &model, entity, component, timeline, at)?;
                }
                check_range(&store, &model, entity, component, timeline, 0, MAX_TIME)?;
                check_range(&store, &model, entity, component, timeline, 3, 7)?;
            }
        }
    }
    Ok(())
}

fn check_latest_at(
    store: &ChunkStore,
    model: &Model,
    entity: usize,
    component: usize,
    timeline: usize,
    at: i64,
) -> Result<(), TestCaseError> {
    let query = LatestAtQuery::new(TIMELINES[timeline], TimeInt::new(at).unwrap());
    let ours = store
        .latest_at(&query, &path(ENTITIES[entity]), COMPONENTS[component])
        .map(|a| {
            (
                a.time().map(TimeInt::as_i64),
                a.row_id().as_u128(),
                values(&a.cell()),
            )
        });
    let expected = model.latest_at(entity, component, timeline, at);
    prop_assert_eq!(
        ours,
        expected,
        "latest-at {}={} {}:{}",
        TIMELINES[timeline],
        at,
        ENTITIES[entity],
        COMPONENTS[component]
    );
    Ok(())
}

fn check_range(
    store: &ChunkStore,
    model: &Model,
    entity: usize,
    component: usize,
    timeline: usize,
    min: i64,
    max: i64,
) -> Result<(), TestCaseError> {
    let query = RangeQuery::new(
        TIMELINES[timeline],
        TimeInt::new(min).unwrap(),
        TimeInt::new(max).unwrap(),
    );
    let ours: Vec<Answer> = store
        .range(&query, &path(ENTITIES[entity]), COMPONENTS[component])
        .iter()
        .map(|r| {
            (
                r.time().map(TimeInt::as_i64),
                r.row_id().as_u128(),
                values(&r.cell()),
            )
        })
        .collect();
    let expected = model.range(entity, component, timeline, min, max);
    prop_assert_eq!(
        ours,
        expected,
        "range {} [{}, {}] {}:{}",
        TIMELINES[timeline],
        min,
        max,
        ENTITIES[entity],
        COMPONENTS[component]
    );
    Ok(())
}

/// Number of random sequences per run; the closing note quotes it.
const NUM_CASES: u32 = 768;

proptest! {
    #![proptest_config(ProptestConfig { cases: NUM_CASES, max_shrink_iters: 4096, ..ProptestConfig::default() })]

    #[test]
    fn store_answers_like_the_naive_model(ops in prop::collection::vec(op(), 1..40), shuffles in prop::collection::vec(any::<u64>(), 1..16)) {
        run(&ops, &shuffles)?;
    }
}

/// Wide time spans next to short ones: exercises the span classes of the index with
/// chunks that straddle query times by a lot.
#[test]
fn wide_and_narrow_chunks_answer_like_the_model() {
    let mut ops = Vec::new();
    for (i, entity) in (0..30i32).zip((0..3usize).cycle()) {
        let i64 = i64::from(i);
        let rows = vec![
            ([i64 % 13, 12 - i64 % 13], [Some(vec![f64::from(i)]), None]),
            ([(i64 * 7) % 13, i64 % 5], [Some(vec![]), Some(vec![1.0])]),
        ];
        ops.push(Op::Temporal {
            entity,
            timelines: 3,
            rows,
        });
    }
    run(&ops, &[7, 3, 999, 1]).unwrap();
}
