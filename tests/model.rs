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

mod common;

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

/// A tree five levels deep, with a part that needs escaping and a gap (`e/f` holds nothing).
const ENTITIES: [&str; 9] = [
    "/", "a", "a/b", "a/b/c", "a/b/c/d", "a/d", "a/b\\ c", "e", "e/f/g",
];
/// `x`: `List<Float64>`; `s`: `List<Utf8>`; `p`: `List<FixedSizeList<Int32, 2>>`.
const COMPONENTS: [&str; 3] = ["x", "s", "p"];
const TIMELINES: [(&str, TimeType); 3] = [
    ("t1", TimeType::Sequence),
    ("t2", TimeType::DurationNs),
    ("t3", TimeType::TimestampNs),
];
const MAX_TIME: i64 = 12;
/// Where [`Op::Run`]s start and how far they reach at most: past the small times, so that
/// their chunks overlap nothing else.
const RUN_START: i64 = 100;
const RUN_END: i64 = RUN_START + 40 + 40 * 2;
/// Times at both ends of the valid range.
const EXTREMES: [i64; 4] = [i64::MIN + 1, i64::MIN + 2, i64::MAX - 1, i64::MAX];

/// A cell as the model sees it: `None` null, `Some(vec![])` empty, else instances.
type Cell = Option<Vec<i64>>;

/// What a row holds: data cells, or a Clear (recursive or not).
#[derive(Clone, Debug, PartialEq)]
enum Content {
    Data([Cell; 3]),
    Clear(bool),
}

/// One row of a chunk as the test builds it.
#[derive(Clone, Debug, PartialEq)]
struct ModelRow {
    row_id: u128,
    /// The row's time on each timeline; only those of the chunk's timelines count.
    times: [i64; 3],
    content: Content,
}

/// A chunk as the test builds it: which timelines it has (bit `i`: `TIMELINES[i]`; none:
/// static) and whether it holds data or Clears.
#[derive(Clone, Debug, PartialEq)]
struct ModelChunk {
    id: ChunkId,
    entity: usize,
    timelines: u8,
    is_clear: bool,
    rows: Vec<ModelRow>,
}

impl ModelChunk {
    fn has_timeline(&self, timeline: usize) -> bool {
        self.timelines & (1 << timeline) != 0
    }

    fn is_static(&self) -> bool {
        self.timelines == 0
    }

    /// The row's time on `timeline`, if the chunk has that timeline.
    fn time(&self, row: &ModelRow, timeline: usize) -> Option<i64> {
        self.has_timeline(timeline).then_some(row.times[timeline])
    }

    /// The Arrow chunk.
    fn build(&self) -> Chunk {
        let row_ids = self
            .rows
            .iter()
            .map(|r| RowId::from_u128(r.row_id))
            .collect();
        let mut time_columns = Vec::new();
        for (i, (name, time_type)) in TIMELINES.iter().enumerate() {
            if self.has_timeline(i) {
                let times: Vec<i64> = self.rows.iter().map(|r| r.times[i]).collect();
                let array: ArrayRef = match time_type {
                    TimeType::Sequence => Arc::new(Int64Array::from(times)),
                    TimeType::DurationNs => {
                        Arc::new(PrimitiveArray::<DurationNanosecondType>::from(times))
                    }
                    TimeType::TimestampNs => {
                        Arc::new(PrimitiveArray::<TimestampNanosecondType>::from(times))
                    }
                };
                time_columns.push((Timeline::new(*name, *time_type), array));
            }
        }
        let components = if self.is_clear {
            let flags: Vec<Option<bool>> = self
                .rows
                .iter()
                .map(|r| match r.content {
                    Content::Clear(recursive) => Some(recursive),
                    Content::Data(_) => None,
                })
                .collect();
            vec![(ComponentName::CLEAR_IS_RECURSIVE.into(), bool_list(&flags))]
        } else {
            (0..COMPONENTS.len())
                .map(|c| {
                    let cells: Vec<Cell> = self
                        .rows
                        .iter()
                        .map(|r| match &r.content {
                            Content::Data(cells) => cells[c].clone(),
                            Content::Clear(_) => None,
                        })
                        .collect();
                    (COMPONENTS[c].into(), encode(c, &cells))
                })
                .collect()
        };
        Chunk::try_new(
            self.id,
            path(ENTITIES[self.entity]),
            row_ids,
            time_columns,
            components,
        )
        .unwrap()
    }
}

/// Component `c`'s column for `cells`: floats, strings or pairs `[v, -v]`.
fn encode(c: usize, cells: &[Cell]) -> ArrayRef {
    match c {
        0 => {
            let mut list = ListBuilder::new(Float64Builder::new());
            for cell in cells {
                for &v in cell.iter().flatten() {
                    list.values().append_value(v as f64);
                }
                list.append(cell.is_some());
            }
            Arc::new(list.finish())
        }
        1 => {
            let mut list = ListBuilder::new(StringBuilder::new());
            for cell in cells {
                for v in cell.iter().flatten() {
                    list.values().append_value(v.to_string());
                }
                list.append(cell.is_some());
            }
            Arc::new(list.finish())
        }
        _ => {
            let mut list = ListBuilder::new(FixedSizeListBuilder::new(Int32Builder::new(), 2));
            for cell in cells {
                for &v in cell.iter().flatten() {
                    let v = i32::try_from(v).unwrap();
                    list.values().values().append_value(v);
                    list.values().values().append_value(-v);
                    list.values().append(true);
                }
                list.append(cell.is_some());
            }
            Arc::new(list.finish())
        }
    }
}

/// The values of a cell of component `component`, as [`encode`] wrote them.
fn decode(component: &str, cell: &ArrayRef) -> Vec<i64> {
    match component {
        "x" => cell
            .as_primitive::<Float64Type>()
            .values()
            .iter()
            .map(|&v| v as i64)
            .collect(),
        "s" => cell
            .as_string::<i32>()
            .iter()
            .map(|v| v.unwrap().parse().unwrap())
            .collect(),
        _ => {
            let pairs = cell.as_fixed_size_list();
            let values = pairs.values().as_primitive::<Int32Type>();
            (0..pairs.len())
                .map(|i| {
                    let (v, minus) = (values.value(2 * i), values.value(2 * i + 1));
                    assert_eq!(minus, -v, "pairs are [v, -v]");
                    i64::from(v)
                })
                .collect()
        }
    }
}

/// A stored chunk as the test would have built it.
fn model_chunk_of(chunk: &Chunk) -> ModelChunk {
    let entity = ENTITIES
        .iter()
        .position(|e| path(e) == *chunk.entity_path())
        .unwrap();
    let rows: Vec<(u8, ModelRow)> = (0..chunk.num_rows())
        .map(|row| model_row_of(chunk, row))
        .collect();
    ModelChunk {
        id: chunk.id(),
        entity,
        timelines: rows.first().map_or(0, |(timelines, _)| *timelines),
        is_clear: chunk.component(ComponentName::CLEAR_IS_RECURSIVE).is_some(),
        rows: rows.into_iter().map(|(_, row)| row).collect(),
    }
}

/// Row `row` of a stored chunk as the model writes rows.
fn model_row_of(chunk: &Chunk, row: usize) -> (u8, ModelRow) {
    let mut timelines = 0;
    let mut times = [0; 3];
    for (i, (name, _)) in TIMELINES.iter().enumerate() {
        if let Some(column) = chunk.time_column(name) {
            timelines |= 1 << i;
            times[i] = column.times()[row];
        }
    }
    let content = match chunk.component(ComponentName::CLEAR_IS_RECURSIVE) {
        Some(column) => {
            let cell = column
                .cell(row)
                .expect("model Clear chunks have no null cell");
            Content::Clear(
                cell.as_any()
                    .downcast_ref::<BooleanArray>()
                    .unwrap()
                    .value(0),
            )
        }
        None => Content::Data(COMPONENTS.map(|name| {
            chunk
                .component(name)
                .and_then(|column| column.cell(row))
                .map(|cell| decode(name, &cell))
        })),
    };
    let row_id = chunk.row_ids()[row].as_u128();
    (
        timelines,
        ModelRow {
            row_id,
            times,
            content,
        },
    )
}

