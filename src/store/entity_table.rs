//! [`EntityTable`]: the store view's entity map, built so that a write copies little while a
//! snapshot shares it.
//!
//! A [`SharedStore`](crate::SharedStore) that publishes after every insert makes each write
//! copy what the last published snapshot shares on the way to the entity it changes. Keyed
//! by path in one hash trie, that path was a trie node of up to 32 (path, view) entries and
//! its children: about 2,600 instructions to copy and 2,300 to free once the old version
//! went, per insert, at 100 entities (`docs/performance-log.md`). So the map is two pieces:
//!
//! - a **directory** from path to a small integer, the entity's *slot*: a hash map that
//!   changes only when an entity comes or goes (see [`Directory`] for how it is shared);
//! - a **slot table**: a persistent radix tree of 16-way nodes from slot to the entity's
//!   view. Slots are dense (a freed slot is reused first), so at `n` entities the tree is
//!   `⌈log₁₆ n⌉` levels deep, and a write copies that many nodes of 16 pointers.
//!
//! The store's writer keeps each entity's slot in its own part of the entity
//! ([`EntityIndex::slot`](super::EntityIndex)), so an insert finds the entity with the
//! hash lookup of its own map it makes anyway and walks the slot table without hashing
//! the path again. A reader looks up the path in the directory, then walks the table.

use std::sync::Arc;

use crate::EntityPath;
use crate::sanity::{SanityError, Structure, ensure};

/// The directory: path to slot, as a hash map shared with snapshots and the changes made
/// since it was last copied.
///
/// A reader's lookup is a hash map's (about a third of a hash trie's instructions, measured
/// on `latest_at_mono`), and the map is never copied whole for one entity: while a snapshot
/// shares it, entities that come or go are noted in `recent`, a small map copied instead,
/// and folded into a fresh copy of `base` once they are more than about the square root of
/// its size. An entity created per insert under a `SharedStore` publishing each insert
/// thus costs O(√n) amortized, where copying the whole map each time would be O(n).
#[derive(Clone, Debug, Default)]
struct Directory {
    base: Arc<ahash::HashMap<EntityPath, u32>>,
    /// Entities added (`Some`) or removed (`None`) since `base` was last copied, while a
    /// snapshot shared it; folded into `base` by the first change made once none does.
    /// `None` rather than empty, so that a lookup reads nothing more when there are none.
    recent: Option<Arc<ahash::HashMap<EntityPath, Option<u32>>>>,
    len: usize,
}

impl Directory {
    fn get(&self, path: &EntityPath) -> Option<u32> {
        if let Some(recent) = &self.recent
            && let Some(&slot) = recent.get(path)
        {
            return slot;
        }
        self.base.get(path).copied()
    }

    fn set(&mut self, path: EntityPath, slot: Option<u32>) {
        if let Some(base) = Arc::get_mut(&mut self.base) {
            // Nobody shares the base: write there, with whatever was noted meanwhile.
            fold(self.recent.take().as_deref(), base);
            apply(base, path, slot);
            return;
        }
        let in_base = self.base.contains_key(&path);
        let recent = Arc::make_mut(self.recent.get_or_insert_with(Arc::default));
        if slot.is_none() && !in_base {
            recent.remove(&path);
        } else {
            recent.insert(path, slot);
        }
        if recent.len() > 8 + self.base.len().isqrt() {
            let mut base = (*self.base).clone();
            fold(self.recent.take().as_deref(), &mut base);
            self.base = Arc::new(base);
        } else if recent.is_empty() {
            self.recent = None;
        }
    }

    fn insert(&mut self, path: EntityPath, slot: u32) {
        self.len += 1;
        self.set(path, Some(slot));
    }

    fn remove(&mut self, path: &EntityPath) -> Option<u32> {
        let slot = self.get(path)?;
        self.len -= 1;
        self.set(path.clone(), None);
        Some(slot)
    }

    fn iter(&self) -> impl Iterator<Item = (&EntityPath, u32)> {
        let recent = self.recent.as_deref();
        self.base
            .iter()
            .filter(move |(path, _)| recent.is_none_or(|recent| !recent.contains_key(*path)))
            .map(|(path, &slot)| (path, slot))
            .chain(
                recent
                    .into_iter()
                    .flat_map(|recent| recent.iter())
                    .filter_map(|(path, slot)| slot.map(|slot| (path, slot))),
            )
    }
}

