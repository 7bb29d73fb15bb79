//! [`WriteBuffer`]: an entity's small temporal chunks, waiting for compaction on insert to
//! merge them. It is compaction's first level (chunks of fewer than `K` rows, `K` the
//! merge fanout): a layout's group that reaches `K` chunks is handed back whole by
//! [`WriteBuffer::push`] and merged, so these chunks are in no other compaction group and
//! no temporal index. See `compaction/mod.rs` for why and for what a subscriber sees.
//!
//! Queries scan the buffer beside the indices, so it is laid out for them: chunks of one
//! layout form one group, and each group keeps, per time column, its least and greatest
//! time, and per (time column, component column) its greatest cell. A latest-at at or
//! after a group's greatest time (a viewer asking for the newest data of a streaming
//! entity) reads that summary; one before its least time skips the group; only a time
//! inside the group's span looks at its chunks. Without the summary, a latest-at at a
//! streaming entity read every buffered chunk's columns, each a cold allocation: 130 →
//! 310 ns a query on 100 entities of 15 buffered chunks each.
//!
//! The writer keeps, beside each group, its chunks' rows in growing columns
//! ([`BufferColumns`], where the shape allows), so that the merge of a full fan builds its
//! chunk from them rather than gathering from every chunk again. They are the writer's
//! alone (`EntityIndex`, not the view): a snapshot never needs them, so a write under one
//! copies none of them.

use std::sync::Arc;

use smallvec::SmallVec;

use crate::chunk::{ComponentTimeBounds, RowColumns};
use crate::sanity::{SanityError, Structure};
use crate::{Chunk, ChunkId, EntityPath, TimeInt};

/// The write buffer of one entity: see the module docs.
#[derive(Clone, Debug, Default)]
pub(crate) struct WriteBuffer {
    groups: Vec<BufferGroup>,
}

/// Buffered chunks of one layout (`Chunk::has_same_layout`: they can be merged), and their
/// summary.
#[derive(Debug)]
struct BufferGroup {
    /// In arrival order; never empty.
    chunks: Vec<Arc<Chunk>>,
    /// Per time column: the least and greatest time of any row of the group.
    time_ranges: SmallVec<[(TimeInt, TimeInt); 1]>,
    /// Per (time column `t`, component column `c`), at `t * components + c`: the chunk
    /// holding the group's greatest non-null cell there, and that chunk's bounds.
    latest: Vec<Option<(u32, ComponentTimeBounds)>>,
    /// Has a chunk left since the summary was made? [`WriteBuffer::refresh`] remakes it
    /// once a removal is done (a seal takes a whole group out one chunk at a time).
    stale: bool,
}

/// What [`WriteBuffer::push`] did with a chunk.
#[derive(Debug)]
pub(crate) enum Pushed {
    /// It opened a new group, the last.
    Opened,
    /// It joined the group at this position.
    Joined(usize),
    /// It filled the group at this position, which was taken out whole (`swap_remove`):
    /// a full fan for compaction to merge, oldest first.
    Filled(usize, Vec<Arc<Chunk>>),
}

/// A full fan of a write buffer's group, taken out for compaction to merge: its chunks,
/// oldest first, and their rows in columns if the writer kept them.
#[derive(Debug)]
pub(crate) struct Fan {
    pub chunks: Vec<Arc<Chunk>>,
    pub columns: Option<RowColumns>,
}

/// The writer's columns of its entity's write buffer: per group of the buffer (same
/// positions), the group's rows in [`RowColumns`], or `None` where a chunk's shape is not
/// kept. Not in the store's figures, like the buffer's own structures: at most a fan's
/// rows per group.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct BufferColumns {
    groups: Vec<Option<RowColumns>>,
    /// Did a chunk leave the buffer other than in a full fan (a collection, a drop)? The
    /// positions may have moved: the columns are made again before their next use.
    stale: bool,
}

