//! The store's own sanity check: every index, order and figure recounted from the chunks.

use std::collections::BTreeMap;
use std::sync::Arc;

use arrow_schema::DataType;

use super::entity::{ComponentType, EntityIndex};
use super::view::{EntityView, StaticWinner};
use super::{ChunkStore, RewriteMark, StoreConfig, StoredChunk, TimelineChunks};
use crate::ordered::OrderedSet;
use crate::sanity::{SanityError, Structure, ensure};
use crate::small_map::SmallMap;
use crate::stats::{BufferLedger, EntityStats, StoreLedgers, StoreStats};
use crate::{Chunk, ChunkId, ComponentName, EntityPath, RowId};

/// What [`ChunkStore::recount`] counts from the chunks.
struct Recount<'a> {
    stats: StoreStats,
    ledgers: StoreLedgers,
    entities: ahash::HashMap<&'a EntityPath, (EntityStats, BufferLedger)>,
    by_row_id: OrderedSet<(RowId, ChunkId)>,
    per_timeline: BTreeMap<&'a str, TimelineChunks>,
    outside_global_orders: usize,
}

/// Debug builds check the store after every public mutation while it holds at most this
/// many chunks.
const DEBUG_CHECK_ALWAYS_MAX_CHUNKS: usize = 64;

impl ChunkStore {
    /// Only a temporal chunk compaction waits for may be left out of the store-wide
    /// orders (part of [`ChunkStore::sanity_check`]).
    fn check_outside_global_orders(&self, chunk: &Arc<Chunk>) -> Result<(), SanityError> {
        let waiting = self
            .entities
            .get(chunk.entity_path())
            .is_some_and(|e| self.waiting_chunks(e).any(|c| Arc::ptr_eq(c, chunk)));
        if chunk.is_static() || !waiting {
            return Err(SanityError::new(
                Structure::Store,
                "only a temporal chunk compaction waits for is left out of the store-wide \
                 orders",
            )
            .at(chunk.id()));
        }
        Ok(())
    }

    /// The store-wide orders hold exactly the expected chunks (part of
    /// [`ChunkStore::sanity_check`]).
    fn check_global_orders(
        &self,
        outside_global_orders: usize,
        expected_by_row_id: &OrderedSet<(RowId, ChunkId)>,
        expected_per_timeline: &BTreeMap<&str, TimelineChunks>,
    ) -> Result<(), SanityError> {
        let Self {
            temporal_by_row_id,
            temporal_per_timeline,
            num_outside_global_orders,
            global_orders_set_aside,
            ..
        } = self;
        ensure(
            !global_orders_set_aside,
            Structure::Store,
            "the store-wide orders are kept between mutations (a mutation that sets them \
             aside restores them before it ends)",
        )?;
        if outside_global_orders != *num_outside_global_orders {
            return Err(SanityError::new(
                Structure::Store,
                "the chunks outside the store-wide orders are counted",
            )
            .at(format_args!(
                "{num_outside_global_orders} counted, {outside_global_orders} are"
            )));
        }
        temporal_by_row_id.sanity_check()?;
        ensure(
            expected_by_row_id == temporal_by_row_id,
            Structure::Store,
            "the row-id order holds exactly the temporal chunks in the store-wide orders",
        )?;
        for TimelineChunks {
            by_min_time,
            by_max_time,
        } in temporal_per_timeline.values()
        {
            by_min_time.sanity_check()?;
            by_max_time.sanity_check()?;
        }
        let timelines_match = expected_per_timeline.len() == temporal_per_timeline.len()
            && expected_per_timeline.iter().all(|(name, expected)| {
                temporal_per_timeline.get(*name).is_some_and(|kept| {
                    kept.by_min_time == expected.by_min_time
                        && kept.by_max_time == expected.by_max_time
                })
            });
        ensure(
            timelines_match,
            Structure::Store,
            "the per-timeline orders hold exactly the temporal chunks in the store-wide orders",
        )
    }

