//! [`SmallMap`]: a map for the few keys an entity has (its timelines, its components), as
//! one vector searched linearly, turning into a hash map past [`SMALL_MAP_MAX_KEYS`].
//!
//! An entity usually has one to three timelines and a handful of components. A hash map
//! for each costs a table allocation and a string hash per lookup; a short vector is one
//! allocation next to its neighbours, and comparing a few short names (lengths first) is
//! cheaper than hashing one. A viewer's store holds thousands of entities, so this is what
//! decides how many cache lines a query touches before it reaches the data.

use std::borrow::Borrow;
use std::hash::Hash;

use smallvec::SmallVec;

use crate::sanity::{SanityError, Structure, ensure};

/// Past this many keys, a [`SmallMap`] is a hash map.
const SMALL_MAP_MAX_KEYS: usize = 16;

/// A map; see the module docs. Iteration order is unspecified.
#[derive(Clone, Debug)]
pub(crate) enum SmallMap<K, V> {
    /// The first entry inline: most entities have one timeline and a few components, and an
    /// inline entry is one pointer less to follow on every query (the hash map variant is
    /// larger anyway, so it costs no room).
    Few(SmallVec<[(K, V); 1]>),
    Many(ahash::HashMap<K, V>),
}

/// Key equality with a shortcut, for the keys and for what a lookup compares them with:
/// names are usually one shared allocation (see [`crate::interner`]), and short ones
/// compare as words ([`crate::text::same_text`]), where `str`'s own equality calls
/// `memcmp` whatever the length.
pub(crate) trait SmallMapKey: Eq + Hash {
    fn same_key(&self, other: &Self) -> bool {
        self == other
    }
}

impl SmallMapKey for str {
    #[inline]
    fn same_key(&self, other: &Self) -> bool {
        crate::text::same_text(self, other)
    }
}

impl SmallMapKey for std::sync::Arc<str> {
    fn same_key(&self, other: &Self) -> bool {
        crate::interner::same_name(self, other)
    }
}

/// Its equality already compares with [`crate::text::same_text`].
impl SmallMapKey for crate::ComponentName {}

impl SmallMapKey for crate::ChunkId {}

#[cfg(test)]
impl SmallMapKey for String {}

impl<K, V> Default for SmallMap<K, V> {
    fn default() -> Self {
        Self::Few(SmallVec::new())
    }
}

/// [`SmallMap::get`] past [`SMALL_MAP_MAX_KEYS`] keys.
#[inline(never)]
fn get_many<'a, K, V, Q>(map: &'a ahash::HashMap<K, V>, key: &Q) -> Option<&'a V>
where
    K: SmallMapKey + Borrow<Q>,
    Q: SmallMapKey + ?Sized,
{
    map.get(key)
}

impl<K: SmallMapKey, V> SmallMap<K, V> {
    #[inline]
    pub fn get<Q>(&self, key: &Q) -> Option<&V>
    where
        K: Borrow<Q>,
        Q: SmallMapKey + ?Sized,
    {
        // The few keys' scan inline, the hash map's lookup out of line: with the probe
        // inlined, `get` was too large for its callers and spent 18 of its 46 instructions
        // a call saving and restoring registers (callgrind, `clear_recursive`).
        match self {
            Self::Few(entries) => entries
                .iter()
                .find(|(k, _)| k.borrow().same_key(key))
                .map(|(_, v)| v),
            Self::Many(map) => get_many(map, key),
        }
    }

    pub fn get_mut<Q>(&mut self, key: &Q) -> Option<&mut V>
    where
        K: Borrow<Q>,
        Q: SmallMapKey + ?Sized,
    {
        match self {
            Self::Few(entries) => entries
                .iter_mut()
                .find(|(k, _)| k.borrow().same_key(key))
                .map(|(_, v)| v),
            Self::Many(map) => map.get_mut(key),
        }
    }

    /// The value of `key`, inserted with `V::default()` if absent.
    pub fn get_or_default(&mut self, key: K) -> &mut V
    where
        V: Default,
    {
        if let Self::Few(entries) = self
            && entries.len() >= SMALL_MAP_MAX_KEYS
            && !entries.iter().any(|(k, _)| k.same_key(&key))
        {
            *self = Self::Many(std::mem::take(entries).into_iter().collect());
        }
        match self {
            Self::Few(entries) => {
                let position =
                    if let Some(position) = entries.iter().position(|(k, _)| k.same_key(&key)) {
                        position
                    } else {
                        entries.push((key, V::default()));
                        entries.len() - 1
                    };
                &mut entries[position].1
            }
            Self::Many(map) => map.entry(key).or_default(),
        }
    }

