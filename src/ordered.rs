//! [`OrderedSet`]: a sorted set that is a plain deque while keys arrive in order and leave
//! from its ends, and a B-tree otherwise.
//!
//! The store keeps its chunks in a few global orders (by least row id; per timeline by
//! least and greatest time) for garbage collection and drops. Chunks usually arrive in
//! those orders (row ids grow; time mostly does) and usually leave from their ends (oldest
//! first, or furthest from a cursor), where a deque does in O(1) what a B-tree does in
//! O(log n) node searches. The first key that would land far from both ends turns the set
//! into a B-tree for good (until it empties), so no pattern of use costs more than the
//! B-tree would, plus one conversion.

use std::collections::{BTreeSet, VecDeque, btree_set, vec_deque};

use crate::sanity::{SanityError, Structure, ensure};

/// Inserting or removing this far from the nearer end of a deque still shifts it; farther
/// turns the set into a B-tree.
const MAX_SHIFT: usize = 32;

/// A sorted set of `Copy` keys; see the module docs.
#[derive(Clone, Debug)]
pub(crate) enum OrderedSet<K> {
    /// Sorted, no duplicates.
    Deque(VecDeque<K>),
    Tree(BTreeSet<K>),
}

impl<K> Default for OrderedSet<K> {
    fn default() -> Self {
        Self::Deque(VecDeque::new())
    }
}

impl<K: Ord + Copy> OrderedSet<K> {
    /// Adds `key`; returns whether it was new.
    pub fn insert(&mut self, key: K) -> bool {
        match self {
            Self::Deque(keys) => {
                match keys.back() {
                    None => {
                        keys.push_back(key);
                        return true;
                    }
                    Some(last) if *last < key => {
                        keys.push_back(key);
                        return true;
                    }
                    _ => {}
                }
                if keys.front().is_some_and(|first| key < *first) {
                    keys.push_front(key);
                    return true;
                }
                match keys.binary_search(&key) {
                    Ok(_) => false,
                    Err(position) if position.min(keys.len() - position) <= MAX_SHIFT => {
                        keys.insert(position, key);
                        true
                    }
                    Err(_) => {
                        let mut tree: BTreeSet<K> = keys.drain(..).collect();
                        tree.insert(key);
                        *self = Self::Tree(tree);
                        true
                    }
                }
            }
            Self::Tree(tree) => tree.insert(key),
        }
    }

    /// Removes `key`; returns whether it was there.
    pub fn remove(&mut self, key: &K) -> bool {
        match self {
            Self::Deque(keys) => {
                // Most removals are at an end (oldest first, or around a cursor).
                if keys.front() == Some(key) {
                    keys.pop_front();
                    return true;
                }
                if keys.back() == Some(key) {
                    keys.pop_back();
                    return true;
                }
                let Ok(position) = keys.binary_search(key) else {
                    return false;
                };
                if position.min(keys.len() - 1 - position) <= MAX_SHIFT {
                    keys.remove(position);
                    if keys.len() * 4 <= keys.capacity() {
                        keys.shrink_to(keys.len() * 2);
                    }
                } else {
                    let mut tree: BTreeSet<K> = keys.drain(..).collect();
                    tree.remove(key);
                    *self = Self::Tree(tree);
                }
                true
            }
            Self::Tree(tree) => {
                let removed = tree.remove(key);
                if tree.is_empty() {
                    *self = Self::default();
                }
                removed
            }
        }
    }

    pub fn is_empty(&self) -> bool {
        match self {
            Self::Deque(keys) => keys.is_empty(),
            Self::Tree(tree) => tree.is_empty(),
        }
    }

