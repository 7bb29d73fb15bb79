//! Clears (SEMANTICS.md section 5), indexed on their own: a tree mirroring the entity tree
//! holds, per entity that ever logged a Clear, the indices of its Clears per timeline. A
//! query walks from the root to the queried entity, one map lookup per level, and never
//! looks at any entity's data. The maps are keyed by the path's parts, which carry their
//! hashes ([`PathPart`]), so a level costs a probe and no hashing of text.
//!
//! Most entities have no Clear at or above them, and a query of one should not pay the
//! walk: beside the tree, a filter of 4,096 bits marks the path hashes of the entities
//! holding Clears (one bit for any Clear, one for a recursive one). A query first looks for
//! its entity's own hash and its ancestors' among the bits, and walks only down to the
//! deepest level marked, if any. In `clear_recursive`, where half the entities lie under a
//! recursive Clear, that saves 43 of the walk's 265 instructions a query and 5% of the
//! cache misses; in a store whose few Clears are elsewhere, the whole walk.

use std::collections::BTreeMap;
use std::sync::Arc;

use arrow_array::{Array, BooleanArray};
use arrow_buffer::ArrowNativeType;

mod filter;

use filter::ClearFilter;

use crate::entity_path::{PartMap, PathPart};
use crate::sanity::{SanityError, Structure, ensure};
use crate::small_map::SmallMap;
use crate::{Chunk, ChunkId, EntityPath, RowId, TimeInt, TimeRange};

/// The Clears that apply to one (entity, component) column of a dataframe on one
/// timeline, from [`ClearIndex::column_clears`]. Indices are `(time, row id)`.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct ColumnClears {
    /// The greatest row id of a static Clear that applies: it hides every temporal cell,
    /// and static cells with a row id not above it.
    pub latest_static: Option<RowId>,
    /// The greatest temporal Clear before the range's start.
    pub latest_before: Option<(TimeInt, RowId)>,
    /// Every temporal Clear inside the range, ascending, without repeats.
    pub in_range: Vec<(TimeInt, RowId)>,
}

/// A multiset of indices, each with the chunk holding it (so removing a chunk removes
/// exactly its Clears): duplicated row ids must neither crash nor miscount.
type IndexMultiset<K> = BTreeMap<K, u32>;

/// The Clears logged at one entity.
#[derive(Clone, Debug, Default)]
struct EntityClears {
    /// All Clears, flat and recursive, per timeline: they hide this entity's own data.
    any_per_timeline: SmallMap<Arc<str>, IndexMultiset<(TimeInt, RowId, ChunkId)>>,
    /// Recursive Clears per timeline: they hide descendants' data too.
    recursive_per_timeline: SmallMap<Arc<str>, IndexMultiset<(TimeInt, RowId, ChunkId)>>,
    static_any: IndexMultiset<(RowId, ChunkId)>,
    static_recursive: IndexMultiset<(RowId, ChunkId)>,
}

/// The Clears of a whole store: the tree of entity path parts and its filter (see the
/// module docs).
///
/// Nodes and each entity's Clears sit behind `Arc`s, so that a snapshot of the store
/// shares the tree and a write copies only the nodes on its entity's path (and that
/// entity's Clears), and only while a snapshot still holds them. The filter is 512 bytes,
/// copied with the root.
#[derive(Clone, Debug, Default)]
pub(crate) struct ClearIndex {
    root: ClearNode,
    filter: ClearFilter,
}

/// A node of the tree: the Clears of the entity at its path, and its children.
#[derive(Clone, Debug, Default)]
struct ClearNode {
    clears: Option<Arc<EntityClears>>,
    children: PartMap<Arc<ClearNode>>,
}

/// What an entity's Clears can hide beyond its own data.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Holds {
    /// Any Clear: it hides the entity's own data.
    any: bool,
    /// A recursive Clear: it hides its descendants' data too.
    recursive: bool,
}

impl Holds {
    fn of(node: Option<&ClearNode>) -> Self {
        node.and_then(|node| node.clears.as_deref())
            .map_or_else(Self::default, |clears| Self {
                any: !clears.is_empty(),
                recursive: !clears.recursive_per_timeline.is_empty()
                    || !clears.static_recursive.is_empty(),
            })
    }
}

