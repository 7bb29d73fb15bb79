//! The operations a sequence is made of, and the strategies that draw them.

use super::*;

#[derive(Clone, Debug)]
pub(crate) enum Op {
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
    /// Retention: `retain_recent(timeline, span)`.
    Retain {
        timeline: usize,
        span: u64,
    },
    /// On-demand compaction: `compact()`, or `compact_group_by_group` (whose events, one
    /// group's at a time, must replay as `compact()`'s do).
    Compact {
        group_by_group: bool,
    },
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
pub(crate) struct GcOp {
    /// 0: everything; 1: half the heap; 2: a few bytes (one chunk or so).
    pub(crate) target: u8,
    pub(crate) protect_latest: usize,
    /// Furthest from `(timeline, time)` first, else oldest row ids first.
    pub(crate) cursor: Option<(usize, i64)>,
    /// `(timeline, min, max)`.
    pub(crate) protected: Option<(usize, i64, i64)>,
    /// A zero time budget: planning stops after the first chunk it chooses.
    pub(crate) zero_budget: bool,
}

impl GcOp {
    pub(crate) fn options(&self) -> GcOptions {
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
pub(crate) fn time() -> impl Strategy<Value = i64> {
    prop_oneof![9 => 0..=MAX_TIME, 1 => prop::sample::select(&EXTREMES[..])]
}

/// A query time: around the small times, among the runs' times, or at an extreme.
pub(crate) fn query_time() -> impl Strategy<Value = i64> {
    prop_oneof![
        9 => -1..=MAX_TIME + 1,
        2 => RUN_START - 1..=RUN_END + 1,
        1 => prop::sample::select(&EXTREMES[..]),
    ]
}

pub(crate) fn cell() -> impl Strategy<Value = Cell> {
    prop_oneof![
        2 => Just(None),
        1 => Just(Some(vec![])),
        4 => (0..100i64).prop_map(|v| Some(vec![v])),
        1 => (0..100i64, 0..100i64).prop_map(|(a, b)| Some(vec![a, b])),
    ]
}

pub(crate) fn temporal_rows() -> impl Strategy<Value = Vec<([i64; 3], [Cell; 3])>> {
    prop::collection::vec(([time(), time(), time()], [cell(), cell(), cell()]), 1..7)
}

/// An [`Op::Run`] of 20 to 40 chunks of one or two rows.
pub(crate) fn run_op() -> impl Strategy<Value = Op> {
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

pub(crate) fn op() -> impl Strategy<Value = Op> {
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
    let retain = (0..3usize, 0..8u64).prop_map(|(timeline, span)| Op::Retain { timeline, span });
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
        2 => retain,
        2 => any::<bool>().prop_map(|group_by_group| Op::Compact { group_by_group }),
        2 => query_time().prop_map(|at| Op::RrdRoundTrip { at }),
        4 => dataframe_op().prop_map(Op::Dataframe),
    ]
}
