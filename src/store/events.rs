//! What a mutation reports: [`StoreEvent`]s, and the subscribers that see them.

use std::fmt;
use std::sync::Arc;

use crate::Chunk;

/// Why a chunk left the store.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum DeletionReason {
    /// Garbage collection removed it.
    Gc,
    /// Compaction merged it into another chunk.
    Compaction,
    /// Newer static data shadows all of it, so no query can see it any more.
    Overwrite,
    /// The caller dropped it (a time range or an entity).
    Drop,
}

/// One change to the set of chunks a store holds. Replaying every event a store returned,
/// in order, on an empty set yields exactly the store's chunks.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub enum StoreEvent {
    /// The chunk entered the store.
    Addition(Arc<Chunk>),
    /// The chunk left the store.
    Deletion {
        /// The chunk.
        chunk: Arc<Chunk>,
        /// Why.
        reason: DeletionReason,
    },
}

impl StoreEvent {
    /// The chunk added or removed.
    pub fn chunk(&self) -> &Arc<Chunk> {
        match self {
            Self::Addition(chunk) | Self::Deletion { chunk, .. } => chunk,
        }
    }
}

/// A callback that sees every batch of events a store's mutations return.
pub(super) type EventSubscriber = Arc<dyn Fn(&[StoreEvent]) + Send + Sync>;

/// The store's subscribers. A clone of a store starts without any: a subscriber watches
/// the store it subscribed to.
#[derive(Default)]
pub(super) struct Subscribers(pub(super) Vec<EventSubscriber>);

impl Clone for Subscribers {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl fmt::Debug for Subscribers {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} subscribers", self.0.len())
    }
}