    /// Sets `key` to `value`.
    pub fn insert(&mut self, key: K, value: V) {
        if let Some(existing) = self.get_mut(&key) {
            *existing = value;
            return;
        }
        match self {
            Self::Few(entries) if entries.len() < SMALL_MAP_MAX_KEYS => entries.push((key, value)),
            Self::Few(entries) => {
                let mut map: ahash::HashMap<K, V> = std::mem::take(entries).into_iter().collect();
                map.insert(key, value);
                *self = Self::Many(map);
            }
            Self::Many(map) => {
                map.insert(key, value);
            }
        }
    }

    pub fn remove<Q>(&mut self, key: &Q) -> Option<V>
    where
        K: Borrow<Q>,
        Q: SmallMapKey + ?Sized,
    {
        match self {
            Self::Few(entries) => {
                let position = entries.iter().position(|(k, _)| k.borrow().same_key(key))?;
                Some(entries.swap_remove(position).1)
            }
            Self::Many(map) => map.remove(key),
        }
    }

    pub fn retain(&mut self, mut keep: impl FnMut(&K, &mut V) -> bool) {
        match self {
            Self::Few(entries) => entries.retain_mut(|(k, v)| keep(k, v)),
            Self::Many(map) => map.retain(|k, v| keep(k, v)),
        }
    }

    pub fn len(&self) -> usize {
        match self {
            Self::Few(entries) => entries.len(),
            Self::Many(map) => map.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        match self {
            Self::Few(entries) => entries.is_empty(),
            Self::Many(map) => map.is_empty(),
        }
    }

    /// The entries, in no particular order.
    pub fn iter(&self) -> Box<dyn Iterator<Item = (&K, &V)> + '_> {
        match self {
            Self::Few(entries) => Box::new(entries.iter().map(|(k, v)| (k, v))),
            Self::Many(map) => Box::new(map.iter()),
        }
    }

    /// The entries, taken out, in no particular order.
    pub fn into_entries(self) -> Box<dyn Iterator<Item = (K, V)>>
    where
        K: 'static,
        V: 'static,
    {
        match self {
            Self::Few(entries) => Box::new(entries.into_iter()),
            Self::Many(map) => Box::new(map.into_iter()),
        }
    }

    /// The values, in no particular order.
    pub fn values(&self) -> impl Iterator<Item = &V> + '_ {
        self.iter().map(|(_, v)| v)
    }

    /// The vector holds at most [`SMALL_MAP_MAX_KEYS`] distinct keys. (The hash map does
    /// not shrink back: it may hold fewer.)
    pub fn sanity_check(&self) -> Result<(), SanityError> {
        let Self::Few(entries) = self else {
            return Ok(());
        };
        let distinct = entries
            .iter()
            .enumerate()
            .all(|(i, (key, _))| entries[..i].iter().all(|(other, _)| !other.same_key(key)));
        ensure(
            entries.len() <= SMALL_MAP_MAX_KEYS && distinct,
            Structure::SmallMap,
            "a small map's vector holds at most SMALL_MAP_MAX_KEYS distinct keys",
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every operation agrees with a `HashMap`, below and past the vector's limit.
    #[test]
    fn agrees_with_a_hash_map() {
        let mut map: SmallMap<String, u32> = SmallMap::default();
        let mut model: std::collections::HashMap<String, u32> = std::collections::HashMap::new();
        for round in 0..3u32 {
            for k in 0..40u32 {
                let key = format!("k{}", (k * 7 + round) % 23);
                *map.get_or_default(key.clone()) += k;
                *model.entry(key.clone()).or_default() += k;
                assert_eq!(map.get(key.as_str()), model.get(&key));
                if k % 5 == 0 {
                    assert_eq!(map.remove(key.as_str()), model.remove(&key));
                }
                if k % 11 == 0 {
                    map.retain(|_, v| *v % 3 != 0);
                    model.retain(|_, v| *v % 3 != 0);
                }
            }
            let mut entries: Vec<_> = map.iter().map(|(k, v)| (k.clone(), *v)).collect();
            let mut expected: Vec<_> = model.iter().map(|(k, v)| (k.clone(), *v)).collect();
            entries.sort();
            expected.sort();
            assert_eq!(entries, expected);
            assert_eq!(map.is_empty(), model.is_empty());
        }
    }
}