/// Applies the changes noted in `recent` (if any) to `base`.
fn fold(
    recent: Option<&ahash::HashMap<EntityPath, Option<u32>>>,
    base: &mut ahash::HashMap<EntityPath, u32>,
) {
    for (path, slot) in recent.into_iter().flatten() {
        apply(base, path.clone(), *slot);
    }
}

/// Adds (`Some`) or removes (`None`) one entity of `base`.
fn apply(base: &mut ahash::HashMap<EntityPath, u32>, path: EntityPath, slot: Option<u32>) {
    match slot {
        Some(slot) => base.insert(path, slot),
        None => base.remove(&path),
    };
}

/// Bits of a slot each level of the table consumes.
const SHIFT: u32 = 4;
/// Children per node.
const FANOUT: usize = 1 << SHIFT;
const MASK: u32 = (1 << SHIFT) - 1;

/// Does a table `depth` levels below its root have a place for `slot`? (Checked: a table
/// of eight levels holds every `u32`.)
fn fits(slot: u32, depth: u32) -> bool {
    slot.checked_shr(SHIFT * (depth + 1)).unwrap_or(0) == 0
}

/// The child index of `slot` at `level` (0 is the leaves' level).
fn child(slot: u32, level: u32) -> usize {
    ((slot >> (SHIFT * level)) & MASK) as usize
}

/// A node of the slot table: the last level holds the views, the others their subtrees.
#[derive(Clone, Debug)]
enum Node<V> {
    Leaf([Option<Arc<V>>; FANOUT]),
    Branch([Option<Arc<Node<V>>>; FANOUT]),
}

impl<V> Node<V> {
    fn empty(level: u32) -> Self {
        if level == 0 {
            Self::Leaf(Default::default())
        } else {
            Self::Branch(Default::default())
        }
    }

    /// Calls `visit` with each view below this node and its slot.
    fn for_each<'a>(&'a self, level: u32, base: u32, visit: &mut impl FnMut(u32, &'a V)) {
        match self {
            Self::Leaf(views) => {
                for (i, view) in (0u32..).zip(views) {
                    if let Some(view) = view {
                        visit(base | i, view);
                    }
                }
            }
            Self::Branch(children) => {
                for (i, child) in (0u32..).zip(children) {
                    if let Some(child) = child {
                        child.for_each(level - 1, base | (i << (SHIFT * level)), visit);
                    }
                }
            }
        }
    }
}

/// The entity map of a [`StoreView`](super::StoreView) (`EntityTable<EntityView>`); see
/// the module docs. Cloning it is O(1); a write copies the directory's path only when an
/// entity comes or goes, and otherwise `depth` nodes of the slot table, where a snapshot
/// still shares them. Generic in what it holds per entity only so that this module does not
/// depend on the view, which holds it.
#[derive(Clone, Debug)]
pub(crate) struct EntityTable<V> {
    directory: Directory,
    root: Option<Arc<Node<V>>>,
    /// Levels below the root: the table holds slots `0..FANOUT^(depth + 1)`.
    depth: u32,
    /// Slots no entity holds, below `next_slot`: reused before new ones, so that the table
    /// stays as shallow as the number of entities allows.
    free_slots: Arc<Vec<u32>>,
    /// The least slot never handed out.
    next_slot: u32,
}

impl<V> Default for EntityTable<V> {
    fn default() -> Self {
        Self {
            directory: Directory::default(),
            root: None,
            depth: 0,
            free_slots: Arc::default(),
            next_slot: 0,
        }
    }
}

impl<V: Clone + Default> EntityTable<V> {
    /// How many entities the map holds.
    pub fn len(&self) -> usize {
        self.directory.len
    }

    /// The entity's slot, if the map holds it.
    pub fn slot(&self, path: &EntityPath) -> Option<u32> {
        self.directory.get(path)
    }

    /// The view at `path`.
    pub fn get(&self, path: &EntityPath) -> Option<&Arc<V>> {
        self.at(self.slot(path)?)
    }

    /// The view in `slot`.
    pub fn at(&self, slot: u32) -> Option<&Arc<V>> {
        let mut node = self.root.as_deref()?;
        if !fits(slot, self.depth) {
            return None;
        }
        let mut level = self.depth;
        loop {
            match node {
                Node::Branch(children) => {
                    node = children[child(slot, level)].as_deref()?;
                    level -= 1;
                }
                Node::Leaf(views) => return views[child(slot, 0)].as_ref(),
            }
        }
    }