/// One Clear row: its row, and whether it is recursive.
fn clear_rows(chunk: &Chunk) -> Vec<(usize, bool)> {
    let Some(column) = chunk.clear_column() else {
        return Vec::new();
    };
    let list = column.list_array();
    let Some(flags) = list.values().as_any().downcast_ref::<BooleanArray>() else {
        return Vec::new(); // the store rejects such chunks before indexing them
    };
    let offsets = list.offsets();
    (0..list.len())
        .filter(|&row| list.is_valid(row) && list.value_length(row) > 0)
        .map(|row| {
            // A Clear holds exactly one non-null flag (checked on insert).
            let first = offsets[row].as_usize();
            (row, flags.is_valid(first) && flags.value(first))
        })
        .collect()
}

impl ClearIndex {
    /// Does the store hold any Clear at all? Queries skip the walk when not.
    pub fn is_empty(&self) -> bool {
        self.root.is_empty()
    }

    /// Indexes every Clear row of `chunk`; a chunk without any is not touched (nor is
    /// the tree copied).
    ///
    /// Inlined to the test of the chunk's flag: every chunk joining or leaving the store
    /// passes here, and almost none holds a Clear (a call each way was 0.9% of
    /// `insert_streaming`'s instructions).
    #[inline]
    pub fn insert_chunk(index: &mut Arc<Self>, chunk: &Chunk) {
        if chunk.has_clears() {
            Self::update_chunk(index, chunk, true);
        }
    }

    /// Forgets every Clear row of `chunk` (the mirror of [`ClearIndex::insert_chunk`]).
    #[inline]
    pub fn remove_chunk(index: &mut Arc<Self>, chunk: &Chunk) {
        if chunk.has_clears() {
            Self::update_chunk(index, chunk, false);
        }
    }

    fn update_chunk(index: &mut Arc<Self>, chunk: &Chunk, insert: bool) {
        let rows = clear_rows(chunk);
        if rows.is_empty() {
            return;
        }
        let parts = chunk.entity_path().path_parts();
        let before = Holds::of(index.root.node(parts));
        if !insert && !before.any {
            return;
        }
        let this = Arc::make_mut(index);
        this.root.update_chunk(parts, chunk, &rows, insert);
        let after = Holds::of(this.root.node(parts));
        let hash = parts
            .last()
            .map_or(PathPart::ROOT_HASH, PathPart::prefix_hash);
        this.filter.note(&this.root, hash, before, after);
    }

    /// Forgets every Clear logged at `entity` (and at its descendants if `recursive`),
    /// static ones included: what dropping the entity means.
    pub fn remove_entity(index: &mut Arc<Self>, entity: &EntityPath, recursive: bool) {
        let parts = entity.path_parts();
        let Some(node) = index.root.node(parts) else {
            return;
        };
        let mut gone = usize::from(node.clears.is_some());
        if recursive {
            for child in node.children.values() {
                child.for_each_entity(0, &mut |_, _| gone += 1);
            }
        }
        let this = Arc::make_mut(index);
        if let Some(node) = this.root.node_mut(parts, false) {
            node.clears = None;
            if recursive {
                node.children.clear();
            }
        }
        this.root.prune(parts);
        this.filter.forget(gone, &this.root);
    }

    /// Every static Clear indexed: `(entity, row id, chunk id, recursive)`, in no
    /// particular order.
    pub fn static_clears(&self) -> Vec<(EntityPath, RowId, ChunkId, bool)> {
        let mut out = Vec::new();
        let mut parts = Vec::new();
        self.root.collect_static(&mut parts, &mut out);
        out
    }

    /// Is `id` among the chunks holding the `n` latest Clears (flat or recursive, and
    /// recursive alone) of `entity` on any timeline? Together with the latest data, those
    /// decide every latest-at at `+∞`.
    pub fn is_among_latest(&self, entity: &EntityPath, id: ChunkId, n: usize) -> bool {
        let Some(clears) = self
            .root
            .node(entity.path_parts())
            .and_then(|node| node.clears.as_ref())
        else {
            return false;
        };
        clears
            .any_per_timeline
            .values()
            .chain(clears.recursive_per_timeline.values())
            .any(|set| set.keys().rev().take(n).any(|&(_, _, latest)| latest == id))
    }

