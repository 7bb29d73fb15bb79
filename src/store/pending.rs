//! The chunks compaction on insert keeps waiting to grow ([`PendingGroups`], per entity),
//! and the mark an on-demand rewrite leaves on what it wrote ([`RewriteMark`]).

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

/// The chunks of one entity still waiting to grow, per layout and level.
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
}

impl PendingGroup {
    fn any_chunk(&self) -> Option<&Arc<Chunk>> {
        self.levels.iter().flatten().next()
    }

    fn is_empty(&self) -> bool {
        self.levels.iter().all(Vec::is_empty)
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
        let position = self.group_position(&chunk).unwrap_or_else(|| {
            self.groups.push(PendingGroup::default());
            self.groups.len() - 1
        });
        let level = config.level(chunk.num_rows());
        let levels = &mut self.groups[position].levels;
        if levels.len() <= level {
            levels.resize_with(level + 1, Vec::new);
        }
        levels[level].push(chunk);
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
        let chunks = self.groups.get_mut(position)?.levels.get_mut(level)?;
        if chunks.len() < config.merge_fanout {
            return None;
        }
        let fan = chunks.drain(..config.merge_fanout).collect();
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
        }
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
            let PendingGroup { levels } = group;
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
        }
        Ok(())
    }
}
