//! Model test: random operation sequences (temporal inserts on several timelines, with
//! out-of-order and overlapping chunks, null cells, empty lists and duplicate times; static
//! inserts; flat and recursive Clears, temporal and static, at random depths of a small
//! entity tree; garbage collections with random targets, orders and protections; drops of
//! time ranges and of entities; on-demand compaction) interleaved with latest-at and range
//! queries, run against two stores (compaction off, and compaction with tiny thresholds)
//! and against a deliberately naive model that scans every row. After every step, answers
//! must be identical, `sanity_check()` must pass, and replaying every event returned so
//! far must give exactly the store's chunks.
//!
//! The named properties of the lifecycle (SEMANTICS.md sections 6 to 8) reuse the same
//! generator and harness, each in its own test.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::float_cmp,
    reason = "tests fail loudly on unexpected values; test values are small integers, exact in f64"
)]

mod common;

use std::collections::{BTreeSet, HashMap, HashSet};
use std::sync::Arc;

use arrow_array::{Array, ArrayRef, BooleanArray, Float64Array, Int64Array};
use chunkstore::{
    Chunk, ChunkId, ChunkStore, ComponentName, DeletionReason, GcOptions, GcOrder, GcTarget,
    LatestAtQuery, RangeQuery, RowId, StoreConfig, StoreEvent, TimeInt, Timeline,
};
use common::{bool_list, f64_list, path, t};
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
    Gc(GcOp),
    DropTimeRange {
        timeline: usize,
        min: i64,
        max: i64,
    },
    DropEntity {
        entity: usize,
        recursive: bool,
    },
    Compact,
}

#[derive(Clone, Debug)]
struct GcOp {
    /// 0: everything; 1: half the heap; 2: a few bytes (one chunk or so).
    target: u8,
    protect_latest: usize,
    /// Furthest from `(timeline, time)` first, else oldest row ids first.
    cursor: Option<(usize, i64)>,
    /// `(timeline, min, max)`.
    protected: Option<(usize, i64, i64)>,
    /// A zero time budget: planning stops after the first chunk it chooses.
    zero_budget: bool,
}

impl GcOp {
    fn options(&self) -> GcOptions {
        GcOptions {
            target: match self.target {
                0 => GcTarget::Everything,
                1 => GcTarget::drop_at_least_fraction(0.5).unwrap(),
                _ => GcTarget::DropAtLeastBytes(1),
            },
            protect_latest: self.protect_latest,
            protected_time_ranges: self
                .protected
                .iter()
                .map(|&(timeline, min, max)| (TIMELINES[timeline].to_owned(), t(min), t(max)))
                .collect(),
            time_budget: self.zero_budget.then_some(std::time::Duration::ZERO),
            order: match self.cursor {
                Some((timeline, time)) => GcOrder::FurthestFrom {
                    timeline: TIMELINES[timeline].to_owned(),
                    time: t(time),
                },
                None => GcOrder::OldestRowIdsFirst,
            },
        }
    }
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
    let gc = (
        0u8..3,
        0usize..3,
        prop::option::of((0..2usize, 0..=MAX_TIME)),
        prop::option::weighted(0.3, (0..2usize, 0..=MAX_TIME, 0..4i64)),
        prop::bool::weighted(0.2),
    )
        .prop_map(|(target, protect_latest, cursor, protected, zero_budget)| {
            Op::Gc(GcOp {
                target,
                protect_latest,
                cursor,
                protected: protected.map(|(timeline, min, len)| (timeline, min, min + len)),
                zero_budget,
            })
        });
    let drop_range =
        (0..2usize, 0..=MAX_TIME, 0..4i64).prop_map(|(timeline, min, len)| Op::DropTimeRange {
            timeline,
            min,
            max: min + len,
        });
    let drop_entity = (0..ENTITIES.len(), any::<bool>())
        .prop_map(|(entity, recursive)| Op::DropEntity { entity, recursive });
    prop_oneof![
        6 => temporal,
        1 => statics,
        2 => clear,
        4 => latest,
        2 => range,
        1 => gc,
        1 => drop_range,
        1 => drop_entity,
        1 => Just(Op::Compact),
    ]
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

/// The two stores every sequence runs against: compaction off, and compaction with
/// thresholds so small that nearly every insert merges or splits.
const CONFIGS: [StoreConfig; 2] = [
    StoreConfig::COMPACTION_OFF,
    StoreConfig {
        compact_on_insert: true,
        max_rows: 4,
        max_rows_unsorted: 3,
        max_bytes: 256,
        merge_fanout: 2,
    },
];

/// One store, its naive model, and the chunks its events replay to.
struct Harness {
    store: ChunkStore,
    model: Model,
    replayed: HashMap<ChunkId, Arc<Chunk>>,
    row_ids: RowIds,
}

impl Harness {
    fn new(config: StoreConfig) -> Self {
        Self {
            store: ChunkStore::with_config(config).unwrap(),
            model: Model::default(),
            replayed: HashMap::new(),
            row_ids: RowIds { counter: 0 },
        }
    }

