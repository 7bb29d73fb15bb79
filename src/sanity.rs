//! The typed sanity contract: every structure's `sanity_check()` returns a [`SanityError`]
//! naming the structure and the invariant that broke. An error is always a bug in this
//! crate, never bad input: constructors and insertion refuse bad input with their own
//! errors before any structure holds it.

use std::fmt;

/// The structure whose invariant broke.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Structure {
    /// A [`crate::Chunk`]'s own fields.
    Chunk,
    /// A chunk's [`crate::TimeColumn`].
    TimeColumn,
    /// A chunk's [`crate::ComponentColumn`].
    ComponentColumn,
    /// The memory figures a chunk keeps (heap, payload, its distinct buffers).
    ChunkMemory,
    /// A [`crate::StoreConfig`].
    Config,
    /// The [`crate::ChunkStore`]'s chunk map, its store-wide orders and its timelines.
    Store,
    /// The store's figures ([`crate::StoreStats`], [`crate::EntityStats`]), recounted.
    Stats,
    /// The store's index of one entity.
    Entity,
    /// The chunks compaction on insert keeps waiting, per entity.
    PendingGroups,
    /// The marks on-demand compaction leaves on the chunks it wrote.
    RewriteMarks,
    /// A per-(entity, timeline, component) temporal index.
    TemporalIndex,
    /// The index of Clears.
    ClearIndex,
    /// An ordered set (a B-tree of the store-wide orders).
    OrderedSet,
    /// A small map (linear while small, hashed beyond).
    SmallMap,
    /// A process-wide set of shared names or fields.
    SharedSet,
    /// The dataframe view rows a snapshot keeps between queries.
    KeptRows,
}

impl fmt::Display for Structure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = match self {
            Self::Chunk => "chunk",
            Self::TimeColumn => "time column",
            Self::ComponentColumn => "component column",
            Self::ChunkMemory => "chunk memory figures",
            Self::Config => "store configuration",
            Self::Store => "store",
            Self::Stats => "store figures",
            Self::Entity => "entity index",
            Self::PendingGroups => "compaction's waiting chunks",
            Self::RewriteMarks => "compaction's rewrite marks",
            Self::TemporalIndex => "temporal index",
            Self::ClearIndex => "clear index",
            Self::OrderedSet => "ordered set",
            Self::SmallMap => "small map",
            Self::SharedSet => "shared set",
            Self::KeptRows => "kept dataframe rows",
        };
        f.write_str(name)
    }
}

/// A broken invariant: a bug in this crate.
///
/// ```
/// use chunkstore::{ChunkStore, SanityError};
/// let store = ChunkStore::new();
/// let checked: Result<(), SanityError> = store.sanity_check();
/// assert!(checked.is_ok());
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct SanityError {
    /// The structure.
    pub structure: Structure,
    /// The invariant, stated as what should hold.
    pub invariant: &'static str,
    /// Where: the entity, chunk, component or figures concerned (may be empty).
    pub detail: String,
}

impl SanityError {
    /// `invariant` of `structure` is broken.
    pub(crate) fn new(structure: Structure, invariant: &'static str) -> Self {
        Self {
            structure,
            invariant,
            detail: String::new(),
        }
    }

    /// The same error, saying where.
    #[must_use]
    pub(crate) fn at(mut self, detail: impl fmt::Display) -> Self {
        self.detail = detail.to_string();
        self
    }
}

/// `Err` of `invariant` of `structure` unless `holds`.
pub(crate) fn ensure(
    holds: bool,
    structure: Structure,
    invariant: &'static str,
) -> Result<(), SanityError> {
    if holds {
        Ok(())
    } else {
        Err(SanityError::new(structure, invariant))
    }
}

impl fmt::Display for SanityError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} invariant broken: {}", self.structure, self.invariant)?;
        if !self.detail.is_empty() {
            write!(f, " ({})", self.detail)?;
        }
        Ok(())
    }
}

impl std::error::Error for SanityError {}