#[derive(Clone, Debug)]
enum Op {
    /// A temporal chunk with these timelines; with `reuse_row_ids`, its row ids are those of
    /// an earlier chunk (picked by index, cycled).
    Temporal {
        entity: usize,
        timelines: u8,
        rows: Vec<([i64; 3], [Cell; 3])>,
        reuse_row_ids: Option<usize>,
    },
    Static {
        entity: usize,
        rows: Vec<[Cell; 3]>,
    },
    /// A chunk of one to three Clear rows at one time, each recursive or not.
    Clear {
        entity: usize,
        /// `None`: static; else the timelines and times.
        time: Option<(u8, [i64; 3])>,
        recursive: Vec<bool>,
    },
    /// An earlier chunk again: as the very same chunk, or as its rows under a new id.
    Again {
        pick: usize,
        new_id: bool,
    },
    /// A new temporal chunk under an earlier chunk's id.
    ReuseId {
        pick: usize,
        entity: usize,
        rows: Vec<([i64; 3], [Cell; 3])>,
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
    /// A dataframe view (SEMANTICS.md section 9) compared with the model's table.
    Dataframe(DataframeOp),
    /// The store's chunks written as an `.rrd` and read back: into a fresh store, which
    /// must answer every latest-at as the model does at `at`, and lazily, through the
    /// footer, which must answer as the store does.
    RrdRoundTrip {
        at: i64,
    },
    /// Chunks of one entity in time order past the small times, each ending before the
    /// next starts (a live stream's batches), inserted one by one: with compaction off,
    /// enough of them turn an index into a sequence (more than 32 chunks, which the
    /// small times' overlapping chunks never form), and later ones before or among
    /// them take its other paths (a chunk in front, one in a gap, the general form).
    Run {
        entity: usize,
        timelines: u8,
        start: i64,
        chunks: Vec<Vec<[Cell; 3]>>,
    },
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
        let mut options = GcOptions::everything()
            .with_target(match self.target {
                0 => GcTarget::Everything,
                1 => GcTarget::drop_at_least_fraction(0.5).unwrap(),
                _ => GcTarget::DropAtLeastBytes(1),
            })
            .with_protect_latest(self.protect_latest)
            .with_order(match self.cursor {
                Some((timeline, time)) => GcOrder::furthest_from(TIMELINES[timeline].0, t(time)),
                None => GcOrder::OldestRowIdsFirst,
            });
        if let Some((timeline, min, max)) = self.protected {
            options = options
                .with_protected_time_range(TIMELINES[timeline].0, TimeRange::new(t(min), t(max)));
        }
        if self.zero_budget {
            options = options.with_time_budget(std::time::Duration::ZERO);
        }
        options
    }
}

/// A time: usually small, now and then at an extreme.
fn time() -> impl Strategy<Value = i64> {
    prop_oneof![9 => 0..=MAX_TIME, 1 => prop::sample::select(&EXTREMES[..])]
}

/// A query time: around the small times, among the runs' times, or at an extreme.
fn query_time() -> impl Strategy<Value = i64> {
    prop_oneof![
        9 => -1..=MAX_TIME + 1,
        2 => RUN_START - 1..=RUN_END + 1,
        1 => prop::sample::select(&EXTREMES[..]),
    ]
}

fn cell() -> impl Strategy<Value = Cell> {
    prop_oneof![
        2 => Just(None),
        1 => Just(Some(vec![])),
        4 => (0..100i64).prop_map(|v| Some(vec![v])),
        1 => (0..100i64, 0..100i64).prop_map(|(a, b)| Some(vec![a, b])),
    ]
}

fn temporal_rows() -> impl Strategy<Value = Vec<([i64; 3], [Cell; 3])>> {
    prop::collection::vec(([time(), time(), time()], [cell(), cell(), cell()]), 1..7)
}

/// An [`Op::Run`] of 20 to 40 chunks of one or two rows.
fn run_op() -> impl Strategy<Value = Op> {
    (
        0..ENTITIES.len(),
        1u8..=7,
        RUN_START..=RUN_START + 40,
        prop::collection::vec(
            prop::collection::vec([cell(), cell(), cell()], 1..=2),
            20..=40,
        ),
    )
        .prop_map(|(entity, timelines, start, chunks)| Op::Run {
            entity,
            timelines,
            start,
            chunks,
        })
}

