//! [`Metadata`]: the string metadata a chunk keeps only to give it back on transport.

use std::collections::HashMap;

/// String metadata kept only for lossless transport: almost always empty, so it costs one
/// pointer until it is not.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
#[expect(
    clippy::box_collection,
    reason = "one pointer instead of a 48-byte empty map in every chunk and time column"
)]
pub(crate) struct Metadata(Option<Box<HashMap<String, String>>>);

impl Metadata {
    pub(crate) fn new(map: HashMap<String, String>) -> Self {
        Self((!map.is_empty()).then(|| Box::new(map)))
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

    /// Heap the entries' map occupies (its strings aside).
    pub(crate) fn heap_bytes(&self) -> u64 {
        self.0
            .as_ref()
            .map_or(0, |_| size_of::<HashMap<String, String>>() as u64)
    }
}