    /// The view in `slot`, ready to change: the table's nodes on the way are copied first
    /// if a snapshot shares them (the view itself is the caller's to copy, with
    /// [`Arc::make_mut`], as it changes it).
    pub fn at_mut(&mut self, slot: u32) -> Option<&mut Arc<V>> {
        if !fits(slot, self.depth) {
            return None;
        }
        let mut node = Arc::make_mut(self.root.as_mut()?);
        let mut level = self.depth;
        loop {
            match node {
                Node::Branch(children) => {
                    node = Arc::make_mut(children[child(slot, level)].as_mut()?);
                    level -= 1;
                }
                Node::Leaf(views) => return views[child(slot, 0)].as_mut(),
            }
        }
    }

    /// Adds an entity the map does not hold, with an empty view; returns its slot.
    pub fn add(&mut self, path: EntityPath) -> u32 {
        debug_assert!(self.directory.get(&path).is_none());
        // A snapshot may share the free list: it is copied only if it has a slot to give.
        let reused = if self.free_slots.is_empty() {
            None
        } else {
            Arc::make_mut(&mut self.free_slots).pop()
        };
        let slot = if let Some(slot) = reused {
            slot
        } else {
            let slot = self.next_slot;
            self.next_slot += 1;
            slot
        };
        self.directory.insert(path, slot);
        *self.place(slot) = Some(Arc::default());
        slot
    }

    /// Removes the entity at `path`; returns its view.
    pub fn remove(&mut self, path: &EntityPath) -> Option<Arc<V>> {
        let slot = self.directory.remove(path)?;
        let view = self.place(slot).take();
        Arc::make_mut(&mut self.free_slots).push(slot);
        if self.directory.len == 0 {
            // Start over shallow: a store that forgot everything holds no table.
            *self = Self::default();
        }
        view
    }

    /// The place of `slot` in the table, growing the table (a level at a time, the old
    /// root becoming the first child of the new one) and creating nodes on the way.
    fn place(&mut self, slot: u32) -> &mut Option<Arc<V>> {
        while !fits(slot, self.depth) {
            let mut root = Node::empty(self.depth + 1);
            if let (Node::Branch(children), Some(old)) = (&mut root, self.root.take()) {
                children[0] = Some(old);
            }
            self.root = Some(Arc::new(root));
            self.depth += 1;
        }
        let mut level = self.depth;
        let mut node = Arc::make_mut(
            self.root
                .get_or_insert_with(|| Arc::new(Node::empty(level))),
        );
        loop {
            match node {
                Node::Branch(children) => {
                    let child = children[child(slot, level)]
                        .get_or_insert_with(|| Arc::new(Node::empty(level - 1)));
                    node = Arc::make_mut(child);
                    level -= 1;
                }
                Node::Leaf(views) => return &mut views[child(slot, 0)],
            }
        }
    }

    /// Every entity's path, in no particular order.
    pub fn keys(&self) -> impl Iterator<Item = &EntityPath> {
        self.directory.iter().map(|(path, _)| path)
    }

    /// Every entity's view, in no particular order.
    pub fn values(&self) -> impl Iterator<Item = &V> {
        self.iter().map(|(_, view)| view)
    }

    /// Every entity with its view, in no particular order.
    pub fn iter(&self) -> impl Iterator<Item = (&EntityPath, &V)> {
        self.directory.iter().filter_map(|(path, slot)| {
            // Every slot of the directory holds a view (`sanity_check`).
            Some((path, &**self.at(slot)?))
        })
    }

    /// The table's own invariants: the directory and the table hold the same slots, each
    /// once; a free slot is empty and below the next one; the table is as deep as the slots
    /// handed out need.
    pub fn sanity_check(&self) -> Result<(), SanityError> {
        let mut held = Vec::new();
        if let Some(root) = &self.root {
            root.for_each(self.depth, 0, &mut |slot, _| held.push(slot));
        }
        let mut listed: Vec<u32> = self.directory.iter().map(|(_, slot)| slot).collect();
        listed.sort_unstable();
        listed.dedup();
        ensure(
            held.len() == self.directory.len
                && listed.len() == self.directory.len
                && listed.iter().all(|&slot| self.at(slot).is_some()),
            Structure::Entity,
            "the entity directory and its slot table hold the same slots",
        )?;
        let mut free = self.free_slots.to_vec();
        free.sort_unstable();
        free.dedup();
        ensure(
            free.len() == self.free_slots.len()
                && free
                    .iter()
                    .all(|&slot| slot < self.next_slot && self.at(slot).is_none())
                && free.len() + held.len() == self.next_slot as usize,
            Structure::Entity,
            "each slot below the next is held or free, once",
        )?;
        ensure(
            self.depth == 0 || self.next_slot > 1 << (SHIFT * self.depth),
            Structure::Entity,
            "the slot table is no deeper than its slots need",
        )
    }
}

