//! The chunks compaction on insert keeps waiting to grow and the runs of settled chunks it
//! keeps from overlapping ([`PendingGroups`], per entity), and the mark an on-demand
//! rewrite leaves on what it wrote ([`RewriteMark`]).

use std::sync::Arc;

use super::StoredChunk;
use super::config::StoreConfig;
use crate::sanity::{SanityError, Structure};
use crate::{Chunk, ChunkId, EntityPath};

/// Which on-demand rewrite made a chunk, and how many chunks it made.
///
/// `compact()` leaves alone a group of chunks that is exactly what one of its rewrites
/// made: rewriting them again would make the same chunks. (The size figures cannot tell:
/// rows of different sizes cut into pieces of equal row counts can leave a piece above the
/// byte threshold, and payloads change by a byte or two when validity bitmaps are cut
/// differently, so a check by size alone would rewrite such a group on every call.)
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct RewriteMark {
    /// The rewrite, numbered per store.
    pub rewrite: u64,
    /// How many chunks it made.
    pub num_pieces: usize,
}

/// Per layout, the chunks of one entity still waiting to grow, by level, and the runs of
/// settled chunks, by tier.
#[derive(Clone, Debug, Default)]
pub(crate) struct PendingGroups {
    /// One group per layout; never empty.
    groups: Vec<PendingGroup>,
}

#[derive(Clone, Debug, Default)]
struct PendingGroup {
    /// `levels[l]`: chunks of level `l`, oldest first; fewer than the fanout between
    /// merges.
    levels: Vec<Vec<Arc<Chunk>>>,
    /// `tiers[t]`: runs of tier `t` (the level of their row count when they formed),
    /// oldest first; fewer than the fanout between merges.
    tiers: Vec<Vec<SettledRun>>,
}

/// Settled chunks of one layout that overlap none of each other on the first timeline:
/// sorted by their time range there (then id), each ending at or before the next begins.
///
/// Compaction on insert merges a full fan of waiting chunks into one that no longer grows,
/// and such chunks pile up: from an out-of-order stream each spans nearly all of time, so
/// without more a latest-at searched every one of them (one per 4,096 rows with the
/// defaults: 250 at a million rows, 38 us a query). Runs bound that: a full tier of runs
/// merges into one run of the next tier, rewriting only the chunks that overlap
/// (an in-order stream's runs are joined without a copy), so at most `fanout - 1` runs per
/// tier, and `log_fanout(rows)` tiers, cover any time.
#[derive(Clone, Debug, Default)]
pub(crate) struct SettledRun {
    chunks: Vec<Arc<Chunk>>,
}

/// A temporal chunk's key in a run: its time range on its first timeline, then its id.
/// Chunks that overlap nowhere but may touch (one ending at the time the next begins) are
/// in sequence in this order, even where several begin at one time (all but the last of
/// them hold that time alone).
fn run_key(chunk: &Chunk) -> (crate::TimeInt, crate::TimeInt, ChunkId) {
    let range = chunk.time_columns().first().map_or(
        crate::TimeRange::at(crate::TimeInt::MAX),
        crate::TimeColumn::time_range,
    );
    (range.min(), range.max(), chunk.id())
}

impl SettledRun {
    /// A run of `chunks`, which must not overlap on the first timeline (any order).
    pub(crate) fn new(mut chunks: Vec<Arc<Chunk>>) -> Self {
        chunks.sort_by_key(|c| run_key(c));
        Self { chunks }
    }

    fn num_rows(&self) -> usize {
        self.chunks.iter().map(|c| c.num_rows()).sum()
    }

    pub(crate) fn first_entity_path(&self) -> Option<EntityPath> {
        self.chunks.first().map(|c| c.entity_path().clone())
    }

    pub(crate) fn into_chunks(self) -> Vec<Arc<Chunk>> {
        self.chunks
    }

    fn remove(&mut self, chunk: &Chunk) -> bool {
        let key = run_key(chunk);
        match self.chunks.binary_search_by_key(&key, |c| run_key(c)) {
            Ok(position) => {
                self.chunks.remove(position);
                true
            }
            Err(_) => false,
        }
    }
}

impl PendingGroup {
    fn any_chunk(&self) -> Option<&Arc<Chunk>> {
        self.levels
            .iter()
            .flatten()
            .chain(self.tiers.iter().flatten().flat_map(|run| &run.chunks))
            .next()
    }

    fn is_empty(&self) -> bool {
        self.levels.iter().all(Vec::is_empty) && self.tiers.iter().all(Vec::is_empty)
    }
}