    /// Debug builds check the whole store at the end of every public mutation while it
    /// holds at most [`DEBUG_CHECK_ALWAYS_MAX_CHUNKS`] chunks (where unit tests live), and
    /// beyond that after the mutations whose count is a power of two: O(1) amortized per
    /// mutation, and it keeps firing however large the store grows and whatever its chunk
    /// sizes. The model test checks after every step regardless.
    ///
    /// # Panics
    /// In debug builds, on a broken invariant (a bug in this crate).
    pub(crate) fn debug_check_on_schedule(&self) {
        if cfg!(debug_assertions)
            && (self.chunks.len() <= DEBUG_CHECK_ALWAYS_MAX_CHUNKS
                || self.num_mutations.is_power_of_two())
            && let Err(error) = self.sanity_check()
        {
            panic!("after mutation {}: {error}", self.num_mutations);
        }
    }

    /// Checks every invariant of the store and its indices, recounting every figure from
    /// the chunks. Cheap enough for tests to call after every mutation; debug builds call
    /// it at the end of public mutations (see `debug_check_on_schedule`).
    ///
    /// # Errors
    /// The first broken invariant: a bug in this crate.
    pub fn sanity_check(&self) -> Result<(), SanityError> {
        let Self {
            config,
            view,
            chunks: _,                    // recounted by `recount`
            entities: _,                  // checked by `check_entities`
            temporal_by_row_id: _,        // checked by `check_global_orders`
            temporal_per_timeline: _,     // checked by `check_global_orders`
            num_outside_global_orders: _, // checked by `check_global_orders`
            global_orders_set_aside: _,   // checked by `check_global_orders`
            num_rewrites: _,              // bounds the marks, checked by `recount`
            ledgers: kept_ledgers,
            num_mutations: _, // a count of calls: nothing to check it against
            subscribers: _,   // callbacks: nothing to check
        } = self;
        // Its own pieces (each entity's indices, the Clear index); its figures and
        // timeline types against the chunks below.
        view.sanity_check()?;
        let stats = &view.stats;
        config.validate().map_err(|error| {
            SanityError::new(Structure::Config, "thresholds are valid").at(error)
        })?;
        let Recount {
            stats: expected,
            ledgers,
            entities: expected_entities,
            by_row_id: expected_by_row_id,
            per_timeline: expected_per_timeline,
            outside_global_orders,
        } = self.recount()?;
        if expected != stats.contents() {
            return Err(
                SanityError::new(Structure::Stats, "the store's figures match its chunks")
                    .at(format_args!("kept {stats:?}, counted {expected:?}")),
            );
        }
        ensure(
            ledgers == *kept_ledgers,
            Structure::Stats,
            "the buffer ledgers count each shared buffer's chunks",
        )?;
        self.check_global_orders(
            outside_global_orders,
            &expected_by_row_id,
            &expected_per_timeline,
        )?;
        self.check_entities(&expected_entities)
    }