    /// Is a cell of `entity` with index `(time, row_id)` (`time` `None` for static) hidden
    /// by a Clear visible at `at` on `timeline`?
    pub fn is_hidden(
        &self,
        entity: &EntityPath,
        timeline: &str,
        at: TimeInt,
        time: Option<TimeInt>,
        row_id: RowId,
    ) -> bool {
        let parts = entity.path_parts();
        let hash_at = |depth: usize| {
            depth
                .checked_sub(1)
                .map_or(PathPart::ROOT_HASH, |last| parts[last].prefix_hash())
        };
        // The deepest level that may hold a Clear hiding the cell: the entity's own (any
        // Clear), or a strict ancestor's (a recursive one). None: nothing to walk.
        let deepest = if self.filter.may_hold_any(hash_at(parts.len())) {
            Some(parts.len())
        } else {
            (0..parts.len())
                .rev()
                .find(|&depth| self.filter.may_hold_recursive(hash_at(depth)))
        };
        let Some(deepest) = deepest else {
            return false;
        };
        let mut node = &self.root;
        for depth in 0..=deepest {
            if let Some(clears) = &node.clears {
                let is_self = depth == parts.len();
                if clears.hides(is_self, timeline, at, time, row_id) {
                    return true;
                }
            }
            if depth == deepest {
                break;
            }
            match node.children.get(&parts[depth]) {
                Some(child) => node = child,
                None => return false,
            }
        }
        false
    }

    /// The Clears that can hide the cells of `entity` (its own, and recursive ones at its
    /// strict ancestors) as a dataframe column on `timeline` over `range` sees them: the
    /// greatest static one, the greatest temporal one before the range, and every
    /// temporal one inside it, ascending.
    pub fn column_clears(
        &self,
        entity: &EntityPath,
        timeline: &str,
        range: TimeRange,
    ) -> ColumnClears {
        self.root.column_clears(entity, timeline, range)
    }

    /// The temporal recursive Clears of `entity`'s strict ancestors on `timeline` inside
    /// `range`, ascending, without repeats: where the `Clear:is_recursive` column of
    /// `entity` shows an ancestor's Clear in a dataframe (no Clear hides that column).
    pub fn ancestor_recursive_clears(
        &self,
        entity: &EntityPath,
        timeline: &str,
        range: TimeRange,
    ) -> Vec<(TimeInt, RowId)> {
        self.root.ancestor_recursive_clears(entity, timeline, range)
    }

    /// The tree's checks, and the filter's: every entity holding Clears has its bits, the
    /// count of such entities is right, and at most `stale` bits are set beyond those.
    pub fn sanity_check(&self) -> Result<(), SanityError> {
        self.root.sanity_check_below(PathPart::ROOT_HASH)?;
        self.filter.sanity_check(&self.root)
    }
}

impl ClearNode {
    fn is_empty(&self) -> bool {
        self.clears.is_none() && self.children.is_empty()
    }

    /// Calls `visit` with the path hash and node of each entity holding Clears at or below
    /// this node, whose path hashes to `hash`.
    fn for_each_entity<'a>(&'a self, hash: u64, visit: &mut impl FnMut(u64, &'a Self)) {
        if self.clears.is_some() {
            visit(hash, self);
        }
        for (part, child) in &self.children {
            child.for_each_entity(part.prefix_hash(), visit);
        }
    }

    /// Indexes (`insert`) or forgets the Clear `rows` of `chunk`, at `parts`.
    fn update_chunk(
        &mut self,
        parts: &[PathPart],
        chunk: &Chunk,
        rows: &[(usize, bool)],
        insert: bool,
    ) {
        let Some(clears) = self
            .node_mut(parts, insert)
            .and_then(|n| n.clears.as_mut().map(Arc::make_mut))
        else {
            return;
        };
        let id = chunk.id();
        let row_ids = chunk.row_ids();
        for &(row, recursive) in rows {
            let row_id = row_ids[row];
            if chunk.is_static() {
                update_multiset(&mut clears.static_any, (row_id, id), insert);
                if recursive {
                    update_multiset(&mut clears.static_recursive, (row_id, id), insert);
                }
            }
            for column in chunk.time_columns() {
                let name = column.timeline().name_arc();
                let key = (TimeInt::saturating(column.times()[row]), row_id, id);
                let update = |per_timeline: &mut SmallMap<Arc<str>, _>| {
                    if insert {
                        update_multiset(per_timeline.get_or_default(Arc::clone(name)), key, true);
                    } else if let Some(set) = per_timeline.get_mut(&**name) {
                        update_multiset(set, key, false);
                        if set.is_empty() {
                            per_timeline.remove(&**name);
                        }
                    }
                };
                update(&mut clears.any_per_timeline);
                if recursive {
                    update(&mut clears.recursive_per_timeline);
                }
            }
        }
        if !insert {
            self.prune(parts);
        }
    }

    /// The node of `parts`, if there is one.
    fn node(&self, parts: &[PathPart]) -> Option<&Self> {
        let mut node = self;
        for part in parts {
            node = node.children.get(part)?;
        }
        Some(node)
    }