impl BufferColumns {
    /// Follows a push into `buffer` (already made): copies `chunk`'s rows into its group's
    /// columns, and returns a filled group's columns with its fan.
    pub fn follow(&mut self, buffer: &WriteBuffer, pushed: Pushed, chunk: &Chunk) -> Option<Fan> {
        if self.stale {
            // Made again from the groups as they are, the pushed chunk included.
            *self = Self::of(buffer);
            return match pushed {
                Pushed::Filled(_, chunks) => Some(Fan {
                    columns: columns_of(&chunks, chunks.len()),
                    chunks,
                }),
                Pushed::Opened | Pushed::Joined(_) => None,
            };
        }
        match pushed {
            Pushed::Opened => {
                let room = buffer.groups.last().map_or(0, |g| g.chunks.capacity());
                self.groups.push(RowColumns::start(
                    chunk,
                    room.saturating_mul(chunk.num_rows()),
                ));
                None
            }
            Pushed::Joined(g) => {
                if let Some(slot) = self.groups.get_mut(g)
                    && let Some(columns) = slot
                    && !columns.append(chunk)
                {
                    *slot = None;
                }
                None
            }
            Pushed::Filled(g, chunks) => {
                let mut columns = (g < self.groups.len())
                    .then(|| self.groups.swap_remove(g))
                    .flatten();
                if let Some(kept) = &mut columns
                    && !kept.append(chunk)
                {
                    columns = None;
                }
                Some(Fan { chunks, columns })
            }
        }
    }

    /// A chunk left `buffer` other than in a full fan: see `stale`.
    pub fn invalidate(&mut self) {
        self.stale = true;
    }

    /// The columns of every group of `buffer`, made from its chunks.
    fn of(buffer: &WriteBuffer) -> Self {
        Self {
            groups: buffer
                .groups
                .iter()
                .map(|g| columns_of(&g.chunks, g.chunks.capacity()))
                .collect(),
            stale: false,
        }
    }

    /// Unless stale, the columns are each group's chunks' rows, as made from them.
    pub fn sanity_check(&self, buffer: &WriteBuffer, path: &EntityPath) -> Result<(), SanityError> {
        if !self.stale && *self != Self::of(buffer) {
            return Err(SanityError::new(
                Structure::Entity,
                "the write buffer's columns hold each group's rows, in order",
            )
            .at(path));
        }
        Ok(())
    }
}

/// The rows of `chunks` (one layout) in columns, with room for `room` chunks like the
/// first, if every chunk's shape is kept.
fn columns_of(chunks: &[Arc<Chunk>], room: usize) -> Option<RowColumns> {
    let (first, rest) = chunks.split_first()?;
    let room = room.saturating_mul(first.num_rows());
    let mut columns = RowColumns::start(first, room)?;
    rest.iter()
        .all(|chunk| columns.append(chunk))
        .then_some(columns)
}

/// Most room a new group reserves: a full fan with the default fanout, not a million
/// handles for a store configured never to merge.
const MAX_RESERVED_CHUNKS: usize = 16;

/// A copy is made when a snapshot shares the group and a write changes it, and a write that
/// copies a group usually pushes a chunk next: the copy has room for it, rather than
/// exactly the chunks it holds (which made every push under a `SharedStore` publishing
/// per insert a reallocation).
impl Clone for BufferGroup {
    fn clone(&self) -> Self {
        let mut chunks = Vec::with_capacity(self.chunks.len() + 1);
        chunks.extend_from_slice(&self.chunks);
        Self {
            chunks,
            time_ranges: self.time_ranges.clone(),
            latest: self.latest.clone(),
            stale: self.stale,
        }
    }
}

/// Where a (timeline, component) is in a group's chunks.
#[derive(Clone, Copy)]
struct Located {
    time_column: usize,
    component_column: usize,
}

impl BufferGroup {
    /// A group of `chunk` alone, with room for a full fan (up to [`MAX_RESERVED_CHUNKS`]):
    /// it grows to `fanout` chunks and is then taken whole, so with the default fanout it
    /// never reallocates.
    fn new(chunk: &Arc<Chunk>, fanout: usize) -> Self {
        let mut group = Self {
            chunks: Vec::with_capacity(fanout.min(MAX_RESERVED_CHUNKS)),
            time_ranges: SmallVec::new(),
            latest: Vec::new(),
            stale: false,
        };
        group.chunks.push(Arc::clone(chunk));
        group.summarize();
        group
    }