    /// Every figure and order recounted from the chunks through fresh ledgers, checking
    /// each chunk on the way (part of [`ChunkStore::sanity_check`]).
    fn recount(&self) -> Result<Recount<'_>, SanityError> {
        let Self {
            chunks,
            view,
            entities,
            num_rewrites,
            ..
        } = self;
        let time_types = &view.time_types;
        let mut expected = StoreStats::default();
        let mut ledgers = StoreLedgers::default();
        let mut expected_entities: ahash::HashMap<&EntityPath, (EntityStats, BufferLedger)> =
            ahash::HashMap::default();
        let mut expected_by_row_id = OrderedSet::default();
        let mut expected_per_timeline: BTreeMap<&str, TimelineChunks> = BTreeMap::new();
        let mut outside_global_orders = 0;
        let mut pieces_per_rewrite: ahash::HashMap<u64, usize> = ahash::HashMap::default();
        for (
            &id,
            StoredChunk {
                chunk,
                ledgered,
                in_global_orders,
                buffered,
                rewritten_by,
            },
        ) in chunks
        {
            chunk.sanity_check()?;
            ensure(
                chunk.id() == id,
                Structure::Store,
                "a chunk is keyed by its id",
            )?;
            ensure(
                !*buffered || (!*in_global_orders && !chunk.is_static()),
                Structure::Store,
                "a buffered chunk is temporal and outside the store-wide orders",
            )?;
            if let Some(mark) = rewritten_by {
                check_rewrite_mark(chunk, *mark, *num_rewrites, &mut pieces_per_rewrite)?;
            }
            let (entity_stats, entity_ledger) =
                expected_entities.entry(chunk.entity_path()).or_default();
            crate::stats::account(
                chunk,
                *ledgered,
                true,
                &mut expected,
                &mut ledgers,
                entity_stats,
                entity_ledger,
            );
            for column in chunk.time_columns() {
                let timeline = column.timeline();
                if time_types.get(timeline.name()) != Some(&timeline.time_type()) {
                    return Err(SanityError::new(
                        Structure::Store,
                        "a chunk's timelines have the store's types",
                    )
                    .at(format_args!("{id}: {timeline:?}")));
                }
                if *in_global_orders {
                    let bounds = column.time_range();
                    let (min, max) = (bounds.min(), bounds.max());
                    let per_timeline = expected_per_timeline.entry(timeline.name()).or_default();
                    per_timeline.by_min_time.insert((min, id));
                    per_timeline.by_max_time.insert((max, id));
                }
            }
            if !*in_global_orders {
                self.check_outside_global_orders(chunk)?;
                outside_global_orders += 1;
            } else if !chunk.is_static() {
                expected_by_row_id.insert((chunk.row_id_range().0, id));
            }
            if !entities.contains_key(chunk.entity_path()) {
                return Err(
                    SanityError::new(Structure::Store, "a chunk's entity is indexed").at(id),
                );
            }
        }
        // Each entity's own bookkeeping, and large indices' extra heap, which the store
        // adds as indices grow and shrink.
        for (path, entity) in view.entities.iter() {
            let extra = entity.extra_index_heap_bytes();
            expected.heap_bytes += extra + crate::stats::ENTITY_BYTES;
            expected.temporal_heap_bytes += extra;
            if let Some((entity_stats, _)) = expected_entities.get_mut(path) {
                entity_stats.heap_bytes += extra + crate::stats::ENTITY_BYTES;
            }
        }
        Ok(Recount {
            stats: expected,
            ledgers,
            entities: expected_entities,
            by_row_id: expected_by_row_id,
            per_timeline: expected_per_timeline,
            outside_global_orders,
        })
    }

    /// Each entity's figures equal `expected` (a recount of its chunks), and its own
    /// sanity check passes (part of [`ChunkStore::sanity_check`]).
    fn check_entities(
        &self,
        expected: &ahash::HashMap<&EntityPath, (EntityStats, BufferLedger)>,
    ) -> Result<(), SanityError> {
        ensure(
            self.entities.len() == self.view.entities.len(),
            Structure::Entity,
            "the writer's entities are the view's",
        )?;
        for (path, entity) in &self.entities {
            // The writer's part knows where the view is.
            let Some(view) = self
                .view
                .entities
                .at(entity.slot)
                .filter(|_| self.view.entities.slot(path) == Some(entity.slot))
            else {
                return Err(SanityError::new(
                    Structure::Entity,
                    "the writer's entities are the view's, in the slot it keeps",
                )
                .at(path));
            };
            let counted = expected.get(path).map(|e| &e.0);
            let num_chunks = counted.map_or(0, |c| c.num_static_chunks + c.num_temporal_chunks);
            let num_listed = entity.chunk_ids.len() + view.buffered.chunks().count();
            if num_chunks != num_listed as u64 {
                return Err(SanityError::new(
                    Structure::Entity,
                    "its chunk ids and its write buffer list all its chunks",
                )
                .at(path));
            }
            if counted != Some(&view.stats) {
                return Err(SanityError::new(
                    Structure::Stats,
                    "an entity's figures match its chunks",
                )
                .at(format_args!(
                    "{path}: kept {:?}, counted {counted:?}",
                    view.stats
                )));
            }
            if expected.get(path).map(|e| &e.1) != Some(&entity.ledger) {
                return Err(SanityError::new(
                    Structure::Stats,
                    "an entity's buffer ledger counts each shared buffer's chunks",
                )
                .at(path));
            }
            entity.sanity_check(path, view, &self.chunks, &self.config)?;
        }
        Ok(())
    }
}