impl PendingGroups {
    fn group_position(&self, chunk: &Chunk) -> Option<usize> {
        self.groups
            .iter()
            .position(|g| g.any_chunk().is_some_and(|c| c.has_same_layout(chunk)))
    }

    /// Adds a chunk to its layout's group; returns the group's position and the chunk's
    /// level, which [`PendingGroups::take_full_fan`] takes back (so a chunk's layout is
    /// compared once per push, not again per level).
    pub(crate) fn push(&mut self, chunk: Arc<Chunk>, config: &StoreConfig) -> (usize, usize) {
        let position = self.group_of(&chunk);
        let level = config.level(chunk.num_rows());
        push_at(&mut self.groups[position].levels, level, chunk);
        (position, level)
    }

    /// If `level` of the group at `position` (as [`PendingGroups::push`] returned them)
    /// holds a full fan of chunks, takes them out.
    pub(crate) fn take_full_fan(
        &mut self,
        position: usize,
        level: usize,
        config: &StoreConfig,
    ) -> Option<Vec<Arc<Chunk>>> {
        self.take_full(position, level, config, |group| &mut group.levels)
    }

    /// Adds a run to its layout's group at the tier of its rows; returns the group's
    /// position and the tier, which [`PendingGroups::take_full_tier`] takes back.
    pub(crate) fn push_run(
        &mut self,
        run: SettledRun,
        config: &StoreConfig,
    ) -> Option<(usize, usize)> {
        let position = self.group_of(run.chunks.first()?);
        let tier = config.level(run.num_rows());
        push_at(&mut self.groups[position].tiers, tier, run);
        Some((position, tier))
    }

    /// If `tier` of the group at `position` holds a full fan of runs, takes them out.
    pub(crate) fn take_full_tier(
        &mut self,
        position: usize,
        tier: usize,
        config: &StoreConfig,
    ) -> Option<Vec<SettledRun>> {
        self.take_full(position, tier, config, |group| &mut group.tiers)
    }

    /// The position of `chunk`'s layout's group, made if there is none.
    fn group_of(&mut self, chunk: &Chunk) -> usize {
        self.group_position(chunk).unwrap_or_else(|| {
            self.groups.push(PendingGroup::default());
            self.groups.len() - 1
        })
    }

    /// Takes a full fan out of bucket `at` of the group at `position` (its levels or its
    /// tiers, as `buckets` picks), if the bucket holds one; drops the group left empty.
    fn take_full<T>(
        &mut self,
        position: usize,
        at: usize,
        config: &StoreConfig,
        buckets: impl FnOnce(&mut PendingGroup) -> &mut Vec<Vec<T>>,
    ) -> Option<Vec<T>> {
        let bucket = buckets(self.groups.get_mut(position)?).get_mut(at)?;
        if bucket.len() < config.merge_fanout {
            return None;
        }
        let fan = bucket.drain(..config.merge_fanout).collect();
        if self.groups[position].is_empty() {
            self.groups.swap_remove(position);
        }
        Some(fan)
    }

    /// Every waiting chunk.
    pub fn chunks(&self) -> impl Iterator<Item = &Arc<Chunk>> {
        self.groups.iter().flat_map(|g| g.levels.iter().flatten())
    }

    /// Forgets a chunk that left the store (or was merged). Only the chunk's own level is
    /// searched: a merge removes each of its inputs, which have already left their level.
    pub fn remove(&mut self, chunk: &Chunk, config: &StoreConfig) {
        let id = chunk.id();
        let level = config.level(chunk.num_rows());
        let found = self.groups.iter().position(|group| {
            group
                .levels
                .get(level)
                .is_some_and(|l| l.iter().any(|c| c.id() == id))
        });
        if let Some(position) = found {
            self.groups[position].levels[level].retain(|c| c.id() != id);
            if self.groups[position].is_empty() {
                self.groups.swap_remove(position);
            }
            return;
        }
        // A settled chunk: in a run of its layout's group, if in any.
        let Some(position) = self.group_position(chunk) else {
            return;
        };
        let group = &mut self.groups[position];
        for runs in &mut group.tiers {
            if let Some(at) = runs.iter_mut().position(|run| run.remove(chunk)) {
                if runs[at].chunks.is_empty() {
                    runs.remove(at);
                }
                if group.is_empty() {
                    self.groups.swap_remove(position);
                }
                return;
            }
        }
    }

    /// Does the entity have no chunk waiting and no run?
    pub fn is_empty(&self) -> bool {
        self.groups.is_empty()
    }