fn op() -> impl Strategy<Value = Op> {
    let entity = 0..ENTITIES.len();
    let temporal = (
        entity.clone(),
        1u8..=7,
        temporal_rows(),
        prop::option::weighted(0.15, any::<usize>()),
    )
        .prop_map(|(entity, timelines, rows, reuse_row_ids)| Op::Temporal {
            entity,
            timelines,
            rows,
            reuse_row_ids,
        });
    let statics = (
        entity.clone(),
        prop::collection::vec([cell(), cell(), cell()], 1..3),
    )
        .prop_map(|(entity, rows)| Op::Static { entity, rows });
    let clear = (
        entity.clone(),
        prop::option::weighted(0.85, (1u8..=7, [time(), time(), time()])),
        prop::collection::vec(any::<bool>(), 1..4),
    )
        .prop_map(|(entity, time, recursive)| Op::Clear {
            entity,
            time,
            recursive,
        });
    let again =
        (any::<usize>(), any::<bool>()).prop_map(|(pick, new_id)| Op::Again { pick, new_id });
    let reuse_id = (any::<usize>(), entity.clone(), temporal_rows())
        .prop_map(|(pick, entity, rows)| Op::ReuseId { pick, entity, rows });
    let latest = (entity.clone(), 0..3usize, 0..3usize, query_time()).prop_map(
        |(entity, component, timeline, at)| Op::LatestAt {
            entity,
            component,
            timeline,
            at,
        },
    );
    let range = (entity, 0..3usize, 0..3usize, query_time(), query_time()).prop_map(
        |(entity, component, timeline, a, b)| Op::Range {
            entity,
            component,
            timeline,
            min: a.min(b),
            max: a.max(b),
        },
    );
    let gc = (
        0u8..3,
        0usize..3,
        prop::option::of((0..3usize, query_time())),
        prop::option::weighted(0.3, (0..3usize, 0..=MAX_TIME, 0..4i64)),
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
        (0..3usize, time(), 0..4i64).prop_map(|(timeline, min, len)| Op::DropTimeRange {
            timeline,
            min,
            max: min.saturating_add(len),
        });
    let drop_entity = (0..ENTITIES.len(), any::<bool>())
        .prop_map(|(entity, recursive)| Op::DropEntity { entity, recursive });
    prop_oneof![
        12 => temporal,
        // About one case in two has a run: each holds more rows than the rest of a
        // case, and the naive model's work grows with its rows.
        1 => run_op(),
        2 => statics,
        4 => clear,
        4 => again,
        2 => reuse_id,
        8 => latest,
        4 => range,
        2 => gc,
        2 => drop_range,
        2 => drop_entity,
        2 => Just(Op::Compact),
        2 => query_time().prop_map(|at| Op::RrdRoundTrip { at }),
        4 => dataframe_op().prop_map(Op::Dataframe),
    ]
}

/// What a query answers: `(time, row id, cell)` (time `None` for static).
type Answer = (Option<i64>, u128, Vec<i64>);

/// A Clear as the model keeps it: `(entity, row id, times, recursive)`; `times` is `None`
/// for a static Clear, else each timeline's time (`None` where the Clear has none).
type ModelClear = (usize, u128, Option<[Option<i64>; 3]>, bool);

/// A temporal data row the model holds: `(entity, timelines, row)`.
type HeldRow = (usize, u8, ModelRow);

/// The naive model: every row in a list.
#[derive(Clone, Default)]
struct Model {
    rows: Vec<HeldRow>,
    /// Every Clear that hides (an overwritten static Clear keeps hiding, SEMANTICS.md section 5).
    clears: Vec<ModelClear>,
    /// The static chunks the store holds, oldest first: each answers for at least one
    /// component (the Clear component counts for a static Clear chunk).
    statics: Vec<ModelChunk>,
}

fn is_strict_ancestor(ancestor: usize, of: usize) -> bool {
    path(ENTITIES[ancestor]).is_ancestor_of(&path(ENTITIES[of]))
}

/// The cell of component `component` in a static row, or the Clear pseudo-component
/// (`component == COMPONENTS.len()`).
fn static_cell(row: &ModelRow, component: usize) -> Option<Vec<i64>> {
    match &row.content {
        Content::Data(cells) => cells.get(component).cloned().flatten(),
        Content::Clear(_) => (component == COMPONENTS.len()).then(Vec::new),
    }
}

impl Model {
    /// The static winner of `(entity, component)`: the greatest row id with a cell, the
    /// later insert on a tie; and the position of its chunk in `statics`.
    fn static_winner(&self, entity: usize, component: usize) -> Option<(usize, Answer)> {
        let mut best: Option<(usize, Answer)> = None;
        for (position, chunk) in self.statics.iter().enumerate() {
            if chunk.entity != entity {
                continue;
            }
            for row in &chunk.rows {
                if let Some(cell) = static_cell(row, component)
                    && best
                        .as_ref()
                        .is_none_or(|(_, (_, id, _))| row.row_id >= *id)
                {
                    best = Some((position, (None, row.row_id, cell)));
                }
            }
        }
        best
    }

    /// Keeps only the static chunks of `entity` that still answer for a component.
    fn drop_overwritten_statics(&mut self, entity: usize) {
        let winners: HashSet<usize> = (0..=COMPONENTS.len())
            .filter_map(|c| self.static_winner(entity, c).map(|(position, _)| position))
            .collect();
        let mut position = 0;
        self.statics.retain(|chunk| {
            let keep = chunk.entity != entity || winners.contains(&position);
            position += 1;
            keep
        });
    }

    /// Does the model hold `row` of `chunk`: a row of the same entity and layout, with the
    /// same row id, times and contents?
    fn holds(&self, chunk: &ModelChunk, row: &ModelRow) -> bool {
        let same_times = |other: &ModelRow| {
            (0..3).all(|i| !chunk.has_timeline(i) || other.times[i] == row.times[i])
        };
        if chunk.is_static() {
            return self.statics.iter().any(|held| {
                held.entity == chunk.entity
                    && held.is_clear == chunk.is_clear
                    && held.rows.contains(row)
            });
        }
        if chunk.is_clear {
            let Content::Clear(recursive) = row.content else {
                return false;
            };
            let times = [0, 1, 2].map(|i| chunk.time(row, i));
            return self
                .clears
                .contains(&(chunk.entity, row.row_id, Some(times), recursive));
        }
        self.rows.iter().any(|(entity, timelines, held)| {
            *entity == chunk.entity
                && *timelines == chunk.timelines
                && held.row_id == row.row_id
                && held.content == row.content
                && same_times(held)
        })
    }

    /// Adds the rows of `chunk` the model does not hold; returns whether any was new.
    fn insert(&mut self, chunk: &ModelChunk) -> bool {
        let new: Vec<ModelRow> = chunk
            .rows
            .iter()
            .filter(|row| !self.holds(chunk, row))
            .cloned()
            .collect();
        if new.is_empty() {
            return false;
        }
        for row in &new {
            if let Content::Clear(recursive) = row.content {
                let times = (!chunk.is_static()).then(|| [0, 1, 2].map(|i| chunk.time(row, i)));
                self.clears
                    .push((chunk.entity, row.row_id, times, recursive));
            }
        }
        if chunk.is_static() {
            self.statics.push(ModelChunk {
                rows: new,
                ..chunk.clone()
            });
            self.drop_overwritten_statics(chunk.entity);
        } else if !chunk.is_clear {
            self.rows.extend(
                new.into_iter()
                    .map(|row| (chunk.entity, chunk.timelines, row)),
            );
        }
        true
    }

    /// Every temporal row of `entity` with a time on `timeline` and a non-null cell of
    /// `component`, as an answer.
    fn temporal_cells(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
    ) -> impl Iterator<Item = Answer> + '_ {
        self.rows.iter().filter_map(move |(e, timelines, row)| {
            let time = (timelines & (1 << timeline) != 0).then_some(row.times[timeline])?;
            let Content::Data(cells) = &row.content else {
                return None;
            };
            let cell = cells[component].clone()?;
            (*e == entity).then_some((Some(time), row.row_id, cell))
        })
    }

    /// Every acceptable latest-at answer (several when rows tie on `(time, row id)` with
    /// different cells); empty for none.
    fn latest_at(&self, entity: usize, component: usize, timeline: usize, at: i64) -> Vec<Answer> {
        let candidates: Vec<Answer> =
            if let Some((_, winner)) = self.static_winner(entity, component) {
                vec![winner]
            } else {
                let rows: Vec<Answer> = self
                    .temporal_cells(entity, component, timeline)
                    .filter(|(time, ..)| time.is_some_and(|time| time <= at))
                    .collect();
                let Some(best) = rows.iter().map(|(time, id, _)| (*time, *id)).max() else {
                    return Vec::new();
                };
                rows.into_iter()
                    .filter(|(time, id, _)| (*time, *id) == best)
                    .collect()
            };
        candidates
            .into_iter()
            .filter(|(time, row_id, _)| !self.is_hidden(entity, timeline, at, *time, *row_id))
            .collect()
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
                    (Some(times), Some(time)) => times[timeline].is_some_and(|clear_time| {
                        clear_time <= at && (time, row_id) <= (clear_time, clear_row_id)
                    }),
                }
            })
    }

    /// The range answer, sorted by `(time, row id, cell)` (the order among rows of equal
    /// index is unspecified, so both sides are compared sorted this way).
    fn range(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
        min: i64,
        max: i64,
    ) -> Vec<Answer> {
        if let Some((_, winner)) = self.static_winner(entity, component) {
            return vec![winner];
        }
        let mut rows: Vec<Answer> = self
            .temporal_cells(entity, component, timeline)
            .filter(|(time, ..)| time.is_some_and(|time| min <= time && time <= max))
            .collect();
        rows.sort();
        rows
    }

    /// Forgets one row per row of `chunk` (a chunk garbage collection removed).
    fn forget_chunk(&mut self, chunk: &Chunk) {
        let entity = ENTITIES
            .iter()
            .position(|e| path(e) == *chunk.entity_path())
            .unwrap();
        for row in 0..chunk.num_rows() {
            let (timelines, row) = model_row_of(chunk, row);
            let position = match row.content {
                Content::Clear(recursive) => {
                    let times =
                        [0, 1, 2].map(|i| (timelines & (1 << i) != 0).then_some(row.times[i]));
                    let clear = (entity, row.row_id, Some(times), recursive);
                    self.clears.iter().position(|c| *c == clear).map(|p| {
                        self.clears.remove(p);
                    })
                }
                Content::Data(_) => {
                    let same = |(e, l, held): &HeldRow| {
                        *e == entity
                            && *l == timelines
                            && held.row_id == row.row_id
                            && held.content == row.content
                            && (0..3).all(|i| l & (1 << i) == 0 || held.times[i] == row.times[i])
                    };
                    self.rows.iter().position(same).map(|p| {
                        self.rows.remove(p);
                    })
                }
            };
            assert!(position.is_some(), "the model held every collected row");
        }
    }
}

/// Row ids unique across the run, in random order: a random high part, a counter low part.
struct RowIds {
    counter: u128,
}

impl RowIds {
    fn next(&mut self, random: u64) -> u128 {
        self.counter += 1;
        (u128::from(random % 1000) << 64) | self.counter
    }
}

/// The stores every sequence runs against: compaction off; compaction with thresholds so
/// small that nearly every insert merges or splits (and the write buffer seals at every
/// second chunk); and compaction whose write buffer never seals on insert (a fanout no
/// sequence reaches: every temporal chunk of fewer rows waits there, in no index, until
/// `compact()`).
const CONFIGS: [StoreConfig; 3] = [
    StoreConfig::COMPACTION_OFF,
    StoreConfig::DEFAULT
        .with_max_rows(4)
        .with_max_rows_unsorted(3)
        .with_max_bytes(256)
        .with_merge_fanout(2),
    StoreConfig::DEFAULT.with_merge_fanout(1 << 20),
];