    /// The node of `parts`, created (with empty Clears) if `create`; every node on the way
    /// is made this index's own (copied if a snapshot shares it).
    fn node_mut(&mut self, parts: &[PathPart], create: bool) -> Option<&mut Self> {
        let mut node = self;
        for part in parts {
            let child = if create {
                node.children.entry(part.clone()).or_default()
            } else {
                node.children.get_mut(part)?
            };
            node = Arc::make_mut(child);
        }
        if create {
            node.clears.get_or_insert_with(Arc::default);
        }
        Some(node)
    }

    /// Drops empty Clears and empty subtrees along `parts`, so the index stays as small as
    /// what it holds.
    fn prune(&mut self, parts: &[PathPart]) {
        if let Some((first, rest)) = parts.split_first()
            && let Some(child) = self.children.get_mut(first)
        {
            // Already this index's own: `node_mut` copied the path before the removal.
            let child = Arc::make_mut(child);
            child.prune(rest);
            if child.is_empty() {
                self.children.remove(first);
            }
        }
        if self.clears.as_ref().is_some_and(|c| c.is_empty()) {
            self.clears = None;
        }
    }

    fn collect_static(
        &self,
        parts: &mut Vec<Arc<str>>,
        out: &mut Vec<(EntityPath, RowId, ChunkId, bool)>,
    ) {
        if let Some(clears) = &self.clears
            && let Ok(path) = EntityPath::try_from_parts(parts.iter().cloned())
        {
            for &(row_id, chunk_id) in clears.static_any.keys() {
                let recursive = clears.static_recursive.contains_key(&(row_id, chunk_id));
                out.push((path.clone(), row_id, chunk_id, recursive));
            }
        }
        for (part, child) in &self.children {
            parts.push(Arc::clone(part.name()));
            child.collect_static(parts, out);
            parts.pop();
        }
    }

    /// The Clears that can hide the cells of `entity` (its own, and recursive ones at its
    /// strict ancestors) as a dataframe column on `timeline` over `range` sees them: the
    /// greatest static one, the greatest temporal one before the range, and every
    /// temporal one inside it, ascending.
    fn column_clears(&self, entity: &EntityPath, timeline: &str, range: TimeRange) -> ColumnClears {
        let mut out = ColumnClears::default();
        let parts = entity.path_parts();
        let mut node = self;
        for depth in 0..=parts.len() {
            if let Some(clears) = &node.clears {
                let (statics, per_timeline) = if depth == parts.len() {
                    (&clears.static_any, &clears.any_per_timeline)
                } else {
                    (&clears.static_recursive, &clears.recursive_per_timeline)
                };
                if let Some((&(row_id, _), _)) = statics.last_key_value() {
                    out.latest_static = out.latest_static.max(Some(row_id));
                }
                if let Some(set) = per_timeline.get(timeline) {
                    let start = (range.min(), RowId::ZERO, ChunkId::ZERO);
                    if let Some((&(time, row_id, _), _)) = set.range(..start).next_back() {
                        out.latest_before = out.latest_before.max(Some((time, row_id)));
                    }
                    if !range.is_empty() {
                        let end = (range.max(), RowId::MAX, ChunkId::MAX);
                        out.in_range.extend(
                            set.range(start..=end)
                                .map(|(&(time, row_id, _), _)| (time, row_id)),
                        );
                    }
                }
            }
            match parts.get(depth).and_then(|part| node.children.get(part)) {
                Some(child) => node = child,
                None => break,
            }
        }
        out.in_range.sort_unstable();
        out.in_range.dedup();
        out
    }

    /// The temporal recursive Clears of `entity`'s strict ancestors on `timeline` inside
    /// `range`, ascending, without repeats: where the `Clear:is_recursive` column of
    /// `entity` shows an ancestor's Clear in a dataframe (no Clear hides that column).
    fn ancestor_recursive_clears(
        &self,
        entity: &EntityPath,
        timeline: &str,
        range: TimeRange,
    ) -> Vec<(TimeInt, RowId)> {
        let mut out = Vec::new();
        if range.is_empty() {
            return out;
        }
        let parts = entity.path_parts();
        let mut node = self;
        for part in parts {
            if let Some(set) = node
                .clears
                .as_ref()
                .and_then(|clears| clears.recursive_per_timeline.get(timeline))
            {
                let start = (range.min(), RowId::ZERO, ChunkId::ZERO);
                let end = (range.max(), RowId::MAX, ChunkId::MAX);
                out.extend(
                    set.range(start..=end)
                        .map(|(&(time, row_id, _), _)| (time, row_id)),
                );
            }
            match node.children.get(part) {
                Some(child) => node = child,
                None => break,
            }
        }
        out.sort_unstable();
        out.dedup();
        out
    }

