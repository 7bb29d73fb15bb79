//! [`Metadata`]: the string metadata a chunk keeps only to give it back on transport.

use std::cell::RefCell;
use std::collections::HashMap;
use std::sync::Arc;

thread_local! {
    /// The map [`Metadata::kept`] made last on this thread (one map: at most a few hundred
    /// bytes held past its chunks).
    static LAST_KEPT: RefCell<Option<Arc<HashMap<String, String>>>> = const { RefCell::new(None) };
}

/// String metadata kept only for lossless transport: empty for a chunk built through the
/// API, so it costs one pointer until it is not. Shared, never copied: a chunk's slices
/// and rewrites carry their source's metadata (Rerun's SDK writes some into every chunk,
/// and copying that map was a ninth of slicing a small piece off a chunk).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct Metadata(Option<Arc<HashMap<String, String>>>);

/// A string map's entries as `&str` pairs, as [`Metadata::kept_of`] and
/// `Chunk::from_transport_parts` take them.
pub(crate) fn str_entries(
    map: &HashMap<String, String>,
) -> impl Iterator<Item = (&str, &str)> + Clone {
    map.iter()
        .map(|(key, value)| (key.as_str(), value.as_str()))
}

impl Metadata {
    /// The entries of `map` that `keep` keeps: nothing is allocated when none is
    /// (decoding copies a schema's and each time field's metadata, usually all dropped),
    /// nor when they are the entries this thread kept last, whose map is shared instead.
    /// A recording's chunks mostly carry the same metadata (Rerun's SDK writes its version
    /// into each), so its chunks then hold one map, and comparing two of their layouts
    /// compares one pointer.
    pub(crate) fn kept(map: &HashMap<String, String>, keep: impl Fn(&str, &str) -> bool) -> Self {
        Self::kept_of(&str_entries(map), keep)
    }

    /// [`Metadata::kept`] of entries given one by one, their keys unique (a schema's
    /// metadata read straight from its IPC message, without a map).
    pub(crate) fn kept_of<'m>(
        entries: &(impl Iterator<Item = (&'m str, &'m str)> + Clone),
        keep: impl Fn(&str, &str) -> bool,
    ) -> Self {
        let entries = || entries.clone().filter(|&(key, value)| keep(key, value));
        if entries().next().is_none() {
            return Self(None);
        }
        LAST_KEPT.with(|last| {
            let mut last = last.borrow_mut();
            if let Some(shared) = last.as_ref()
                && entries().count() == shared.len()
                && entries().all(|(key, value)| shared.get(key).map(String::as_str) == Some(value))
            {
                return Self(Some(Arc::clone(shared)));
            }
            let kept: HashMap<String, String> = entries()
                .map(|(key, value)| (key.to_owned(), value.to_owned()))
                .collect();
            let kept = Arc::new(kept);
            *last = Some(Arc::clone(&kept));
            Self(Some(kept))
        })
    }

    /// A copy of the entries.
    pub(crate) fn to_map(&self) -> HashMap<String, String> {
        self.0.as_deref().cloned().unwrap_or_default()
    }

    pub(crate) fn contains_key(&self, key: &str) -> bool {
        self.0.as_ref().is_some_and(|map| map.contains_key(key))
    }

    /// Heap the entries' map occupies (its strings aside), counted whole with every chunk
    /// that shares it: an upper bound of a few dozen bytes, where a per-map ledger would
    /// cost more than it corrects.
    pub(crate) fn heap_bytes(&self) -> u64 {
        self.0.as_ref().map_or(0, |_| {
            (size_of::<HashMap<String, String>>() + 2 * size_of::<usize>()) as u64
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(entries: &[(&str, &str)]) -> HashMap<String, String> {
        entries
            .iter()
            .map(|&(k, v)| (k.to_owned(), v.to_owned()))
            .collect()
    }

    fn shared(metadata: &Metadata) -> &Arc<HashMap<String, String>> {
        metadata.0.as_ref().expect("kept entries")
    }

    #[test]
    fn equal_kept_entries_share_one_map_and_others_get_their_own() {
        let keep = |key: &str, _: &str| key != "rerun:id";
        let a = Metadata::kept(&map(&[("rerun:id", "1"), ("sorbet:version", "0.1")]), keep);
        // Another id, the same kept entries: the same map.
        let b = Metadata::kept(&map(&[("rerun:id", "2"), ("sorbet:version", "0.1")]), keep);
        assert!(Arc::ptr_eq(shared(&a), shared(&b)));
        assert_eq!(b.to_map(), map(&[("sorbet:version", "0.1")]));
        // Another value, one entry more or fewer: a map of their own, with their entries.
        let other_value = Metadata::kept(&map(&[("sorbet:version", "0.2")]), keep);
        assert!(!Arc::ptr_eq(shared(&a), shared(&other_value)));
        assert_eq!(other_value.to_map(), map(&[("sorbet:version", "0.2")]));
        let more = Metadata::kept(&map(&[("sorbet:version", "0.2"), ("x", "y")]), keep);
        assert_eq!(more.to_map(), map(&[("sorbet:version", "0.2"), ("x", "y")]));
        let fewer = Metadata::kept(&map(&[("x", "y")]), keep);
        assert_eq!(fewer.to_map(), map(&[("x", "y")]));
        // Nothing kept: nothing allocated, and the last map stays for the next chunk.
        assert_eq!(
            Metadata::kept(&map(&[("rerun:id", "3")]), keep),
            Metadata::default()
        );
        let again = Metadata::kept(&map(&[("x", "y")]), keep);
        assert!(Arc::ptr_eq(shared(&fewer), shared(&again)));
    }
}