impl EntityIndex {
    fn sanity_check(
        &self,
        path: &EntityPath,
        view: &EntityView,
        chunks: &ahash::HashMap<ChunkId, StoredChunk>,
        config: &StoreConfig,
    ) -> Result<(), SanityError> {
        let fail = |invariant| SanityError::new(Structure::Entity, invariant).at(path);
        let Self {
            slot: _, // checked by `check_entities`
            element_types,
            static_chunks,
            chunk_ids,
            max_row_id,
            pending,
            large_index_bytes,
            ledger: _, // recounted by the store (`check_entities`)
            buffer_columns,
        } = self;
        // The view's own invariants were checked with the view; here, what it must agree
        // with: the writer's part and the chunks.
        let EntityView {
            component_types,
            static_winners,
            temporal_per_timeline_per_component,
            unindexed,
            buffered,
            stats: _, // recounted by the store (`check_entities`)
        } = view;
        let types_agree = component_types.len() == element_types.len()
            && element_types.iter().all(|(name, known)| {
                component_types
                    .get(name)
                    .is_some_and(|t| t.equals_datatype(&known.element_type))
            });
        ensure(
            types_agree,
            Structure::Entity,
            "the view's component types are the writer's",
        )?;
        if unindexed.iter().any(|c| !chunk_ids.contains(&c.id())) {
            return Err(fail("an unindexed chunk is the store's"));
        }
        buffer_columns.sanity_check(buffered, path)?;
        for chunk in buffered.chunks() {
            let waiting = chunks
                .get(&chunk.id())
                .is_some_and(|s| Arc::ptr_eq(&s.chunk, chunk) && !s.in_global_orders && s.buffered);
            if chunk_ids.contains(&chunk.id()) || !waiting || chunk.entity_path() != path {
                return Err(fail(
                    "a buffered chunk is the entity's, the store's, waiting, marked buffered, \
                     in no chunk set",
                )
                .at(format_args!("{path}: {}", chunk.id())));
            }
        }
        // With the count above (chunk set and buffer together list every chunk), no
        // chunk marked buffered is outside the buffer.
        if chunk_ids
            .iter()
            .any(|id| chunks.get(id).is_some_and(|s| s.buffered))
        {
            return Err(fail(
                "a chunk marked buffered is in its entity's write buffer, not its chunk set",
            ));
        }
        if buffered.largest_group() >= config.merge_fanout {
            return Err(fail("a write buffer's full fan is merged at once"));
        }
        let counted = view.extra_index_heap_bytes();
        if *large_index_bytes != counted {
            return Err(
                fail("the large indices' bytes are kept up to date").at(format_args!(
                    "{path}: {large_index_bytes} kept, {counted} counted"
                )),
            );
        }
        if (chunk_ids.is_empty() && buffered.is_empty())
            || chunk_ids
                .iter()
                .any(|id| chunks.get(id).is_none_or(|s| s.chunk.entity_path() != path))
        {
            return Err(fail(
                "it holds a chunk, and the ids in its chunk set are its own",
            ));
        }
        if self
            .held_chunks(view, chunks)
            .any(|chunk| chunk.row_id_range().1 > *max_row_id)
        {
            return Err(fail("max_row_id bounds the row ids of its chunks"));
        }
        // A write buffer's group counts once (`ComponentType::num_chunks`).
        let counted = self.set_chunks(chunks).chain(buffered.group_firsts());
        check_component_types(path, element_types, counted)?;
        pending.sanity_check(path, chunks, config)?;
        check_static_winners(path, static_winners, static_chunks, chunks)?;
        for per_component in temporal_per_timeline_per_component.values() {
            for index in per_component.values() {
                for entry in index.chunks() {
                    if !chunks.contains_key(&entry.chunk.id()) || entry.chunk.entity_path() != path
                    {
                        return Err(fail("an indexed chunk is the store's")
                            .at(format_args!("{path}: {}", entry.chunk.id())));
                    }
                }
            }
        }
        Ok(())
    }
}