/// A chunk the test built and inserted (`chunk` is `model` built, or a copy of it).
#[derive(Clone)]
struct Inserted {
    model: ModelChunk,
    chunk: Arc<Chunk>,
    /// Did the store accept it (rather than refuse it for its id)?
    accepted: bool,
}

/// One store, its naive model, and the chunks its events replay to.
struct Harness {
    store: ChunkStore,
    model: Model,
    replayed: HashMap<ChunkId, Arc<Chunk>>,
    row_ids: RowIds,
    /// Every chunk the test built, in order, for the operations that insert one again.
    history: Vec<Inserted>,
}

impl Harness {
    fn new(config: StoreConfig) -> Self {
        Self {
            store: ChunkStore::with_config(config).unwrap(),
            model: Model::default(),
            replayed: HashMap::new(),
            row_ids: RowIds { counter: 0 },
            history: Vec::new(),
        }
    }

    /// See [`Op::RrdRoundTrip`].
    fn check_rrd_round_trip(&self, at: i64) -> Result<(), TestCaseError> {
        use chunkstore::rrd::{self, LazyRecording, RrdWriter, StoreId};
        let fail = |e: &dyn std::fmt::Display| TestCaseError::fail(e.to_string());
        let chunks = self.store.export_chunks();
        let mut writer =
            RrdWriter::new(Vec::new(), StoreId::recording("model", "run")).map_err(|e| fail(&e))?;
        for chunk in &chunks {
            writer.write_chunk(chunk).map_err(|e| fail(&e))?;
        }
        let bytes = writer.finish().map_err(|e| fail(&e))?;
        let contents = rrd::read_rrd(arrow_buffer::Buffer::from(bytes.clone()), false)
            .map_err(|e| fail(&e))?;
        prop_assert_eq!(contents.chunks.len(), chunks.len());
        let mut fresh = ChunkStore::with_config(*self.store.config()).map_err(|e| fail(&e))?;
        for (_, chunk) in contents.chunks {
            fresh.insert(chunk).map_err(|e| fail(&e))?;
        }
        fresh.sanity_check().map_err(|e| fail(&e))?;
        let mut lazy = LazyRecording::from_reader(std::io::Cursor::new(bytes.clone()))
            .map_err(|e| fail(&e))?
            .ok_or_else(|| fail(&"a footer"))?;
        for (entity, entity_name) in ENTITIES.iter().enumerate() {
            for (component, component_name) in COMPONENTS.iter().enumerate() {
                for (timeline, (timeline_name, _)) in TIMELINES.iter().enumerate() {
                    check_latest_at(&fresh, &self.model, entity, component, timeline, at)?;
                    let query = LatestAtQuery::new(*timeline_name, TimeInt::new(at).unwrap());
                    let lazily = lazy
                        .latest_at(&query, &path(entity_name), component_name)
                        .map_err(|e| fail(&e))?
                        .map(|a| (a.time().map(TimeInt::as_i64), a.row_id().as_u128()));
                    let stored = latest_at_answer(&self.store, entity, component, timeline, at)
                        .map(|a| (a.0, a.1));
                    prop_assert_eq!(lazily, stored, "lazy latest-at {}", at);
                }
            }
        }
        // After some lazy answers, the rest decoded and handed over: what an eager read
        // into a store of the same configuration gives (compaction off), answer for answer,
        // ties between rows of one time and row id included (the order of decoding
        // decides those).
        let handed_over = lazy.into_store().map_err(|e| fail(&e))?;
        handed_over.sanity_check().map_err(|e| fail(&e))?;
        let mut fresh = ChunkStore::with_config(*handed_over.config()).map_err(|e| fail(&e))?;
        for chunk in rrd::read_rrd(arrow_buffer::Buffer::from(bytes), false)
            .map_err(|e| fail(&e))?
            .chunks
        {
            fresh.insert(chunk.1).map_err(|e| fail(&e))?;
        }
        prop_assert_eq!(handed_over.stats().num_rows(), fresh.stats().num_rows());
        for (entity, _) in ENTITIES.iter().enumerate() {
            for (component, _) in COMPONENTS.iter().enumerate() {
                for (timeline, _) in TIMELINES.iter().enumerate() {
                    prop_assert_eq!(
                        latest_at_answer(&handed_over, entity, component, timeline, at),
                        latest_at_answer(&fresh, entity, component, timeline, at),
                        "handed-over latest-at {}",
                        at
                    );
                }
            }
        }
        Ok(())
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
                other => prop_assert!(false, "an event of an unknown kind: {other:?}"),
            }
        }
        Ok(())
    }

    /// Inserts a chunk the test built (`chunk` is `model` built, or a copy of it) and checks
    /// the outcome against the rules of SEMANTICS.md section 6: under an id the store holds,
    /// the same chunk changes nothing and another is refused; otherwise exactly the rows the
    /// model does not hold go in, and a chunk with none returns no event.
    #[expect(
        clippy::needless_pass_by_value,
        reason = "the callers build the chunk for this call"
    )]
    fn insert(&mut self, model: ModelChunk, chunk: Arc<Chunk>) -> Result<(), TestCaseError> {
        let held_under_id = self.store.chunk(model.id).map(|held| model_chunk_of(held));
        let mut inserted = Inserted {
            model: model.clone(),
            chunk: Arc::clone(&chunk),
            accepted: true,
        };
        if let Some(held) = held_under_id {
            let same = held == model;
            let before = self.store.to_string();
            match self.store.insert(chunk) {
                Ok(events) => {
                    prop_assert!(same, "another chunk under a held id was accepted");
                    prop_assert!(events.is_empty(), "the same chunk again changes nothing");
                }
                Err(InsertError::ChunkIdConflict { chunk_id, .. }) => {
                    prop_assert!(!same, "the same chunk again was refused");
                    prop_assert_eq!(chunk_id, model.id);
                    prop_assert_eq!(
                        self.store.to_string(),
                        before,
                        "a refused chunk leaves no trace"
                    );
                    inserted.accepted = false;
                }
                Err(other) => return Err(TestCaseError::fail(format!("insert: {other}"))),
            }
            self.history.push(inserted);
            return Ok(());
        }
        self.history.push(inserted);
        let events = self.store.insert(chunk).unwrap();
        let any_new = self.model.insert(&model);
        prop_assert_eq!(
            !events.is_empty(),
            any_new,
            "events iff the chunk had new rows"
        );
        self.replay(&events)
    }

    /// A chunk of `rows` built with fresh row ids, or with those of an earlier chunk.
    fn temporal_chunk(
        &mut self,
        id: ChunkId,
        entity: usize,
        timelines: u8,
        rows: &[([i64; 3], [Cell; 3])],
        reuse_row_ids: Option<usize>,
        randomness: &mut impl Iterator<Item = u64>,
    ) -> ModelChunk {
        let reused: Vec<u128> = reuse_row_ids
            .filter(|_| !self.history.is_empty())
            .map(|pick| {
                let earlier = &self.history[pick % self.history.len()].model;
                earlier.rows.iter().map(|r| r.row_id).collect()
            })
            .unwrap_or_default();
        let rows = rows
            .iter()
            .enumerate()
            .map(|(i, (times, cells))| ModelRow {
                // Only the chunk's timelines have times (the others read as 0, as when a
                // stored chunk is read back).
                times: [0, 1, 2].map(|t| {
                    if timelines & (1 << t) != 0 {
                        times[t]
                    } else {
                        0
                    }
                }),
                row_id: if reused.is_empty() {
                    self.row_ids.next(randomness.next().unwrap_or(0))
                } else {
                    reused[i % reused.len()]
                },
                content: Content::Data(cells.clone()),
            })
            .collect();
        ModelChunk {
            id,
            entity,
            timelines,
            is_clear: false,
            rows,
        }
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
        count_op();
        match op {
            Op::Temporal {
                entity,
                timelines,
                rows,
                reuse_row_ids,
            } => {
                let model = self.temporal_chunk(
                    ChunkId::new(),
                    *entity,
                    *timelines,
                    rows,
                    *reuse_row_ids,
                    randomness,
                );
                let chunk = Arc::new(model.build());
                self.insert(model, chunk)?;
            }
            Op::Static { entity, rows } => {
                let rows = rows
                    .iter()
                    .map(|cells| ModelRow {
                        row_id: self.row_ids.next(randomness.next().unwrap_or(0)),
                        times: [0; 3],
                        content: Content::Data(cells.clone()),
                    })
                    .collect();
                let model = ModelChunk {
                    id: ChunkId::new(),
                    entity: *entity,
                    timelines: 0,
                    is_clear: false,
                    rows,
                };
                let chunk = Arc::new(model.build());
                self.insert(model, chunk)?;
            }
            Op::Clear {
                entity,
                time,
                recursive,
            } => {
                let (timelines, times) = time.unwrap_or((0, [0; 3]));
                let times = [0, 1, 2].map(|t| {
                    if timelines & (1 << t) != 0 {
                        times[t]
                    } else {
                        0
                    }
                });
                let model = ModelChunk {
                    id: ChunkId::new(),
                    entity: *entity,
                    timelines,
                    is_clear: true,
                    rows: recursive
                        .iter()
                        .map(|&recursive| ModelRow {
                            row_id: self.row_ids.next(randomness.next().unwrap_or(0)),
                            times,
                            content: Content::Clear(recursive),
                        })
                        .collect(),
                };
                let chunk = Arc::new(model.build());
                self.insert(model, chunk)?;
            }
            Op::Again { pick, new_id } => {
                if self.history.is_empty() {
                    return Ok(());
                }
                let Inserted {
                    mut model, chunk, ..
                } = self.history[pick % self.history.len()].clone();
                let chunk = if *new_id {
                    model.id = ChunkId::new();
                    Arc::new(model.build())
                } else if pick % 2 == 0 {
                    chunk
                } else {
                    // A copy decoded from the chunk's transport batch, as a file read again.
                    Arc::new(Chunk::from_record_batch(&chunk.to_record_batch().unwrap()).unwrap())
                };
                self.insert(model, chunk)?;
            }
            Op::ReuseId { pick, entity, rows } => {
                if self.history.is_empty() {
                    return Ok(());
                }
                let id = self.history[pick % self.history.len()].model.id;
                let model = self.temporal_chunk(id, *entity, 1, rows, None, randomness);
                let chunk = Arc::new(model.build());
                self.insert(model, chunk)?;
            }
            Op::LatestAt {
                entity,
                component,
                timeline,
                at,
            } => check_latest_at(
                &self.store,
                &self.model,
                *entity,
                *component,
                *timeline,
                *at,
            )?,
            Op::Dataframe(query) => check_dataframe(&self.store, &self.model, query)?,
            Op::Range {
                entity,
                component,
                timeline,
                min,
                max,
            } => check_range(
                &self.store,
                &self.model,
                *entity,
                *component,
                *timeline,
                *min,
                *max,
            )?,
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
                    self.model.forget_chunk(chunk);
                }
                prop_assert!(
                    !collectable || !events.is_empty(),
                    "gc freed nothing although unprotected chunks exist"
                );
            }
            Op::DropTimeRange { timeline, min, max } => {
                let events = self
                    .store
                    .drop_time_range(TIMELINES[*timeline].0, TimeRange::new(t(*min), t(*max)));
                self.replay(&events)?;
                let in_range = |time: Option<i64>| time.is_some_and(|t| *min <= t && t <= *max);
                self.model.rows.retain(|(_, timelines, row)| {
                    !in_range((timelines & (1 << timeline) != 0).then_some(row.times[*timeline]))
                });
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
                self.model.statics.retain(|chunk| !dropped(chunk.entity));
            }
            Op::RrdRoundTrip { at } => self.check_rrd_round_trip(*at)?,
            Op::Run {
                entity,
                timelines,
                start,
                chunks,
            } => {
                let mut time = *start;
                for cells in chunks {
                    let rows: Vec<([i64; 3], [Cell; 3])> = cells
                        .iter()
                        .map(|cells| {
                            time += 1;
                            ([time; 3], cells.clone())
                        })
                        .collect();
                    let model = self.temporal_chunk(
                        ChunkId::new(),
                        *entity,
                        *timelines,
                        &rows,
                        None,
                        randomness,
                    );
                    let chunk = Arc::new(model.build());
                    self.insert(model, chunk)?;
                }
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

    /// A slice of the full sweep, cheap enough to run after every step: for one component
    /// and timeline (chosen by `step`), every entity's latest-at at a probe time and at
    /// `+∞`, and its full range.
    fn light_sweep(&self, step: usize) -> Result<(), TestCaseError> {
        light_sweep(&self.store, &self.model, step)
    }

    /// Every latest-at time and three ranges, for every (entity, component, timeline).
    fn full_sweep(&self) -> Result<(), TestCaseError> {
        full_sweep(&self.store, &self.model)
    }
}