    /// Forgets every chunk of `gone` (chunks leaving the store together): one pass over
    /// the groups rather than a search, and a shift of a run's later chunks, per chunk.
    pub fn remove_many(&mut self, gone: &ahash::HashSet<ChunkId>) {
        for group in &mut self.groups {
            for level in &mut group.levels {
                level.retain(|c| !gone.contains(&c.id()));
            }
            for runs in &mut group.tiers {
                for run in runs.iter_mut() {
                    run.chunks.retain(|c| !gone.contains(&c.id()));
                }
                runs.retain(|run| !run.chunks.is_empty());
            }
        }
        self.groups.retain(|group| !group.is_empty());
    }

    /// Every waiting chunk is a small temporal chunk of the entity that the store holds,
    /// once, in its layout's only group at its level; no group is empty, no level full.
    pub fn sanity_check(
        &self,
        path: &EntityPath,
        chunks: &ahash::HashMap<ChunkId, StoredChunk>,
        config: &StoreConfig,
    ) -> Result<(), SanityError> {
        let fail = |invariant| Err(SanityError::new(Structure::PendingGroups, invariant).at(path));
        let Self { groups } = self;
        let mut seen: ahash::HashSet<ChunkId> = ahash::HashSet::default();
        for (position, group) in groups.iter().enumerate() {
            let PendingGroup { levels, tiers } = group;
            let Some(first) = group.any_chunk() else {
                return fail("no group is empty");
            };
            if groups[..position]
                .iter()
                .any(|other| other.any_chunk().is_some_and(|c| c.has_same_layout(first)))
            {
                return fail("one group per layout");
            }
            for (l, members) in levels.iter().enumerate() {
                if l == 0 && !members.is_empty() {
                    return fail("the first level waits in the write buffer, not here");
                }
                if members.len() >= config.merge_fanout {
                    return fail("a full fan of waiting chunks is merged at once");
                }
                for chunk in members {
                    let stored = chunks.get(&chunk.id());
                    if stored.is_none_or(|s| !Arc::ptr_eq(&s.chunk, chunk))
                        || !seen.insert(chunk.id())
                        || chunk.is_static()
                        || chunk.entity_path() != path
                        || !chunk.has_same_layout(first)
                        || config.level(chunk.num_rows()) != l
                        || !config.can_grow(chunk)
                    {
                        return Err(SanityError::new(
                            Structure::PendingGroups,
                            "a waiting chunk is a small temporal chunk of the store, once, in \
                             its layout's group at its level",
                        )
                        .at(format_args!("{path}: {}", chunk.id())));
                    }
                }
            }
            for (t, runs) in tiers.iter().enumerate() {
                if runs.len() >= config.merge_fanout {
                    return fail("a full tier of runs is merged at once");
                }
                for run in runs {
                    check_run(run, t, first, path, chunks, config, &mut seen)?;
                }
            }
        }
        Ok(())
    }
}

/// Puts `item` in bucket `at`, making the buckets up to it.
fn push_at<T>(buckets: &mut Vec<Vec<T>>, at: usize, item: T) {
    if buckets.len() <= at {
        buckets.resize_with(at + 1, Vec::new);
    }
    buckets[at].push(item);
}

/// A run is not empty, no larger than its tier, and holds settled temporal chunks of the
/// store in its group's layout, each once, in order, none overlapping the next.
fn check_run(
    run: &SettledRun,
    tier: usize,
    first: &Chunk,
    path: &EntityPath,
    chunks: &ahash::HashMap<ChunkId, StoredChunk>,
    config: &StoreConfig,
    seen: &mut ahash::HashSet<ChunkId>,
) -> Result<(), SanityError> {
    let fail = |invariant, id: Option<ChunkId>| {
        let error = SanityError::new(Structure::PendingGroups, invariant);
        Err(match id {
            Some(id) => error.at(format_args!("{path}: {id}")),
            None => error.at(path),
        })
    };
    if run.chunks.is_empty() || config.level(run.num_rows()) > tier {
        return fail("a run is not empty and no larger than its tier", None);
    }
    for chunk in &run.chunks {
        let stored = chunks.get(&chunk.id());
        if stored.is_none_or(|s| !Arc::ptr_eq(&s.chunk, chunk) || !s.in_global_orders)
            || !seen.insert(chunk.id())
            || chunk.is_static()
            || chunk.entity_path() != path
            || !chunk.has_same_layout(first)
        {
            return fail(
                "a run holds settled temporal chunks of the store in its group's layout, \
                 each once",
                Some(chunk.id()),
            );
        }
    }
    let in_order = run.chunks.windows(2).all(|w| {
        run_key(&w[0]) < run_key(&w[1])
            && w[0].time_columns()[0].time_range().max()
                <= w[1].time_columns()[0].time_range().min()
    });
    if !in_order {
        return fail(
            "a run's chunks are in order, each ending at or before the next begins",
            None,
        );
    }
    Ok(())
}