    /// Replays `events` on the set of chunks, which must stay consistent.
    fn replay(&mut self, events: &[StoreEvent]) -> Result<(), TestCaseError> {
        for event in events {
            match event {
                StoreEvent::Addition(chunk) => {
                    let before = self.replayed.insert(chunk.id(), Arc::clone(chunk));
                    prop_assert!(before.is_none(), "{} added twice", chunk.id());
                }
                StoreEvent::Deletion { chunk, .. } => {
                    let before = self.replayed.remove(&chunk.id());
                    prop_assert!(before.is_some(), "{} deleted before added", chunk.id());
                }
            }
        }
        Ok(())
    }

    /// The model forgets the rows of every chunk garbage collection removed.
    fn forget_collected(&mut self, events: &[StoreEvent]) {
        let collected: HashSet<u128> = events
            .iter()
            .filter_map(|e| match e {
                StoreEvent::Deletion {
                    chunk,
                    reason: DeletionReason::Gc,
                } => Some(chunk.row_ids().iter().map(|r| r.as_u128())),
                _ => None,
            })
            .flatten()
            .collect();
        self.model
            .rows
            .retain(|(_, row_id, ..)| !collected.contains(row_id));
        self.model
            .clears
            .retain(|(_, row_id, ..)| !collected.contains(row_id));
    }

    fn insert(&mut self, chunk: Chunk) -> Result<(), TestCaseError> {
        let events = self.store.insert(chunk).unwrap();
        self.replay(&events)
    }

