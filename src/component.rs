//! Component names and descriptors. The name alone is the key; the descriptor's other
//! fields are metadata carried along and returned.

use std::fmt;
use std::sync::Arc;

/// The name of a component, e.g. `Points3D:positions`. Cheap to clone.
#[derive(Clone, Eq)]
pub struct ComponentName(Arc<str>);

// Equal names are usually one shared allocation (see `ComponentName::new`): equality and
// order compare the pointers first (`crate::interner::same_name`); the hash is the text's.
impl PartialEq for ComponentName {
    #[inline]
    fn eq(&self, other: &Self) -> bool {
        crate::interner::same_name(&self.0, &other.0)
    }
}

impl std::hash::Hash for ComponentName {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.0.hash(state);
    }
}

impl PartialOrd for ComponentName {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for ComponentName {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        crate::interner::cmp_names(&self.0, &other.0)
    }
}

impl ComponentName {
    /// The component that marks a row as a Clear; its boolean says whether it is recursive.
    pub const CLEAR_IS_RECURSIVE: &'static str = "Clear:is_recursive";

    /// A component name. Equal names share one allocation, process-wide (up to a cap), so
    /// that chunks do not each carry a copy.
    pub fn new(name: impl Into<Arc<str>>) -> Self {
        Self(crate::interner::share_name(name.into()))
    }

    /// The name as text.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// Is this the Clear component?
    pub fn is_clear(&self) -> bool {
        &*self.0 == Self::CLEAR_IS_RECURSIVE
    }
}

impl fmt::Display for ComponentName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl fmt::Debug for ComponentName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", &*self.0)
    }
}

impl From<&str> for ComponentName {
    fn from(name: &str) -> Self {
        Self::new(name)
    }
}

impl std::borrow::Borrow<str> for ComponentName {
    fn borrow(&self) -> &str {
        &self.0
    }
}

/// A component name plus the optional metadata Rerun attaches to it.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub struct ComponentDescriptor {
    /// The key: the component's name.
    pub name: ComponentName,
    /// The archetype it belongs to (`rerun:archetype`), e.g. `rerun.archetypes.Points3D`.
    pub archetype: Option<Arc<str>>,
    /// Its semantic type (`rerun:component_type`), e.g. `rerun.components.Position3D`.
    pub component_type: Option<Arc<str>>,
}

impl ComponentDescriptor {
    /// A descriptor with only a name.
    pub fn new(name: impl Into<ComponentName>) -> Self {
        Self {
            name: name.into(),
            archetype: None,
            component_type: None,
        }
    }

    /// The same descriptor, of the archetype `archetype`.
    #[must_use]
    pub fn with_archetype(mut self, archetype: impl Into<Arc<str>>) -> Self {
        self.archetype = Some(archetype.into());
        self
    }

    /// The same descriptor, of the semantic type `component_type`.
    #[must_use]
    pub fn with_component_type(mut self, component_type: impl Into<Arc<str>>) -> Self {
        self.component_type = Some(component_type.into());
        self
    }
}

impl From<&str> for ComponentDescriptor {
    fn from(name: &str) -> Self {
        Self::new(name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Names compare, order and hash as their text does, whether or not they share one
    /// allocation (a name past the shared set's cap, or built around its own `Arc`).
    #[test]
    fn names_compare_as_their_text() {
        let shared = ComponentName::new("b");
        let own = ComponentName(Arc::from("b"));
        assert!(!Arc::ptr_eq(&shared.0, &own.0));
        assert_eq!(shared, own);
        assert_eq!(shared.cmp(&own), std::cmp::Ordering::Equal);
        let hash = |n: &ComponentName| ahash::RandomState::with_seeds(1, 2, 3, 4).hash_one(n);
        assert_eq!(hash(&shared), hash(&own));
        let mut names: Vec<ComponentName> = ["c", "a", "b", "ab"]
            .into_iter()
            .map(ComponentName::new)
            .chain([own])
            .collect();
        names.sort();
        let texts: Vec<&str> = names.iter().map(ComponentName::as_str).collect();
        assert_eq!(texts, ["a", "ab", "b", "b", "c"]);
        assert_ne!(ComponentName::new("a"), ComponentName::new("ab"));
    }
}
