//! What is checked: snapshots held along a sequence, the sweeps of answers, GC's
//! protections, and the comparison of each answer with the model's.

use super::*;

/// Snapshots taken along a sequence, each with a copy of the model as it was then: every
/// later step checks that each still answers as the store did when it was taken, however
/// the store has changed since (SEMANTICS.md section 10).
#[derive(Default)]
pub(crate) struct HeldSnapshots {
    pub(crate) held: Vec<(Snapshot, Model, StoreStatsAndChunks)>,
}

/// What a snapshot's figures and listing were when it was taken.
pub(crate) type StoreStatsAndChunks = (chunkstore::StoreStats, Vec<ChunkId>);

/// A snapshot is taken every this many steps; at most [`MAX_HELD_SNAPSHOTS`] are held.
pub(crate) const SNAPSHOT_EVERY: usize = 4;
pub(crate) const MAX_HELD_SNAPSHOTS: usize = 3;

impl HeldSnapshots {
    pub(crate) fn after_step(
        &mut self,
        harness: &Harness,
        step: usize,
    ) -> Result<(), TestCaseError> {
        if step.is_multiple_of(SNAPSHOT_EVERY) {
            if self.held.len() == MAX_HELD_SNAPSHOTS {
                self.held.remove(step / SNAPSHOT_EVERY % MAX_HELD_SNAPSHOTS);
            }
            let snapshot = harness.store.snapshot();
            snapshot
                .sanity_check()
                .map_err(|e| TestCaseError::fail(e.to_string()))?;
            let mut ids: Vec<ChunkId> = harness.store.chunks_unordered().map(|c| c.id()).collect();
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

    pub(crate) fn full_sweep(&self) -> Result<(), TestCaseError> {
        for (snapshot, model, _) in &self.held {
            full_sweep(snapshot, model)?;
        }
        Ok(())
    }
}

/// A few latest-at and range answers of `view` against `model`, varying with `step`.
pub(crate) fn light_sweep(
    view: &StoreView,
    model: &Model,
    step: usize,
) -> Result<(), TestCaseError> {
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
pub(crate) fn full_sweep(view: &StoreView, model: &Model) -> Result<(), TestCaseError> {
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
pub(crate) fn query_times() -> impl Iterator<Item = i64> {
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
pub(crate) const RANGES: [(i64, i64); 4] = [
    (i64::MIN + 1, i64::MAX),
    (0, MAX_TIME),
    (3, 7),
    (RUN_START + 10, RUN_START + 70),
];

/// Runs `ops` on a store with `config`, checking everything after every step.
pub(crate) fn run_with(
    config: StoreConfig,
    ops: &[Op],
    shuffles: &[u64],
) -> Result<Harness, TestCaseError> {
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

pub(crate) fn run(ops: &[Op], shuffles: &[u64]) -> Result<(), TestCaseError> {
    for config in CONFIGS {
        run_with(config, ops, shuffles)?;
    }
    Ok(())
}

/// Counts one operation applied to a store in [`OPS_APPLIED`]; with
/// `CHUNKSTORE_MODEL_REPORT` set, prints the total at every ten thousand (the last line a
/// run prints is its total, to within that).
pub(crate) fn count_op() {
    let total = OPS_APPLIED.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
    if total.is_multiple_of(10_000) && std::env::var_os("CHUNKSTORE_MODEL_REPORT").is_some() {
        eprintln!("model: {total} operations applied");
    }
}

/// `(time, row id, chunk)`: how the store orders cells and Clears across chunks.
pub(crate) type IndexKey = (i64, RowId, ChunkId);

/// The chunks `options` must keep, found by brute force over the store's chunks: static
/// ones, those touching a protected range, the `n` latest of every (entity, timeline,
/// component), and those holding the `n` latest Clears (flat or recursive, and recursive
/// alone) of every (entity, timeline).
pub(crate) fn protected_chunks(store: &ChunkStore, options: &GcOptions) -> HashSet<ChunkId> {
    let mut protected = HashSet::new();
    // (entity, timeline, component) → (max time, max row id, chunk) per chunk.
    let mut latest: HashMap<(String, String, String), Vec<IndexKey>> = HashMap::new();
    // (entity, timeline, recursive only?) → every Clear row (time, row id, chunk).
    let mut clears: HashMap<(String, String, bool), Vec<IndexKey>> = HashMap::new();
    for chunk in store.chunks_unordered() {
        if chunk.is_static() {
            protected.insert(chunk.id());
            continue;
        }
        for (name, range) in &options.protected_time_ranges {
            if let Some(column) = chunk.time_column(name)
                && column.time_range().intersects(*range)
            {
                protected.insert(chunk.id());
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

pub(crate) fn latest_at_answer(
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

pub(crate) fn range_answer(
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

pub(crate) fn check_latest_at(
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

pub(crate) fn check_range(
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
