//! One store beside its naive model: each operation applied to both, one method per
//! operation, and the checks after every step.

use super::*;
use chunkstore::rrd::{DecodedLogMsg, LogMsg};

/// Row ids unique across the run, in random order: a random high part, a counter low part.
pub(crate) struct RowIds {
    pub(crate) counter: u128,
}

impl RowIds {
    pub(crate) fn next(&mut self, random: u64) -> u128 {
        self.counter += 1;
        (u128::from(random % 1000) << 64) | self.counter
    }
}

/// The stores every sequence runs against: compaction off; compaction with thresholds so
/// small that nearly every insert merges or splits (and the write buffer seals at every
/// second chunk); and compaction whose write buffer never seals on insert (a fanout no
/// sequence reaches: every temporal chunk of fewer rows waits there, in no index, until
/// `compact()`).
pub(crate) const CONFIGS: [StoreConfig; 3] = [
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
pub(crate) struct Inserted {
    pub(crate) model: ModelChunk,
    pub(crate) chunk: Arc<Chunk>,
    /// Did the store accept it (rather than refuse it for its id)?
    pub(crate) accepted: bool,
}

/// One store, its naive model, and the chunks its events replay to.
pub(crate) struct Harness {
    pub(crate) store: ChunkStore,
    pub(crate) model: Model,
    pub(crate) replayed: HashMap<ChunkId, Arc<Chunk>>,
    pub(crate) row_ids: RowIds,
    /// Every chunk the test built, in order, for the operations that insert one again.
    pub(crate) history: Vec<Inserted>,
}

impl Harness {
    pub(crate) fn new(config: StoreConfig) -> Self {
        Self {
            store: ChunkStore::with_config(config).unwrap(),
            model: Model::default(),
            replayed: HashMap::new(),
            row_ids: RowIds { counter: 0 },
            history: Vec::new(),
        }
    }

    /// See [`Op::RrdRoundTrip`].
    pub(crate) fn check_rrd_round_trip(&self, at: i64) -> Result<(), TestCaseError> {
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
    pub(crate) fn replay(&mut self, events: &[StoreEvent]) -> Result<(), TestCaseError> {
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
    pub(crate) fn insert(
        &mut self,
        model: ModelChunk,
        chunk: Arc<Chunk>,
    ) -> Result<(), TestCaseError> {
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
    pub(crate) fn temporal_chunk(
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

    /// Applies `op` to the store and the model (one method per operation), then checks the
    /// store's sanity and that its events replay to its chunks.
    pub(crate) fn apply(
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
            } => self.insert_temporal(*entity, *timelines, rows, *reuse_row_ids, randomness)?,
            Op::Static { entity, rows } => self.insert_static(*entity, rows, randomness)?,
            Op::Clear {
                entity,
                time,
                recursive,
            } => self.insert_clear(*entity, *time, recursive, randomness)?,
            Op::Again { pick, new_id } => self.insert_again(*pick, *new_id)?,
            Op::ReuseId { pick, entity, rows } => {
                self.reuse_id(*pick, *entity, rows, randomness)?;
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
            Op::Gc(gc) => self.gc(gc)?,
            Op::DropTimeRange { timeline, min, max } => {
                self.drop_time_range(*timeline, *min, *max)?;
            }
            Op::DropEntity { entity, recursive } => self.drop_entity(*entity, *recursive)?,
            Op::Retain { timeline, span } => self.retain_recent(*timeline, *span)?,
            Op::RrdRoundTrip { at } => self.check_rrd_round_trip(*at)?,
            Op::Run {
                entity,
                timelines,
                start,
                chunks,
            } => self.insert_run(*entity, *timelines, *start, chunks, randomness)?,
            Op::Compact { group_by_group } => self.compact(*group_by_group)?,
        }
        self.check_after(op)
    }

    fn insert_temporal(
        &mut self,
        entity: usize,
        timelines: u8,
        rows: &[([i64; 3], [Cell; 3])],
        reuse_row_ids: Option<usize>,
        randomness: &mut impl Iterator<Item = u64>,
    ) -> Result<(), TestCaseError> {
        let model = self.temporal_chunk(
            ChunkId::new(),
            entity,
            timelines,
            rows,
            reuse_row_ids,
            randomness,
        );
        let chunk = Arc::new(model.build());
        self.insert(model, chunk)
    }

    fn insert_static(
        &mut self,
        entity: usize,
        rows: &[[Cell; 3]],
        randomness: &mut impl Iterator<Item = u64>,
    ) -> Result<(), TestCaseError> {
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
            entity,
            timelines: 0,
            is_clear: false,
            rows,
        };
        let chunk = Arc::new(model.build());
        self.insert(model, chunk)
    }

    fn insert_clear(
        &mut self,
        entity: usize,
        time: Option<(u8, [i64; 3])>,
        recursive: &[bool],
        randomness: &mut impl Iterator<Item = u64>,
    ) -> Result<(), TestCaseError> {
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
            entity,
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
        self.insert(model, chunk)
    }

    /// An earlier chunk again: the very chunk, a copy decoded from its transport batch, a
    /// copy sent as a server receives it (a gRPC `LogMsg`, LZ4 or not, decoded), or its
    /// rows under a new id.
    fn insert_again(&mut self, pick: usize, new_id: bool) -> Result<(), TestCaseError> {
        if self.history.is_empty() {
            return Ok(());
        }
        let Inserted {
            mut model, chunk, ..
        } = self.history[pick % self.history.len()].clone();
        let chunk = if new_id {
            model.id = ChunkId::new();
            Arc::new(model.build())
        } else {
            match pick % 4 {
                0 => chunk,
                1 | 3 => {
                    // As a server receives it: an `ArrowMsg` in a `WriteMessagesRequest`.
                    // Encoding sorts a chunk's rows by row id (as Rerun's format wants), so
                    // an unsorted chunk comes back as another chunk under its id (SEMANTICS.md
                    // section 6 refuses it); the model sees what arrived.
                    let store = chunkstore::rrd::StoreId::recording("model", "test");
                    let msg = LogMsg::from_chunk(&store, &chunk, pick % 4 == 1).unwrap();
                    let wire = arrow_buffer::Buffer::from(msg.encode_envelope());
                    match LogMsg::decode_envelope(&wire).unwrap().decode().unwrap() {
                        DecodedLogMsg::Chunk { chunk, .. } => {
                            model = model_chunk_of(&chunk);
                            Arc::new(chunk)
                        }
                        other => return Err(TestCaseError::fail(format!("decoded {other:?}"))),
                    }
                }
                // A copy decoded from the chunk's transport batch, as a file read again.
                _ => Arc::new(Chunk::from_record_batch(&chunk.to_record_batch().unwrap()).unwrap()),
            }
        };
        self.insert(model, chunk)
    }

    fn reuse_id(
        &mut self,
        pick: usize,
        entity: usize,
        rows: &[([i64; 3], [Cell; 3])],
        randomness: &mut impl Iterator<Item = u64>,
    ) -> Result<(), TestCaseError> {
        if self.history.is_empty() {
            return Ok(());
        }
        let id = self.history[pick % self.history.len()].model.id;
        let model = self.temporal_chunk(id, entity, 1, rows, None, randomness);
        let chunk = Arc::new(model.build());
        self.insert(model, chunk)
    }

    /// A collection: nothing protected goes, and something goes where something may.
    fn gc(&mut self, gc: &GcOp) -> Result<(), TestCaseError> {
        let options = gc.options();
        let protected = protected_chunks(&self.store, &options);
        let collectable = self
            .store
            .chunks_unordered()
            .any(|c| !protected.contains(&c.id()));
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
        Ok(())
    }

    fn drop_time_range(
        &mut self,
        timeline: usize,
        min: i64,
        max: i64,
    ) -> Result<(), TestCaseError> {
        let events = self
            .store
            .drop_time_range(TIMELINES[timeline].0, TimeRange::new(t(min), t(max)));
        self.replay(&events)?;
        let in_range = |time: Option<i64>| time.is_some_and(|t| min <= t && t <= max);
        self.model.rows.retain(|(_, timelines, row)| {
            !in_range((timelines & (1 << timeline) != 0).then_some(row.times[timeline]))
        });
        self.model
            .clears
            .retain(|(_, _, times, _)| !times.is_some_and(|times| in_range(times[timeline])));
        Ok(())
    }

    /// Retention, checked against the model's own newest time on the timeline: the rows
    /// (and Clears) below `newest − span` go, the newest time stays.
    fn retain_recent(&mut self, timeline: usize, span: u64) -> Result<(), TestCaseError> {
        let on_timeline = |timelines: u8| timelines & (1 << timeline) != 0;
        let newest = self
            .model
            .rows
            .iter()
            .filter(|(_, timelines, _)| on_timeline(*timelines))
            .map(|(_, _, row)| row.times[timeline])
            .chain(
                self.model
                    .clears
                    .iter()
                    .filter_map(|(_, _, times, _)| times.and_then(|times| times[timeline])),
            )
            .max();
        let name = TIMELINES[timeline].0;
        let events = self.store.retain_recent(name, span);
        self.replay(&events)?;
        let Some(newest) = newest else {
            prop_assert!(
                events.is_empty(),
                "retention dropped data from an empty timeline"
            );
            return Ok(());
        };
        let keep_from = i128::from(newest) - i128::from(span);
        let old = |time: Option<i64>| time.is_some_and(|t| i128::from(t) < keep_from);
        self.model.rows.retain(|(_, timelines, row)| {
            !old(on_timeline(*timelines).then_some(row.times[timeline]))
        });
        self.model
            .clears
            .retain(|(_, _, times, _)| !times.is_some_and(|times| old(times[timeline])));
        prop_assert_eq!(
            self.store.time_range(name).map(|r| r.max().as_i64()),
            Some(newest),
            "retention moved the newest time"
        );
        Ok(())
    }

    fn drop_entity(&mut self, entity: usize, recursive: bool) -> Result<(), TestCaseError> {
        let events = self.store.drop_entity(&path(ENTITIES[entity]), recursive);
        self.replay(&events)?;
        let dropped = |e: usize| e == entity || (recursive && is_strict_ancestor(entity, e));
        self.model.rows.retain(|(e, ..)| !dropped(*e));
        self.model.clears.retain(|(e, ..)| !dropped(*e));
        self.model.statics.retain(|chunk| !dropped(chunk.entity));
        Ok(())
    }

    /// A run of chunks in time order from `start`, each one time after the last.
    fn insert_run(
        &mut self,
        entity: usize,
        timelines: u8,
        start: i64,
        chunks: &[Vec<[Cell; 3]>],
        randomness: &mut impl Iterator<Item = u64>,
    ) -> Result<(), TestCaseError> {
        let mut time = start;
        for cells in chunks {
            let rows: Vec<([i64; 3], [Cell; 3])> = cells
                .iter()
                .map(|cells| {
                    time += 1;
                    ([time; 3], cells.clone())
                })
                .collect();
            let model =
                self.temporal_chunk(ChunkId::new(), entity, timelines, &rows, None, randomness);
            let chunk = Arc::new(model.build());
            self.insert(model, chunk)?;
        }
        Ok(())
    }

    fn compact(&mut self, group_by_group: bool) -> Result<(), TestCaseError> {
        let events = if group_by_group {
            let mut events = Vec::new();
            self.store
                .compact_group_by_group(|group| events.extend(group));
            events
        } else {
            self.store.compact()
        };
        self.replay(&events)?;
        for event in &events {
            if let StoreEvent::Deletion { reason, .. } = event {
                prop_assert_eq!(*reason, DeletionReason::Compaction);
            }
        }
        Ok(())
    }

    /// After every operation: the store's sanity check, and its events replayed give
    /// exactly its chunks.
    fn check_after(&self, op: &Op) -> Result<(), TestCaseError> {
        if let Err(broken) = self.store.sanity_check() {
            return Err(TestCaseError::fail(format!(
                "sanity_check after {op:?}: {broken}"
            )));
        }
        let held: BTreeSet<ChunkId> = self.store.chunks_unordered().map(|c| c.id()).collect();
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
    pub(crate) fn light_sweep(&self, step: usize) -> Result<(), TestCaseError> {
        light_sweep(&self.store, &self.model, step)
    }

    /// Every latest-at time and three ranges, for every (entity, component, timeline).
    pub(crate) fn full_sweep(&self) -> Result<(), TestCaseError> {
        full_sweep(&self.store, &self.model)
    }
}
