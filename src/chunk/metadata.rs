//! [`Metadata`]: the string metadata a chunk keeps only to give it back on transport.

use std::collections::HashMap;
use std::sync::Arc;

/// String metadata kept only for lossless transport: empty for a chunk built through the
/// API, so it costs one pointer until it is not. Shared, never copied: a chunk's slices
/// and rewrites carry their source's metadata (Rerun's SDK writes some into every chunk,
/// and copying that map was a ninth of slicing a small piece off a chunk).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct Metadata(Option<Arc<HashMap<String, String>>>);

impl Metadata {
    pub(crate) fn new(map: HashMap<String, String>) -> Self {
        Self((!map.is_empty()).then(|| Arc::new(map)))
    }

    /// The entries of `map` that `keep` keeps, copied: nothing is allocated when none is
    /// (decoding copies a schema's and each time field's metadata, usually all dropped).
    pub(crate) fn kept(map: &HashMap<String, String>, keep: impl Fn(&str, &str) -> bool) -> Self {
        let kept: HashMap<String, String> = map
            .iter()
            .filter(|(key, value)| keep(key, value))
            .map(|(key, value)| (key.clone(), value.clone()))
            .collect();
        Self::new(kept)
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