/// Snapshots taken along a sequence, each with a copy of the model as it was then: every
/// later step checks that each still answers as the store did when it was taken, however
/// the store has changed since (SEMANTICS.md section 10).
#[derive(Default)]
struct HeldSnapshots {
    held: Vec<(Snapshot, Model, StoreStatsAndChunks)>,
}

/// What a snapshot's figures and listing were when it was taken.
type StoreStatsAndChunks = (chunkstore::StoreStats, Vec<ChunkId>);

/// A snapshot is taken every this many steps; at most [`MAX_HELD_SNAPSHOTS`] are held.
const SNAPSHOT_EVERY: usize = 4;
const MAX_HELD_SNAPSHOTS: usize = 3;

impl HeldSnapshots {
    fn after_step(&mut self, harness: &Harness, step: usize) -> Result<(), TestCaseError> {
        if step.is_multiple_of(SNAPSHOT_EVERY) {
            if self.held.len() == MAX_HELD_SNAPSHOTS {
                self.held.remove(step / SNAPSHOT_EVERY % MAX_HELD_SNAPSHOTS);
            }
            let snapshot = harness.store.snapshot();
            snapshot
                .sanity_check()
                .map_err(|e| TestCaseError::fail(e.to_string()))?;
            let mut ids: Vec<ChunkId> = harness.store.chunks().map(|c| c.id()).collect();
            ids.sort_unstable();
            let figures = (harness.store.stats(), ids);
            self.held.push((snapshot, harness.model.clone(), figures));
        }
        // One held snapshot per step, in turn (each is swept fully at the end).
        if let Some((snapshot, model, (stats, ids))) = self.held.get(step % self.held.len().max(1))
        {
            light_sweep(snapshot, model, step)?;
            prop_assert_eq!(snapshot.stats(), *stats);
            let mut listed: Vec<ChunkId> = snapshot.chunks().iter().map(|c| c.id()).collect();
            listed.sort_unstable();
            prop_assert_eq!(&listed, ids);
        }
        Ok(())
    }

    fn full_sweep(&self) -> Result<(), TestCaseError> {
        for (snapshot, model, _) in &self.held {
            full_sweep(snapshot, model)?;
        }
        Ok(())
    }
}

/// A few latest-at and range answers of `view` against `model`, varying with `step`.
fn light_sweep(view: &StoreView, model: &Model, step: usize) -> Result<(), TestCaseError> {
    let (component, timeline) = (step % 3, step / 3 % 3);
    let at = i64::try_from(step).unwrap() % (MAX_TIME + 2) - 1;
    let in_runs = RUN_START + i64::try_from(step * 7).unwrap() % (RUN_END - RUN_START + 2);
    for entity in 0..ENTITIES.len() {
        for at in [at, in_runs, i64::MAX] {
            check_latest_at(view, model, entity, component, timeline, at)?;
        }
        check_range(
            view,
            model,
            entity,
            component,
            timeline,
            i64::MIN + 1,
            i64::MAX,
        )?;
    }
    Ok(())
}