    fn num_components(&self) -> usize {
        self.chunks.first().map_or(0, |c| c.components().len())
    }

    /// Adds chunk number `position` (already in `chunks`) to the summary.
    #[expect(
        clippy::cast_possible_truncation,
        reason = "a group holds fewer than 2^32 chunks"
    )]
    fn add_to_summary(&mut self, position: usize) {
        // Borrowed field by field: a handle cloned to free `self` was two atomic
        // operations on every push.
        let Self {
            chunks,
            time_ranges,
            latest,
            ..
        } = self;
        let chunk = &chunks[position];
        let num_components = chunk.components().len();
        for (t, column) in chunk.time_columns().iter().enumerate() {
            let bounds = column.time_range();
            let (least, greatest) = (bounds.min(), bounds.max());
            match time_ranges.get_mut(t) {
                Some((min, max)) => {
                    *min = (*min).min(least);
                    *max = (*max).max(greatest);
                }
                None => time_ranges.push((least, greatest)),
            }
            for (c, component) in chunk.components().iter().enumerate() {
                let Some(bounds) = component.bounds(t) else {
                    continue;
                };
                let slot = &mut latest[t * num_components + c];
                // The cell latest-at answers with: the greatest key, ties to chunk id.
                if slot.is_none_or(|(best_position, best)| {
                    let best_chunk = chunks[best_position as usize].id();
                    bounds.max_index_key(chunk.id()) > best.max_index_key(best_chunk)
                }) {
                    *slot = Some((position as u32, bounds));
                }
            }
        }
    }

    /// Recomputes the summary from the chunks.
    fn summarize(&mut self) {
        let num_slots = self
            .chunks
            .first()
            .map_or(0, |c| c.time_columns().len() * c.components().len());
        self.time_ranges.clear();
        self.latest.clear();
        self.latest.resize(num_slots, None);
        for position in 0..self.chunks.len() {
            self.add_to_summary(position);
        }
    }

    /// Where `timeline` and `component` are in this group's chunks.
    fn locate(&self, timeline: &str, component: &str) -> Option<Located> {
        let first = self.chunks.first()?;
        Some(Located {
            time_column: first
                .time_columns()
                .iter()
                .position(|column| column.timeline().name() == timeline)?,
            component_column: first
                .components()
                .iter()
                .position(|column| column.name().as_str() == component)?,
        })
    }

    /// Calls `f` with each of the group's chunks that has non-null cells at `located`: the
    /// chunk, the column positions, the component's bounds there.
    #[expect(
        clippy::cast_possible_truncation,
        reason = "columns < 2^32, checked in Chunk::from_raw"
    )]
    fn for_each_with_cells<'a>(
        &'a self,
        located: &Located,
        f: &mut impl FnMut(&'a Arc<Chunk>, u32, u32, ComponentTimeBounds),
    ) {
        let Located {
            time_column,
            component_column,
        } = *located;
        for chunk in &self.chunks {
            if let Some(bounds) = chunk.components()[component_column].bounds(time_column) {
                f(chunk, time_column as u32, component_column as u32, bounds);
            }
        }
    }
}

impl WriteBuffer {
    pub fn is_empty(&self) -> bool {
        self.groups.is_empty()
    }

    /// Number of buffered chunks.
    #[cfg(test)]
    pub fn len(&self) -> usize {
        self.groups.iter().map(|g| g.chunks.len()).sum()
    }

