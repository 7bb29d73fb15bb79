//! Component names and descriptors. The name alone is the key; the descriptor's other
//! fields are metadata carried along and returned.

use std::fmt;
use std::sync::Arc;

/// The name of a component, e.g. `Points3D:positions`. Cheap to clone.
#[derive(Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ComponentName(Arc<str>);

impl ComponentName {
    /// The component that marks a row as a Clear; its boolean says whether it is recursive.
    pub const CLEAR_IS_RECURSIVE: &'static str = "Clear:is_recursive";

    /// A component name. Equal names share one allocation, process-wide (up to a cap), so
    /// that chunks do not each carry a copy.
    pub fn new(name: impl Into<Arc<str>>) -> Self {
        Self(crate::shared::share_name(name.into()))
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
}

impl From<&str> for ComponentDescriptor {
    fn from(name: &str) -> Self {
        Self::new(name)
    }
}