/// Every latest-at time and three ranges, for every (entity, component, timeline).
fn full_sweep(view: &StoreView, model: &Model) -> Result<(), TestCaseError> {
    for entity in 0..ENTITIES.len() {
        for component in 0..COMPONENTS.len() {
            for timeline in 0..TIMELINES.len() {
                for at in query_times() {
                    check_latest_at(view, model, entity, component, timeline, at)?;
                }
                for (min, max) in RANGES {
                    check_range(view, model, entity, component, timeline, min, max)?;
                }
            }
        }
    }
    Ok(())
}

/// The latest-at times of a full sweep: every small time, a few among the runs' times
/// (either side of a chunk's edge and inside two-row chunks) and each extreme.
fn query_times() -> impl Iterator<Item = i64> {
    const IN_RUNS: [i64; 5] = [
        RUN_START + 1,
        RUN_START + 2,
        RUN_START + 41,
        RUN_START + 77,
        RUN_END,
    ];
    (-1..=MAX_TIME + 1).chain(IN_RUNS).chain(EXTREMES)
}

/// The ranges of a full sweep.
const RANGES: [(i64, i64); 4] = [
    (i64::MIN + 1, i64::MAX),
    (0, MAX_TIME),
    (3, 7),
    (RUN_START + 10, RUN_START + 70),
];

/// Runs `ops` on a store with `config`, checking everything after every step.
fn run_with(config: StoreConfig, ops: &[Op], shuffles: &[u64]) -> Result<Harness, TestCaseError> {
    let mut harness = Harness::new(config);
    let mut snapshots = HeldSnapshots::default();
    let mut randomness = shuffles.iter().copied().cycle();
    for (step, op) in ops.iter().enumerate() {
        harness.apply(op, &mut randomness)?;
        harness.light_sweep(step)?;
        snapshots.after_step(&harness, step)?;
    }
    harness.full_sweep()?;
    snapshots.full_sweep()?;
    Ok(harness)
}

fn run(ops: &[Op], shuffles: &[u64]) -> Result<(), TestCaseError> {
    for config in CONFIGS {
        run_with(config, ops, shuffles)?;
    }
    Ok(())
}