#[cfg(test)]
impl<V: Clone + Default> std::ops::Index<&EntityPath> for EntityTable<V> {
    type Output = V;

    /// The view at `path`; panics if the map does not hold it (tests only read entities
    /// they know).
    fn index(&self, path: &EntityPath) -> &V {
        self.get(path).expect("the entity is in the map")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path(i: usize) -> EntityPath {
        EntityPath::parse(&format!("/e/{i}")).expect("a valid path")
    }

    #[test]
    fn slots_are_dense_reused_and_shared_views_stay_frozen() {
        let mut map = EntityTable::<u64>::default();
        for i in 0..300u32 {
            assert_eq!(map.add(path(i as usize)), i);
            *Arc::make_mut(map.at_mut(i).expect("just added")) = u64::from(i);
        }
        map.sanity_check().expect("a sound map");
        assert_eq!(map.depth, 2, "300 slots need three levels of 16");
        let frozen = map.clone();

        // A write after the clone copies its path; the clone keeps what it saw.
        let slot = map.slot(&path(7)).expect("held");
        *Arc::make_mut(map.at_mut(slot).expect("held")) = 1_000;
        assert_eq!(map[&path(7)], 1_000);
        assert_eq!(frozen[&path(7)], 7);
        // Untouched nodes stay shared.
        assert!(Arc::ptr_eq(
            map.get(&path(299)).expect("held"),
            frozen.get(&path(299)).expect("held"),
        ));

        assert_eq!(*map.remove(&path(5)).expect("held"), 5);
        assert!(map.get(&path(5)).is_none());
        assert_eq!(map.add(path(1_000)), 5, "a freed slot is reused first");
        map.sanity_check().expect("a sound map");
        assert_eq!(map.len(), 300);
        assert_eq!(frozen.len(), 300);
        assert!(frozen.get(&path(5)).is_some());

        let mut seen: Vec<u64> = map.values().copied().collect();
        seen.sort_unstable();
        let mut expected: Vec<u64> = (0..300).filter(|&i| i != 5 && i != 7).collect();
        expected.extend([0, 1_000]);
        expected.sort_unstable();
        assert_eq!(seen, expected);
        assert_eq!(map.iter().count(), 300);
        assert_eq!(map.keys().count(), 300);

        for i in (0..300).chain([1_000]) {
            map.remove(&path(i));
        }
        assert_eq!(map.len(), 0);
        assert!(map.root.is_none(), "an empty map holds no table");
        map.sanity_check().expect("a sound map");
        frozen.sanity_check().expect("a sound map");
    }

    #[test]
    fn entities_coming_and_going_under_a_snapshot_leave_it_as_it_was() {
        let mut map = EntityTable::<u64>::default();
        for i in 0..100 {
            map.add(path(i));
        }
        let before = map.clone();
        // Enough to fold the recent changes into a fresh base a few times over.
        for i in 100..400 {
            map.add(path(i));
            let frozen = map.clone();
            map.remove(&path(i - 100));
            assert!(frozen.get(&path(i - 100)).is_some());
            assert_eq!(frozen.len(), 101);
            frozen.sanity_check().expect("a sound map");
        }
        map.sanity_check().expect("a sound map");
        assert_eq!(map.len(), 100);
        assert!((300..400).all(|i| map.get(&path(i)).is_some()));
        assert!((0..300).all(|i| map.get(&path(i)).is_none()));
        assert_eq!(map.keys().count(), 100);
        assert_eq!(before.len(), 100);
        assert!((0..100).all(|i| before.get(&path(i)).is_some()));
        assert!((100..400).all(|i| before.get(&path(i)).is_none()));
        before.sanity_check().expect("a sound map");
        drop(before);
        // Nobody shares it any more: the next change folds what was noted.
        map.add(path(1_000));
        assert!(map.directory.recent.is_none());
        assert_eq!(map.len(), 101);
        map.sanity_check().expect("a sound map");
    }

    #[test]
    fn slots_past_the_table_are_absent() {
        let mut map = EntityTable::<u64>::default();
        assert!(map.at(0).is_none());
        map.add(path(0));
        assert!(map.at(16).is_none());
        assert!(map.at(u32::MAX).is_none());
        assert!(map.at_mut(u32::MAX).is_none());
    }
}