    /// The checks of the node whose path hashes to `path_hash`, and of its subtree.
    fn sanity_check_below(&self, path_hash: u64) -> Result<(), SanityError> {
        let Self { clears, children } = self;
        if let Some(clears) = clears {
            let EntityClears {
                any_per_timeline,
                recursive_per_timeline,
                static_any,
                static_recursive,
            } = &**clears;
            let counts_positive = any_per_timeline
                .values()
                .chain(recursive_per_timeline.values())
                .all(|set| !set.is_empty() && set.values().all(|&n| n > 0))
                && static_any
                    .values()
                    .chain(static_recursive.values())
                    .all(|&n| n > 0);
            if !counts_positive || clears.is_empty() {
                return Err(SanityError::new(
                    Structure::ClearIndex,
                    "clear multisets hold positive counts and no empty sets",
                ));
            }
            any_per_timeline.sanity_check()?;
            recursive_per_timeline.sanity_check()?;
            for (timeline, recursive) in recursive_per_timeline.iter() {
                let any = any_per_timeline.get(timeline);
                if !recursive
                    .keys()
                    .all(|k| any.is_some_and(|a| a.contains_key(k)))
                    || static_recursive.keys().any(|k| !static_any.contains_key(k))
                {
                    return Err(SanityError::new(
                        Structure::ClearIndex,
                        "every recursive Clear is also among all Clears",
                    ));
                }
            }
        }
        for (part, child) in children {
            ensure(
                !child.is_empty(),
                Structure::ClearIndex,
                "clear index holds no empty subtrees",
            )?;
            ensure(
                part.extends(path_hash),
                Structure::ClearIndex,
                "each child's key carries the hash of its parent's path extended by its name",
            )?;
            child.sanity_check_below(part.prefix_hash())?;
        }
        Ok(())
    }
}

/// The greatest Clear of `set` at or before `at`. A query's time is most often past the
/// last Clear or before the first, which the set's edges answer without the search of a
/// range (a third of the walk's instructions in `clear_recursive`).
fn latest_at_or_before(
    set: &IndexMultiset<(TimeInt, RowId, ChunkId)>,
    at: TimeInt,
) -> Option<&(TimeInt, RowId, ChunkId)> {
    let (last, _) = set.last_key_value()?;
    if last.0 <= at {
        return Some(last);
    }
    let (first, _) = set.first_key_value()?;
    if first.0 > at {
        return None;
    }
    set.range(..=(at, RowId::MAX, ChunkId::MAX))
        .next_back()
        .map(|(key, _)| key)
}

fn update_multiset<K: Ord>(set: &mut IndexMultiset<K>, key: K, insert: bool) {
    if insert {
        *set.entry(key).or_default() += 1;
    } else if let std::collections::btree_map::Entry::Occupied(mut entry) = set.entry(key) {
        *entry.get_mut() -= 1;
        if *entry.get() == 0 {
            entry.remove();
        }
    }
}

impl EntityClears {
    fn is_empty(&self) -> bool {
        self.any_per_timeline.is_empty()
            && self.recursive_per_timeline.is_empty()
            && self.static_any.is_empty()
            && self.static_recursive.is_empty()
    }

    fn hides(
        &self,
        is_self: bool,
        timeline: &str,
        at: TimeInt,
        time: Option<TimeInt>,
        row_id: RowId,
    ) -> bool {
        let (statics, per_timeline) = if is_self {
            (&self.static_any, &self.any_per_timeline)
        } else {
            (&self.static_recursive, &self.recursive_per_timeline)
        };
        // A static Clear hides all temporal data, and static data with a smaller row id.
        if let Some((&(latest_static, _), _)) = statics.last_key_value() {
            match time {
                None if row_id <= latest_static => return true,
                Some(_) => return true,
                None => {}
            }
        }
        // A temporal Clear only hides temporal data, and only once it is visible at `at`.
        let Some(time) = time else { return false };
        per_timeline
            .get(timeline)
            .and_then(|set| latest_at_or_before(set, at))
            .is_some_and(|&(clear_time, clear_row_id, _)| {
                (time, row_id) <= (clear_time, clear_row_id)
            })
    }
}