/// Each static winner is its chunk's best cell, no static chunk holds a better one, and
/// each static chunk is the store's and answers for as many components as counted (part
/// of the entity's sanity check).
fn check_static_winners(
    path: &EntityPath,
    static_winners: &crate::small_map::SmallMap<ComponentName, StaticWinner>,
    static_chunks: &SmallMap<ChunkId, (Arc<Chunk>, usize)>,
    chunks: &ahash::HashMap<ChunkId, StoredChunk>,
) -> Result<(), SanityError> {
    let fail = |invariant| SanityError::new(Structure::Entity, invariant).at(path);
    let mut wins: ahash::HashMap<ChunkId, usize> = ahash::HashMap::default();
    for (component, winner) in static_winners.iter() {
        let StaticWinner {
            row_id,
            chunk,
            component_column,
            row,
        } = winner;
        *wins.entry(chunk.id()).or_default() += 1;
        let column = chunk.components().get(*component_column as usize);
        if column.map(crate::ComponentColumn::name) != Some(component)
            || column.and_then(|c| c.max_row_id_cell(chunk.row_ids())) != Some((*row_id, *row))
        {
            return Err(fail("a static winner is its chunk's best cell")
                .at(format_args!("{path}: {component}")));
        }
    }
    // No static chunk holds a better cell than the winner (a later row id wins).
    for (chunk, _) in static_chunks.values() {
        for column in chunk.components() {
            let best = column.max_row_id_cell(chunk.row_ids()).map(|(id, _)| id);
            let winner = static_winners.get(column.name()).map(|w| w.row_id);
            if best.is_some_and(|best| winner.is_none_or(|winner| best > winner)) {
                return Err(fail("a static winner has the greatest row id of its cells")
                    .at(format_args!("{path}: {}", column.name())));
            }
        }
    }
    for (id, (chunk, num_won)) in static_chunks.iter() {
        if wins.get(id).copied().unwrap_or(0) != *num_won || *num_won == 0 {
            return Err(
                fail("a static chunk answers for the components it is counted for")
                    .at(format_args!("{path}: {id}")),
            );
        }
        if !chunks.contains_key(id) || !chunk.is_static() || chunk.entity_path() != path {
            return Err(fail("a static chunk is a static chunk of the store")
                .at(format_args!("{path}: {id}")));
        }
    }
    Ok(())
}

/// A chunk marked by a rewrite of `compact()` is temporal and one of at most as many as
/// that rewrite made (part of [`ChunkStore::sanity_check`]; `seen` counts per rewrite).
fn check_rewrite_mark(
    chunk: &Chunk,
    mark: RewriteMark,
    num_rewrites: u64,
    seen: &mut ahash::HashMap<u64, usize>,
) -> Result<(), SanityError> {
    let RewriteMark {
        rewrite,
        num_pieces,
    } = mark;
    let pieces = seen.entry(rewrite).or_insert(0);
    *pieces += 1;
    if chunk.is_static() || *pieces > num_pieces || rewrite >= num_rewrites {
        return Err(SanityError::new(
            Structure::RewriteMarks,
            "a rewrite's mark is on at most as many temporal chunks as it made",
        )
        .at(chunk.id()));
    }
    Ok(())
}

/// Each component an entity knows has the type of its chunks' columns and is counted once
/// per chunk in `held` that has its column; no other is known (part of the entity's
/// sanity check).
/// `held` are the entity's chunks outside its write buffer and one chunk of each group of
/// its buffer.
fn check_component_types<'a>(
    path: &EntityPath,
    element_types: &SmallMap<ComponentName, ComponentType>,
    held: impl Iterator<Item = &'a Arc<Chunk>>,
) -> Result<(), SanityError> {
    let mut columns_per_component: BTreeMap<&ComponentName, (&DataType, usize)> = BTreeMap::new();
    for chunk in held {
        for column in chunk.components() {
            let counted = columns_per_component
                .entry(column.name())
                .or_insert_with(|| (column.element_type(), 0));
            counted.1 += 1;
        }
    }
    let types_match = columns_per_component.len() == element_types.len()
        && columns_per_component
            .iter()
            .all(|(name, (data_type, count))| {
                element_types.get(*name).is_some_and(|known| {
                    let ComponentType {
                        element_type,
                        num_chunks,
                    } = known;
                    *num_chunks == *count && element_type.equals_datatype(data_type)
                })
            });
    if types_match {
        Ok(())
    } else {
        Err(SanityError::new(
            Structure::Entity,
            "the component types are those of its chunks' columns, each counted once per chunk \
             outside the write buffer and once per buffer group",
        )
        .at(path))
    }
}