/// Counts one operation applied to a store in [`OPS_APPLIED`]; with
/// `CHUNKSTORE_MODEL_REPORT` set, prints the total at every ten thousand (the last line a
/// run prints is its total, to within that).
fn count_op() {
    let total = OPS_APPLIED.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
    if total.is_multiple_of(10_000) && std::env::var_os("CHUNKSTORE_MODEL_REPORT").is_some() {
        eprintln!("model: {total} operations applied");
    }
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
        for (name, range) in &options.protected_time_ranges {
            if let Some(column) = chunk.time_column(name) {
                let (lo, hi) = column.time_range();
                if range.min() <= range.max() && lo <= range.max() && range.min() <= hi {
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
                    for row in (0..chunk.num_rows()).filter(|&r| list.is_valid(r)) {
                        let first = usize::try_from(list.value_offsets()[row]).unwrap();
                        let key = (column.times()[row], chunk.row_ids()[row], chunk.id());
                        clears
                            .entry((entity.clone(), timeline.clone(), false))
                            .or_default()
                            .push(key);
                        if flags.value(first) {
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
    store: &StoreView,
    entity: usize,
    component: usize,
    timeline: usize,
    at: i64,
) -> Option<Answer> {
    let query = LatestAtQuery::new(TIMELINES[timeline].0, TimeInt::new(at).unwrap());
    store
        .latest_at(&query, &path(ENTITIES[entity]), COMPONENTS[component])
        .map(|a| {
            (
                a.time().map(TimeInt::as_i64),
                a.row_id().as_u128(),
                decode(COMPONENTS[component], &a.cell()),
            )
        })
}

fn range_answer(
    store: &StoreView,
    entity: usize,
    component: usize,
    timeline: usize,
    min: i64,
    max: i64,
) -> Vec<Answer> {
    let query = RangeQuery::new(TIMELINES[timeline].0, TimeRange::new(t(min), t(max)));
    let rows: Vec<Answer> = store
        .range(&query, &path(ENTITIES[entity]), COMPONENTS[component])
        .iter()
        .map(|r| {
            (
                r.time().map(TimeInt::as_i64),
                r.row_id().as_u128(),
                decode(COMPONENTS[component], &r.cell()),
            )
        })
        .collect();
    assert!(
        rows.windows(2)
            .all(|w| (w[0].0, w[0].1) <= (w[1].0, w[1].1)),
        "range rows ascend by (time, row id)"
    );
    rows
}

fn check_latest_at(
    store: &StoreView,
    model: &Model,
    entity: usize,
    component: usize,
    timeline: usize,
    at: i64,
) -> Result<(), TestCaseError> {
    let ours = latest_at_answer(store, entity, component, timeline, at);
    let acceptable = model.latest_at(entity, component, timeline, at);
    let agrees = match &ours {
        None => acceptable.is_empty(),
        Some(answer) => acceptable.contains(answer),
    };
    prop_assert!(
        agrees,
        "latest-at {}={} {}:{}: store {:?}, model {:?}",
        TIMELINES[timeline].0,
        at,
        ENTITIES[entity],
        COMPONENTS[component],
        ours,
        acceptable
    );
    Ok(())
}

fn check_range(
    store: &StoreView,
    model: &Model,
    entity: usize,
    component: usize,
    timeline: usize,
    min: i64,
    max: i64,
) -> Result<(), TestCaseError> {
    let mut ours = range_answer(store, entity, component, timeline, min, max);
    ours.sort();
    let expected = model.range(entity, component, timeline, min, max);
    prop_assert_eq!(
        ours,
        expected,
        "range {} [{}, {}] {}:{}",
        TIMELINES[timeline].0,
        min,
        max,
        ENTITIES[entity],
        COMPONENTS[component]
    );
    Ok(())
}

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
        .chunks()
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
    #![proptest_config(ProptestConfig { cases: cases(NUM_CASES), max_shrink_iters: 4096, ..ProptestConfig::default() })]

    #[test]
    fn store_answers_like_the_naive_model(ops in ops(), shuffles in shuffles()) {
        run(&ops, &shuffles)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(PROPERTY_CASES), max_shrink_iters: 4096, ..ProptestConfig::default() })]

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
            if !ops.iter().any(|op| matches!(op, Op::Gc(_) | Op::DropTimeRange { .. } | Op::DropEntity { .. })) {
                prop_assert_eq!(harness.store.to_string(), listing);
            }
            harness.full_sweep()?;
            if !ops.iter().any(|op| matches!(op, Op::Gc(_) | Op::DropTimeRange { .. } | Op::DropEntity { .. })) {
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

/// A dataframe query the model test runs: on `timeline`, over `[min, max]` or sampled at
/// `sample`, filled or not, over the entities `contents` picks, in batches of
/// `batch_rows`.
#[derive(Clone, Debug)]
#[allow(
    clippy::struct_excessive_bools,
    reason = "each is a switch of the query, drawn on its own"
)]
struct DataframeOp {
    timeline: usize,
    min: i64,
    max: i64,
    fill: bool,
    sample: Option<Vec<i64>>,
    /// `None`: the default (everything); `Some((e, true))`: `ENTITIES[e]`'s subtree;
    /// `Some((e, false))`: everything but it.
    contents: Option<(usize, bool)>,
    batch_rows: usize,
    /// `Some(mask)`: only the data columns whose position in the full view has its bit
    /// set (`DataframeQuery::with_columns`; the index columns stay); the rows stay the
    /// full view's.
    columns: Option<u64>,
    /// `DataframeQuery::with_tombstone_columns` and `with_semantically_empty_columns`.
    tombstones: bool,
    empty_columns: bool,
    /// `DataframeQuery::with_exact_index_values`.
    exact: bool,
}

impl DataframeOp {
    /// Is data column `position` (in the full view) kept?
    fn keeps(&self, position: usize) -> bool {
        self.columns
            .is_none_or(|mask| position >= 64 || mask & (1 << position) != 0)
    }
}

fn dataframe_op() -> impl Strategy<Value = DataframeOp> {
    (
        0..3usize,
        query_time(),
        0..6i64,
        any::<bool>(),
        prop::option::weighted(0.3, prop::collection::vec(query_time(), 0..6)),
        prop::option::weighted(0.4, (0..ENTITIES.len(), any::<bool>())),
        1..5usize,
        prop::option::weighted(0.3, any::<u64>()),
        (
            prop::bool::weighted(0.8),
            prop::bool::weighted(0.8),
            any::<bool>(),
        ),
    )
        .prop_map(
            |(
                timeline,
                min,
                len,
                fill,
                sample,
                contents,
                batch_rows,
                columns,
                (tombstones, empty_columns, exact),
            )| DataframeOp {
                timeline,
                min,
                max: if len == 5 {
                    i64::MAX
                } else {
                    min.saturating_add(len)
                },
                fill,
                sample,
                contents,
                batch_rows,
                columns,
                tombstones,
                empty_columns,
                exact,
            },
        )
}

/// The component columns of the model, the Clear component last (`COMPONENTS.len()`).
const CLEAR_COMPONENT: usize = COMPONENTS.len();

fn component_name(component: usize) -> &'static str {
    COMPONENTS
        .get(component)
        .copied()
        .unwrap_or(ComponentName::CLEAR_IS_RECURSIVE)
}

/// A table as the model test reads one: data column names, index values, cells per column.
type Table<C> = (Vec<String>, Vec<i64>, Vec<Vec<C>>);

/// A dataframe cell as the model sees it: every acceptable value (rows that tie on their
/// whole index may answer either way); `None` for a null cell.
type DataframeCell = Vec<Cell>;

impl Model {
    /// The Clears that apply to `entity`'s data: its own, and its ancestors' recursive ones.
    fn clears_of(&self, entity: usize) -> impl Iterator<Item = &ModelClear> + '_ {
        self.clears.iter().filter(move |(at, _, _, recursive)| {
            *at == entity || (*recursive && is_strict_ancestor(*at, entity))
        })
    }

    /// The temporal events of a column on `timeline`: `(time, row id, cell)`, data rows
    /// and, for a data component, the Clears that apply (an empty cell).
    fn column_events(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
    ) -> Vec<(i64, u128, Vec<i64>)> {
        let mut events: Vec<(i64, u128, Vec<i64>)> = Vec::new();
        if component == CLEAR_COMPONENT {
            for &(at, row_id, times, recursive) in &self.clears {
                if let (true, Some(times)) = (at == entity, times)
                    && let Some(time) = times[timeline]
                {
                    events.push((time, row_id, vec![i64::from(recursive)]));
                }
            }
        } else {
            events.extend(
                self.temporal_cells(entity, component, timeline)
                    .map(|(time, row_id, cell)| (time.unwrap(), row_id, cell)),
            );
        }
        events
    }

    /// The temporal Clears a column shows as an empty list at their own time on
    /// `timeline`, `(time, row id)`: for a data component, the Clears that apply to it
    /// (which also hide its values); for the Clear component, which no Clear hides, its
    /// strict ancestors' recursive Clears.
    fn column_clear_events(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
    ) -> Vec<(i64, u128)> {
        let marking: Box<dyn Iterator<Item = &ModelClear>> =
            if component == CLEAR_COMPONENT {
                Box::new(self.clears.iter().filter(move |&&(at, _, _, recursive)| {
                    recursive && is_strict_ancestor(at, entity)
                }))
            } else {
                Box::new(self.clears_of(entity))
            };
        marking
            .filter_map(|&(_, row_id, times, _)| Some((times?[timeline]?, row_id)))
            .collect()
    }

    /// The Clears that hide a column's values at or before a time: none for the Clear
    /// component.
    fn column_hiding_clears(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
    ) -> Vec<(i64, u128)> {
        if component == CLEAR_COMPONENT {
            return Vec::new();
        }
        self.column_clear_events(entity, component, timeline)
    }

    fn has_static_clear(&self, entity: usize, component: usize) -> Option<u128> {
        if component == CLEAR_COMPONENT {
            return None;
        }
        self.clears_of(entity)
            .filter(|(_, _, times, _)| times.is_none())
            .map(|&(_, row_id, _, _)| row_id)
            .max()
    }

    /// Does the column exist: static data, or temporal data on some timeline?
    fn column_has_data(&self, entity: usize, component: usize) -> bool {
        self.static_winner(entity, component).is_some()
            || (0..TIMELINES.len())
                .any(|timeline| !self.column_events(entity, component, timeline).is_empty())
    }

    /// Does the column hold a cell that is neither null nor empty (its static winner's,
    /// where it has static data; else any temporal one)? The Clear component's cells are
    /// its one-flag lists.
    fn column_holds_data(&self, entity: usize, component: usize) -> bool {
        if component == CLEAR_COMPONENT {
            return self.column_has_data(entity, component);
        }
        if let Some((_, (_, _, cell))) = self.static_winner(entity, component) {
            return !cell.is_empty();
        }
        (0..TIMELINES.len()).any(|timeline| {
            self.column_events(entity, component, timeline)
                .iter()
                .any(|(_, _, cell)| !cell.is_empty())
        })
    }

    /// A static column's cell: the static winner, or null (no answer) if a static Clear
    /// hides it.
    fn static_column_cell(&self, entity: usize, component: usize) -> Option<DataframeCell> {
        let (position, (_, row_id, mut cell)) = self.static_winner(entity, component)?;
        if component == CLEAR_COMPONENT {
            // `static_cell` stands in an empty cell for a Clear; the column shows its flag.
            let flag =
                self.statics[position]
                    .rows
                    .iter()
                    .rev()
                    .find_map(|row| match row.content {
                        Content::Clear(recursive) if row.row_id == row_id => Some(recursive),
                        _ => None,
                    })?;
            cell = vec![i64::from(flag)];
        }
        let hidden = self
            .has_static_clear(entity, component)
            .is_some_and(|c| row_id <= c);
        Some(vec![if hidden { None } else { Some(cell) }])
    }

    /// The cell of a temporal column at `at` as filling and sampling see it: the
    /// latest-at answer, null where there is none or a Clear hides it.
    fn column_cell_at(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
        at: i64,
    ) -> DataframeCell {
        if self.has_static_clear(entity, component).is_some() {
            return vec![None];
        }
        let events: Vec<_> = self
            .column_events(entity, component, timeline)
            .into_iter()
            .filter(|(time, ..)| *time <= at)
            .collect();
        let best = events
            .iter()
            .map(|(time, row_id, _)| (*time, *row_id))
            .max();
        let clear = self
            .column_hiding_clears(entity, component, timeline)
            .into_iter()
            .filter(|(time, _)| *time <= at)
            .max();
        match (best, clear) {
            (Some(best), Some(clear)) if best <= clear => vec![None],
            (Some(best), _) => events
                .into_iter()
                .filter(|(time, row_id, _)| (*time, *row_id) == best)
                .map(|(_, _, cell)| Some(cell))
                .collect(),
            (None, _) => vec![None],
        }
    }

    /// The sparse cell of a temporal column at `time`, `None` if it has no event there:
    /// the row of greatest row id; an empty list where a Clear at that time came later
    /// (its mark); null where a static Clear hides the row.
    fn column_cell_exactly_at(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
        time: i64,
    ) -> Option<DataframeCell> {
        let events: Vec<_> = self
            .column_events(entity, component, timeline)
            .into_iter()
            .filter(|(t, ..)| *t == time)
            .collect();
        let best = events.iter().map(|(_, row_id, _)| *row_id).max();
        let clear = self
            .column_clear_events(entity, component, timeline)
            .into_iter()
            .filter(|(t, _)| *t == time)
            .map(|(_, row_id)| row_id)
            .max();
        let hidden_by_static = self.has_static_clear(entity, component).is_some();
        match (best, clear) {
            (Some(best), Some(clear)) if best <= clear || hidden_by_static => {
                Some(vec![Some(vec![])])
            }
            (Some(_), None) if hidden_by_static => Some(vec![None]),
            (Some(best), _) => Some(
                events
                    .into_iter()
                    .filter(|(_, row_id, _)| *row_id == best)
                    .map(|(_, _, cell)| Some(cell))
                    .collect(),
            ),
            (None, Some(_)) => Some(vec![Some(vec![])]),
            (None, None) => None,
        }
    }

    /// The model's table: column names, index values, and per column its cells.
    fn dataframe(&self, op: &DataframeOp) -> Table<DataframeCell> {
        let selected = |entity: usize| match op.contents {
            None => true,
            Some((root, include)) => {
                path(ENTITIES[entity]).starts_with(&path(ENTITIES[root])) == include
            }
        };
        let mut columns: Vec<(chunkstore::EntityPath, &str, usize, usize)> = Vec::new();
        for entity in (0..ENTITIES.len()).filter(|&e| selected(e)) {
            for component in 0..=COMPONENTS.len() {
                if self.column_has_data(entity, component)
                    && (op.tombstones || component != CLEAR_COMPONENT)
                    && (op.empty_columns || self.column_holds_data(entity, component))
                {
                    columns.push((
                        path(ENTITIES[entity]),
                        component_name(component),
                        entity,
                        component,
                    ));
                }
            }
        }
        columns.sort_by(|a, b| (&a.0, a.1).cmp(&(&b.0, b.1)));
        let names = columns
            .iter()
            .map(|(p, name, ..)| format!("{p}:{name}"))
            .collect();
        let timeline = op.timeline;
        let times: Vec<i64> = if let Some(values) = &op.sample {
            values.clone()
        } else {
            let mut times = BTreeSet::new();
            for &(_, _, entity, component) in &columns {
                if self.static_winner(entity, component).is_some() {
                    continue;
                }
                for (time, ..) in self.column_events(entity, component, timeline) {
                    times.insert(time);
                }
                for (time, _) in self.column_clear_events(entity, component, timeline) {
                    times.insert(time);
                }
            }
            times
                .into_iter()
                .filter(|t| op.min <= *t && *t <= op.max)
                .collect()
        };
        let cells = columns
            .iter()
            .map(|&(_, _, entity, component)| {
                times
                    .iter()
                    .map(|&time| {
                        if let Some(cell) = self.static_column_cell(entity, component) {
                            return cell;
                        }
                        if op.sample.is_some() && op.exact {
                            return self
                                .column_cell_exactly_at(entity, component, timeline, time)
                                .unwrap_or_else(|| vec![None]);
                        }
                        if op.sample.is_some() {
                            return self.column_cell_at(entity, component, timeline, time);
                        }
                        match self.column_cell_exactly_at(entity, component, timeline, time) {
                            Some(cell) => cell,
                            None if op.fill => {
                                self.column_cell_at(entity, component, timeline, time)
                            }
                            None => vec![None],
                        }
                    })
                    .collect()
            })
            .collect();
        (names, times, cells)
    }
}