    /// Every buffered chunk, group by group, each in arrival order.
    pub fn chunks(&self) -> impl Iterator<Item = &Arc<Chunk>> + '_ {
        self.groups.iter().flat_map(|g| &g.chunks)
    }

    pub fn contains(&self, id: ChunkId) -> bool {
        self.chunks().any(|c| c.id() == id)
    }

    /// Buffers a temporal chunk (once: the store adds a chunk id once). If its layout's
    /// group then holds `fanout` chunks, takes them all out and returns them, oldest
    /// first: a full fan for compaction to merge.
    pub fn push(&mut self, chunk: &Arc<Chunk>, fanout: usize) -> Pushed {
        let Some(g) = self.groups.iter().position(|g| {
            g.chunks
                .first()
                .is_some_and(|first| first.has_same_layout(chunk))
        }) else {
            debug_assert!(fanout >= 2, "StoreConfig::validate");
            self.groups.push(BufferGroup::new(chunk, fanout));
            return Pushed::Opened;
        };
        let group = &mut self.groups[g];
        if group.chunks.len() + 1 >= fanout {
            let mut fan = self.groups.swap_remove(g).chunks;
            fan.push(Arc::clone(chunk));
            return Pushed::Filled(g, fan);
        }
        group.chunks.push(Arc::clone(chunk));
        group.add_to_summary(group.chunks.len() - 1);
        Pushed::Joined(g)
    }

    /// Takes a chunk out; returns `None` if it was not buffered, else whether its group
    /// went with it (it was the group's last chunk). The group's summary is stale until
    /// [`WriteBuffer::refresh`], which the removal's caller must call before any query
    /// reads the buffer.
    pub fn remove(&mut self, id: ChunkId) -> Option<bool> {
        for (g, group) in self.groups.iter_mut().enumerate() {
            if let Some(position) = group.chunks.iter().position(|c| c.id() == id) {
                group.chunks.remove(position);
                let emptied = group.chunks.is_empty();
                if emptied {
                    self.groups.swap_remove(g);
                } else {
                    group.stale = true;
                }
                return Some(emptied);
            }
        }
        None
    }

    /// The first chunk of each group: one chunk of each layout the buffer holds.
    pub fn group_firsts(&self) -> impl Iterator<Item = &Arc<Chunk>> + '_ {
        self.groups.iter().filter_map(|g| g.chunks.first())
    }

    /// Remakes the summaries removals left stale.
    pub fn refresh(&mut self) {
        for group in self.groups.iter_mut().filter(|g| g.stale) {
            group.summarize();
            group.stale = false;
        }
    }

    /// Calls `f` with each buffered chunk that has non-null cells of `component` on
    /// `timeline`: the chunk, the positions of that time column and component column, and
    /// the component's bounds there (what its index entry would hold).
    pub fn for_each<'a>(
        &'a self,
        timeline: &str,
        component: &str,
        mut f: impl FnMut(&'a Arc<Chunk>, u32, u32, ComponentTimeBounds),
    ) {
        for group in &self.groups {
            if let Some(located) = group.locate(timeline, component) {
                group.for_each_with_cells(&located, &mut f);
            }
        }
    }

    /// [`WriteBuffer::for_each`] for a latest-at at `at`: a group entirely at or before
    /// `at` gives only its greatest cell (from its summary), and a group entirely after
    /// `at` nothing; `f` may still get chunks that end after `at`.
    #[expect(
        clippy::cast_possible_truncation,
        reason = "columns < 2^32, checked in Chunk::from_raw"
    )]
    pub fn for_each_candidate<'a>(
        &'a self,
        timeline: &str,
        component: &str,
        at: TimeInt,
        mut f: impl FnMut(&'a Arc<Chunk>, u32, u32, ComponentTimeBounds),
    ) {
        for group in &self.groups {
            let Some(located) = group.locate(timeline, component) else {
                continue;
            };
            let Some(&(least, greatest)) = group.time_ranges.get(located.time_column) else {
                continue;
            };
            if at < least {
                continue;
            }
            if at < greatest {
                group.for_each_with_cells(&located, &mut f);
                continue;
            }
            let slot = located.time_column * group.num_components() + located.component_column;
            if let Some(&Some((position, bounds))) = group.latest.get(slot)
                && let Some(chunk) = group.chunks.get(position as usize)
            {
                let (t, c) = (located.time_column as u32, located.component_column as u32);
                f(chunk, t, c, bounds);
            }
        }
    }

    /// The most chunks one group holds: fewer than the merge fanout, whose full fans are
    /// merged at once (checked by the store, which knows the fanout).
    pub fn largest_group(&self) -> usize {
        self.groups
            .iter()
            .map(|g| g.chunks.len())
            .max()
            .unwrap_or(0)
    }

    /// The buffer's own invariants: groups non-empty, each chunk a temporal chunk of
    /// `path` buffered once, in its layout's only group, and every summary what its chunks
    /// give.
    pub fn sanity_check(&self, path: &EntityPath) -> Result<(), SanityError> {
        let fail =
            |invariant: &'static str| Err(SanityError::new(Structure::Entity, invariant).at(path));
        let mut seen = ahash::HashSet::default();
        for (g, group) in self.groups.iter().enumerate() {
            let Some(first) = group.chunks.first() else {
                return fail("a write buffer's group is never empty");
            };
            if self.groups[..g].iter().any(|other| {
                other
                    .chunks
                    .first()
                    .is_some_and(|o| o.has_same_layout(first))
            }) {
                return fail("a write buffer has one group per layout");
            }
            for chunk in &group.chunks {
                if chunk.is_static()
                    || chunk.entity_path() != path
                    || !first.has_same_layout(chunk)
                    || !seen.insert(chunk.id())
                {
                    return fail(
                        "a buffered chunk is a temporal chunk of the entity, buffered once, \
                         in the group of its layout",
                    );
                }
            }
            let mut recounted = group.clone();
            recounted.summarize();
            if group.stale
                || recounted.time_ranges != group.time_ranges
                || recounted.latest != group.latest
            {
                return fail("a write buffer group's summary is what its chunks give");
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::{ArrayRef, Float64Array};

    use super::WriteBuffer;
    use crate::{Chunk, ChunkBuilder, ChunkId, EntityPath, RowId, TimeInt, Timeline};

    fn chunk(component: &str, frames: &[i64]) -> Arc<Chunk> {
        let mut builder = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("e").unwrap());
        for &frame in frames {
            let value = Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
            builder = builder.with_row(
                RowId::new(),
                [(Timeline::sequence("frame"), frame)],
                [(component, value)],
            );
        }
        Arc::new(builder.build().unwrap())
    }

    fn candidates(buffer: &WriteBuffer, component: &str, at: i64) -> Vec<ChunkId> {
        let mut ids = Vec::new();
        let at = TimeInt::new(at).unwrap();
        buffer.for_each_candidate("frame", component, at, |chunk, _, _, _| {
            ids.push(chunk.id());
        });
        ids.sort();
        ids
    }

    /// A latest-at past a group's newest row gets only the group's greatest cell, one
    /// before its oldest row nothing, one inside its span every chunk; the summary follows
    /// removals once refreshed, and chunks of other columns form their own group.
    #[test]
    fn a_group_answers_from_its_summary_outside_its_span() {
        let path = EntityPath::parse("e").unwrap();
        let (a, b, c) = (chunk("x", &[5]), chunk("x", &[2, 3]), chunk("x", &[8]));
        let other = chunk("y", &[1]);
        let mut buffer = WriteBuffer::default();
        for chunk in [&a, &b, &c, &other] {
            assert!(matches!(
                buffer.push(chunk, 16),
                super::Pushed::Opened | super::Pushed::Joined(_)
            ));
        }
        buffer.sanity_check(&path).unwrap();
        assert_eq!(buffer.len(), 4);
        assert_eq!(candidates(&buffer, "x", 100), vec![c.id()]);
        assert_eq!(candidates(&buffer, "x", 1), vec![]);
        let mut all = vec![a.id(), b.id(), c.id()];
        all.sort();
        assert_eq!(candidates(&buffer, "x", 6), all);
        assert_eq!(candidates(&buffer, "y", 100), vec![other.id()]);

        assert_eq!(
            buffer.remove(c.id()),
            Some(false),
            "x's group keeps a and b"
        );
        assert!(buffer.sanity_check(&path).is_err(), "stale until refreshed");
        buffer.refresh();
        buffer.sanity_check(&path).unwrap();
        assert_eq!(candidates(&buffer, "x", 100), vec![a.id()]);
        assert_eq!(
            buffer.remove(other.id()),
            Some(true),
            "y's group goes with it"
        );
        assert_eq!(buffer.remove(other.id()), None);
        buffer.refresh();
        assert_eq!(candidates(&buffer, "y", 100), vec![]);
        buffer.sanity_check(&path).unwrap();
    }
}