    /// The keys in ascending order.
    pub fn iter(&self) -> Iter<'_, K> {
        match self {
            Self::Deque(keys) => Iter::Deque(keys.iter()),
            Self::Tree(tree) => Iter::Tree(tree.iter()),
        }
    }

    /// The keys from `first` on, ascending.
    pub fn iter_from(&self, first: &K) -> Iter<'_, K> {
        match self {
            Self::Deque(keys) => Iter::Deque(keys.range(keys.partition_point(|k| k < first)..)),
            Self::Tree(tree) => Iter::TreeRange(tree.range(first..)),
        }
    }

    /// Is the set sorted, without duplicates? (A B-tree always is.)
    pub fn sanity_check(&self) -> Result<(), SanityError> {
        match self {
            Self::Deque(keys) => {
                let ascending = keys.iter().zip(keys.iter().skip(1)).all(|(a, b)| a < b);
                ensure(
                    ascending,
                    Structure::OrderedSet,
                    "an ordered set's deque is strictly ascending",
                )
            }
            Self::Tree(_) => Ok(()),
        }
    }

    /// The set of `keys`, in any order: one sort, where inserting them one by one into a
    /// B-tree searches it per key (a rebuild of the store-wide orders; see
    /// [`crate::ChunkStore`]'s `restore_global_orders`).
    pub fn from_keys(mut keys: Vec<K>) -> Self {
        keys.sort_unstable();
        keys.dedup();
        Self::Deque(keys.into())
    }
}

impl<K: Ord + Copy> PartialEq for OrderedSet<K> {
    fn eq(&self, other: &Self) -> bool {
        self.iter().eq(other.iter())
    }
}

impl<K: Ord + Copy> FromIterator<K> for OrderedSet<K> {
    fn from_iter<I: IntoIterator<Item = K>>(keys: I) -> Self {
        let mut set = Self::default();
        for key in keys {
            set.insert(key);
        }
        set
    }
}

/// An ascending iterator over an [`OrderedSet`], from either end.
pub(crate) enum Iter<'a, K> {
    Deque(vec_deque::Iter<'a, K>),
    Tree(btree_set::Iter<'a, K>),
    TreeRange(btree_set::Range<'a, K>),
}

impl<'a, K> Iterator for Iter<'a, K> {
    type Item = &'a K;

    fn next(&mut self) -> Option<&'a K> {
        match self {
            Self::Deque(keys) => keys.next(),
            Self::Tree(keys) => keys.next(),
            Self::TreeRange(keys) => keys.next(),
        }
    }
}

impl<K> DoubleEndedIterator for Iter<'_, K> {
    fn next_back(&mut self) -> Option<Self::Item> {
        match self {
            Self::Deque(keys) => keys.next_back(),
            Self::Tree(keys) => keys.next_back(),
            Self::TreeRange(keys) => keys.next_back(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every operation agrees with a `BTreeSet`, whatever the order of keys: in order,
    /// reversed, from both ends, and scattered (which turns the deque into a tree).
    #[test]
    fn agrees_with_a_btree_set() {
        let patterns: [Vec<i64>; 4] = [
            (0..200).collect(),
            (0..200).rev().collect(),
            (0..200).map(|k| if k % 2 == 0 { k } else { -k }).collect(),
            (0..200).map(|k| (k * 7919) % 211).collect(),
        ];
        for keys in patterns {
            let mut set = OrderedSet::default();
            let mut model = BTreeSet::new();
            for &k in &keys {
                assert_eq!(set.insert(k), model.insert(k), "insert {k}");
                assert_eq!(set.insert(k), model.insert(k), "insert {k} again");
                set.sanity_check().unwrap();
            }
            assert!(set.iter().eq(model.iter()));
            assert!(set.iter().rev().eq(model.iter().rev()));
            assert!(set.iter_from(&50).eq(model.range(50..)));
            for &k in keys.iter().step_by(3).chain(keys.iter().rev().step_by(5)) {
                assert_eq!(set.remove(&k), model.remove(&k), "remove {k}");
                set.sanity_check().unwrap();
            }
            assert!(set.iter().eq(model.iter()));
            assert_eq!(set.is_empty(), model.is_empty());
        }
    }
}