    #[expect(
        clippy::too_many_lines,
        reason = "one match arm per operation, side by side with the model's"
    )]
    fn apply(
        &mut self,
        op: &Op,
        randomness: &mut impl Iterator<Item = u64>,
    ) -> Result<(), TestCaseError> {
        let mut next_row_id = || self.row_ids.next(randomness.next().unwrap_or(0));
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
                self.insert(chunk)?;
                for (&row_id, (times, cells)) in ids.iter().zip(rows) {
                    let times = [0, 1].map(|i| (timelines & (1 << i) != 0).then_some(times[i]));
                    self.model.rows.push((
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
                self.insert(chunk)?;
                for (&row_id, cells) in ids.iter().zip(rows) {
                    self.model.rows.push((
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
                self.insert(chunk)?;
                self.model
                    .clears
                    .push((*entity, row_id, time.map(|t| t.map(Some)), *recursive));
            }
            Op::LatestAt {
                entity,
                component,
                timeline,
                at,
            } => {
                check_latest_at(
                    &self.store,
                    &self.model,
                    *entity,
                    *component,
                    *timeline,
                    *at,
                )?;
            }
            Op::Range {
                entity,
                component,
                timeline,
                min,
                max,
            } => {
                check_range(
                    &self.store,
                    &self.model,
                    *entity,
                    *component,
                    *timeline,
                    *min,
                    *max,
                )?;
            }
            Op::Gc(gc) => {
                let options = gc.options();
                let protected = protected_chunks(&self.store, &options);
                let collectable = self.store.chunks().any(|c| !protected.contains(&c.id()));
                let events = self.store.gc(&options);
                self.replay(&events)?;
                for event in &events {
                    let StoreEvent::Deletion { chunk, reason } = event else {
                        return Err(TestCaseError::fail("gc only deletes"));
                    };
                    prop_assert_eq!(*reason, DeletionReason::Gc);
                    prop_assert!(
                        !protected.contains(&chunk.id()),
                        "gc removed protected {}",
                        chunk.id()
                    );
                }
                prop_assert!(
                    !collectable || !events.is_empty(),
                    "gc freed nothing although unprotected chunks exist"
                );
                self.forget_collected(&events);
            }
            Op::DropTimeRange { timeline, min, max } => {
                let events = self
                    .store
                    .drop_time_range(TIMELINES[*timeline], t(*min), t(*max));
                self.replay(&events)?;
                let in_range = |time: Option<i64>| time.is_some_and(|t| *min <= t && t <= *max);
                self.model
                    .rows
                    .retain(|(_, _, row, is_static)| *is_static || !in_range(row.times[*timeline]));
                self.model.clears.retain(|(_, _, times, _)| {
                    !times.is_some_and(|times| in_range(times[*timeline]))
                });
            }
            Op::DropEntity { entity, recursive } => {
                let events = self.store.drop_entity(&path(ENTITIES[*entity]), *recursive);
                self.replay(&events)?;
                let dropped =
                    |e: usize| e == *entity || (*recursive && is_strict_ancestor(*entity, e));
                self.model.rows.retain(|(e, ..)| !dropped(*e));
                self.model.clears.retain(|(e, ..)| !dropped(*e));
            }
            Op::Compact => {
                let events = self.store.compact();
                self.replay(&events)?;
                for event in &events {
                    if let StoreEvent::Deletion { reason, .. } = event {
                        prop_assert_eq!(*reason, DeletionReason::Compaction);
                    }
                }
            }
        }
        if let Err(broken) = self.store.sanity_check() {
            return Err(TestCaseError::fail(format!(
                "sanity_check after {op:?}: {broken}"
            )));
        }
        let held: BTreeSet<ChunkId> = self.store.chunks().map(|c| c.id()).collect();
        let replayed: BTreeSet<ChunkId> = self.replayed.keys().copied().collect();
        prop_assert_eq!(
            held,
            replayed,
            "events replay to the store's chunks after {:?}",
            op
        );
        Ok(())
    }

    /// Latest-at at the end of time and a full range, for every (entity, component,
    /// timeline): cheap enough to run after every step.
    fn light_sweep(&self, at: i64) -> Result<(), TestCaseError> {
        for entity in 0..ENTITIES.len() {
            for component in 0..COMPONENTS.len() {
                for timeline in 0..TIMELINES.len() {
                    for at in [at, MAX_TIME + 1] {
                        check_latest_at(&self.store, &self.model, entity, component, timeline, at)?;
                    }
                    check_range(
                        &self.store,
                        &self.model,
                        entity,
                        component,
                        timeline,
                        0,
                        MAX_TIME,
                    )?;
                }
            }
        }
        Ok(())
    }

    /// Every latest-at time and two ranges, for every (entity, component, timeline).
    fn full_sweep(&self) -> Result<(), TestCaseError> {
        for entity in 0..ENTITIES.len() {
            for component in 0..COMPONENTS.len() {
                for timeline in 0..TIMELINES.len() {
                    for at in -1..=MAX_TIME + 1 {
                        check_latest_at(&self.store, &self.model, entity, component, timeline, at)?;
                    }
                    check_range(
                        &self.store,
                        &self.model,
                        entity,
                        component,
                        timeline,
                        0,
                        MAX_TIME,
                    )?;
                    check_range(&self.store, &self.model, entity, component, timeline, 3, 7)?;
                }
            }
        }
        Ok(())
    }
}

/// Runs `ops` on a store with `config`, checking everything after every step.
fn run_with(config: StoreConfig, ops: &[Op], shuffles: &[u64]) -> Result<Harness, TestCaseError> {
    let mut harness = Harness::new(config);
    let mut randomness = shuffles.iter().copied().cycle();
    for (step, op) in ops.iter().enumerate() {
        harness.apply(op, &mut randomness)?;
        harness.light_sweep(i64::try_from(step).unwrap() % (MAX_TIME + 2) - 1)?;
    }
    harness.full_sweep()?;
    Ok(harness)
}

fn run(ops: &[Op], shuffles: &[u64]) -> Result<(), TestCaseError> {
    for config in CONFIGS {
        run_with(config, ops, shuffles)?;
    }
    Ok(())
}

/// `(time, row id, chunk)`: how the store orders cells and Clears across chunks.
type IndexKey = (i64, RowId, ChunkId);

/// The chunks `options` must keep, found by brute force over the store's chunks: static
/// ones, those touching a protected range, the `n` latest of every (entity, timeline,
/// component), and those holding the `n` latest Clears (flat or recursive, and recursive
/// alone) of every (entity, timeline).
fn protected_chunks(store: &ChunkStore, options: &GcOptions) -> HashSet<ChunkId> {
    let mut protected = HashSet::new();
    // (entity, timeline, component) → (max time, max row id, chunk) per chunk.
    let mut latest: HashMap<(String, String, String), Vec<IndexKey>> = HashMap::new();
    // (entity, timeline, recursive only?) → every Clear row (time, row id, chunk).
    let mut clears: HashMap<(String, String, bool), Vec<IndexKey>> = HashMap::new();
    for chunk in store.chunks() {
        if chunk.is_static() {
            protected.insert(chunk.id());
            continue;
        }
        for (name, min, max) in &options.protected_time_ranges {
            if let Some(column) = chunk.time_column(name) {
                let (lo, hi) = column.time_range();
                if lo <= *max && *min <= hi {
                    protected.insert(chunk.id());
                }
            }
        }
        let entity = chunk.entity_path().to_string();
        for column in chunk.time_columns() {
            let timeline = column.timeline().name().to_owned();
            for component in chunk.components() {
                let list = component.list_array();
                let best = (0..chunk.num_rows())
                    .filter(|&row| list.is_valid(row))
                    .map(|row| (column.times()[row], chunk.row_ids()[row]))
                    .max();
                if let Some((time, row_id)) = best {
                    latest
                        .entry((
                            entity.clone(),
                            timeline.clone(),
                            component.name().to_string(),
                        ))
                        .or_default()
                        .push((time, row_id, chunk.id()));
                }
                if component.name().is_clear() {
                    let flags = list
                        .values()
                        .as_any()
                        .downcast_ref::<BooleanArray>()
                        .unwrap();
                    for row in (0..chunk.num_rows())
                        .filter(|&r| list.is_valid(r) && list.value_length(r) > 0)
                    {
                        let first = usize::try_from(list.value_offsets()[row]).unwrap();
                        let recursive = flags.is_valid(first) && flags.value(first);
                        let key = (column.times()[row], chunk.row_ids()[row], chunk.id());
                        clears
                            .entry((entity.clone(), timeline.clone(), false))
                            .or_default()
                            .push(key);
                        if recursive {
                            clears
                                .entry((entity.clone(), timeline.clone(), true))
                                .or_default()
                                .push(key);
                        }
                    }
                }
            }
        }
    }
    for mut keys in latest.into_values().chain(clears.into_values()) {
        keys.sort_unstable();
        protected.extend(keys.iter().rev().take(options.protect_latest).map(|k| k.2));
    }
    protected
}

fn latest_at_answer(
    store: &ChunkStore,
    entity: usize,
    component: usize,
    timeline: usize,
    at: i64,
) -> Option<Answer> {
    let query = LatestAtQuery::new(TIMELINES[timeline], TimeInt::new(at).unwrap());
    store
        .latest_at(&query, &path(ENTITIES[entity]), COMPONENTS[component])
        .map(|a| {
            (
                a.time().map(TimeInt::as_i64),
                a.row_id().as_u128(),
                values(&a.cell()),
            )
        })
}

fn range_answer(
    store: &ChunkStore,
    entity: usize,
    component: usize,
    timeline: usize,
    min: i64,
    max: i64,
) -> Vec<Answer> {
    let query = RangeQuery::new(
        TIMELINES[timeline],
        TimeInt::new(min).unwrap(),
        TimeInt::new(max).unwrap(),
    );
    store
        .range(&query, &path(ENTITIES[entity]), COMPONENTS[component])
        .iter()
        .map(|r| {
            (
                r.time().map(TimeInt::as_i64),
                r.row_id().as_u128(),
                values(&r.cell()),
            )
        })
        .collect()
}

fn check_latest_at(
    store: &ChunkStore,
    model: &Model,
    entity: usize,
    component: usize,
    timeline: usize,
    at: i64,
) -> Result<(), TestCaseError> {
    let ours = latest_at_answer(store, entity, component, timeline, at);
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
    let ours = range_answer(store, entity, component, timeline, min, max);
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

/// Cases per run of each named property (each case runs a whole sequence).
const PROPERTY_CASES: u32 = 256;

/// A store with compaction on insert off but tiny thresholds, so that `compact()` cuts
/// nearly every set of chunks into several.
const TINY_ON_DEMAND: StoreConfig = StoreConfig {
    compact_on_insert: false,
    ..CONFIGS[1]
};

/// Every answer of the full sweep, in order.
fn all_answers(store: &ChunkStore) -> Vec<Vec<Answer>> {
    let mut answers = Vec::new();
    for entity in 0..ENTITIES.len() {
        for component in 0..COMPONENTS.len() {
            for timeline in 0..TIMELINES.len() {
                for at in -1..=MAX_TIME + 1 {
                    answers.push(
                        latest_at_answer(store, entity, component, timeline, at)
                            .into_iter()
                            .collect(),
                    );
                }
                answers.push(range_answer(
                    store, entity, component, timeline, 0, MAX_TIME,
                ));
                answers.push(range_answer(store, entity, component, timeline, 3, 7));
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

/// `(row id, times on t1 and t2)` of every row the store holds; static rows have none.
fn rows_held(store: &ChunkStore) -> BTreeSet<(u128, [Option<i64>; 2])> {
    store
        .chunks()
        .flat_map(|chunk| {
            (0..chunk.num_rows()).map(move |row| {
                let times = TIMELINES.map(|name| chunk.time_column(name).map(|c| c.times()[row]));
                (chunk.row_ids()[row].as_u128(), times)
            })
        })
        .collect()
}

fn ops() -> impl Strategy<Value = Vec<Op>> {
    prop::collection::vec(op(), 1..40)
}

fn shuffles() -> impl Strategy<Value = Vec<u64>> {
    prop::collection::vec(any::<u64>(), 1..16)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: NUM_CASES, max_shrink_iters: 4096, ..ProptestConfig::default() })]

    #[test]
    fn store_answers_like_the_naive_model(ops in ops(), shuffles in shuffles()) {
        run(&ops, &shuffles)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: PROPERTY_CASES, max_shrink_iters: 4096, ..ProptestConfig::default() })]

    /// Compaction on insert (tiny thresholds) and on demand (tiny and default thresholds)
    /// answer every query exactly as the store without compaction. (Garbage collection is
    /// left out: which chunks it drops depends on how rows are chunked.)
    #[test]
    fn compaction_preserves_all_queries(ops in ops(), shuffles in shuffles()) {
        let ops: Vec<Op> = ops.into_iter().filter(|op| !matches!(op, Op::Gc(_))).collect();
        let plain = run_with(StoreConfig::COMPACTION_OFF, &ops, &shuffles)?.store;
        let expected = all_answers(&plain);
        let compacting = run_with(CONFIGS[1], &ops, &shuffles)?.store;
        prop_assert_eq!(&all_answers(&compacting), &expected);
        for config in [TINY_ON_DEMAND, StoreConfig::COMPACTION_OFF] {
            let mut store = run_with(config, &ops, &shuffles)?.store;
            store.compact();
            store.sanity_check().map_err(TestCaseError::fail)?;
            prop_assert_eq!(&all_answers(&store), &expected, "after compact() with {:?}", config);
            // A second pass finds nothing left to do.
            let again = store.compact();
            prop_assert!(again.is_empty(), "compact() is idempotent; second pass: {:?}", again);
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
        cursor in prop::option::of((0..2usize, 0..=MAX_TIME)),
    ) {
        for config in CONFIGS {
            let mut store = run_with(config, &ops, &shuffles)?.store;
            let before = answers_at_infinity(&store);
            let options = GcOp { target: 0, protect_latest, cursor, protected: None, zero_budget: false }.options();
            store.gc(&options);
            store.sanity_check().map_err(TestCaseError::fail)?;
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
                    }
                }
            });
            let mut randomness = shuffles.iter().copied().cycle();
            for op in &ops {
                harness.apply(op, &mut randomness)?;
            }
            let held: HashMap<ChunkId, Arc<Chunk>> =
                harness.store.chunks().map(|c| (c.id(), Arc::clone(c))).collect();
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
        timeline in 0..2usize,
        min in 0..=MAX_TIME,
        len in 0..6i64,
    ) {
        for config in CONFIGS {
            let mut harness = run_with(config, &ops, &shuffles)?;
            let before = rows_held(&harness.store);
            let op = Op::DropTimeRange { timeline, min, max: min + len };
            harness.apply(&op, &mut shuffles.iter().copied().cycle())?;
            let expected: BTreeSet<_> = before
                .into_iter()
                .filter(|(_, times)| !times[timeline].is_some_and(|t| min <= t && t <= min + len))
                .collect();
            prop_assert_eq!(rows_held(&harness.store), expected);
            harness.full_sweep()?;
        }
    }
}

fn static_row_ids(store: &ChunkStore) -> Vec<u128> {
    let mut ids: Vec<u128> = store
        .chunks()
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