/// The store's table for `op`, read back as the model writes tables.
fn dataframe_answer(store: &ChunkStore, op: &DataframeOp) -> Option<Table<Cell>> {
    let mut query = DataframeQuery::new(TIMELINES[op.timeline].0)
        .with_range(TimeRange::new(t(op.min), t(op.max)))
        .with_fill_latest_at(op.fill)
        .with_batch_rows(op.batch_rows)
        .with_tombstone_columns(op.tombstones)
        .with_semantically_empty_columns(op.empty_columns)
        .with_exact_index_values(op.exact);
    if let Some(values) = &op.sample {
        query = query.with_index_values(values.iter().map(|&v| t(v)));
    }
    if let Some((entity, include)) = op.contents {
        let subtree = format!("{}/**", path(ENTITIES[entity])).replacen("//", "/", 1);
        let rule = if include {
            subtree
        } else {
            format!("-{subtree}")
        };
        query = query.with_contents(EntityPathFilter::parse([rule]).unwrap());
    }
    if op.columns.is_some() {
        let Ok(full) = store.dataframe_schema(&query) else {
            return None; // an unknown index: refused with or without columns
        };
        let mut data = 0;
        let kept: Vec<String> = full
            .fields()
            .iter()
            .filter(|f| {
                if !f.name().contains(':') {
                    return true; // index columns
                }
                data += 1;
                op.keeps(data - 1)
            })
            .map(|f| f.name().clone())
            .collect();
        query = query.with_columns(kept);
    }
    // Half the queries read through a stream that owns its snapshot (as the Python
    // package's readers do): the same table either way.
    let stream = if op.batch_rows % 2 == 1 {
        store.snapshot().into_dataframe(&query)
    } else {
        store.dataframe(&query)
    };
    let stream = match stream {
        Ok(stream) => stream,
        Err(chunkstore::DataframeError::UnknownIndex { .. }) => return None,
        Err(e) => panic!("{e}"),
    };
    let schema = stream.schema();
    let names: Vec<String> = schema.fields().iter().map(|f| f.name().clone()).collect();
    let index_position = names
        .iter()
        .position(|n| n == TIMELINES[op.timeline].0)
        .unwrap();
    let data_names: Vec<String> = names.iter().filter(|n| n.contains(':')).cloned().collect();
    let first_data = names.len() - data_names.len();
    let mut times = Vec::new();
    let mut cells: Vec<Vec<Cell>> = vec![Vec::new(); data_names.len()];
    for batch in stream {
        let batch = batch.unwrap();
        assert!(
            batch.num_rows() <= op.batch_rows,
            "a batch holds at most batch_rows rows"
        );
        let index = batch.column(index_position).to_data();
        let index = Int64Array::from(
            index
                .into_builder()
                .data_type(arrow_schema::DataType::Int64)
                .build()
                .unwrap(),
        );
        times.extend(index.iter().map(Option::unwrap));
        for (i, column) in batch.columns()[first_data..].iter().enumerate() {
            let list = column.as_list::<i32>();
            let component = data_names[i].rsplit_once(':').map_or("", |(_, c)| c);
            let component = if data_names[i].ends_with(ComponentName::CLEAR_IS_RECURSIVE) {
                ComponentName::CLEAR_IS_RECURSIVE
            } else {
                component
            };
            for row in 0..list.len() {
                cells[i].push(list.is_valid(row).then(|| {
                    let cell = list.value(row);
                    if component == ComponentName::CLEAR_IS_RECURSIVE {
                        cell.as_boolean()
                            .iter()
                            .map(|b| i64::from(b.unwrap()))
                            .collect()
                    } else {
                        decode(component, &cell)
                    }
                }));
            }
        }
    }
    Some((data_names, times, cells))
}

fn check_dataframe(
    store: &ChunkStore,
    model: &Model,
    op: &DataframeOp,
) -> Result<(), TestCaseError> {
    let (expected_names, expected_times, expected_cells) = model.dataframe(op);
    // Columns left out by `with_columns` are gone; the rows are the full view's.
    let (expected_names, expected_cells): (Vec<String>, Vec<Vec<DataframeCell>>) = expected_names
        .into_iter()
        .zip(expected_cells)
        .enumerate()
        .filter(|(position, _)| op.keeps(*position))
        .map(|(_, column)| column)
        .unzip();
    let Some((names, times, cells)) = dataframe_answer(store, op) else {
        // A timeline the store never saw: the model has nothing on it either.
        let index_known = store.time_type(TIMELINES[op.timeline].0).is_some();
        prop_assert!(!index_known && (op.sample.is_some() || expected_times.is_empty()));
        return Ok(());
    };
    prop_assert_eq!(&names, &expected_names, "dataframe {:?}: columns", op);
    prop_assert_eq!(&times, &expected_times, "dataframe {:?}: index values", op);
    for (((name, ours), expected), _) in names.iter().zip(&cells).zip(&expected_cells).zip(0..) {
        for (row, (cell, acceptable)) in ours.iter().zip(expected).enumerate() {
            prop_assert!(
                acceptable.contains(cell),
                "dataframe {:?}: {} at row {} (time {}): store {:?}, model {:?}",
                op,
                name,
                row,
                times[row],
                cell,
                acceptable
            );
        }
    }
    Ok(())
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
