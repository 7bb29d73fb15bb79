//! Readers that never wait: [`Snapshot`], a store's view frozen at one moment, and
//! [`SharedStore`], a handle that one writer at a time mutates and that publishes a new
//! snapshot after every write.
//!
//! A snapshot is the store's [`StoreView`] cloned, which is O(1): the view is made of
//! persistent pieces (see `store/view.rs`) that the writer copies only where it changes
//! them while a snapshot still holds them. Publication is one pointer swap: the shared
//! store keeps its latest snapshot in an [`ArcSwap`] (the `arc-swap` crate), which readers
//! load without a lock and without waiting for a writer, whatever it is doing. Writers
//! take a mutex among themselves only. A version whose last snapshot a reader drops goes
//! back to the writer through a `std::sync::mpsc` channel, to be freed there (see
//! [`Snapshot`]'s `Drop`). There is no other synchronization: `Arc` reference counts,
//! `arc-swap` and the standard channel, each a well-kept primitive, so no model checker
//! (loom) is run on this protocol; `tests/core/snapshot.rs` stress-tests what it promises.

use std::any::Any;
use std::sync::mpsc::{Receiver, Sender};
use std::sync::{Arc, LazyLock};

use arc_swap::ArcSwap;
use parking_lot::Mutex;

use crate::store::StoreView;
use crate::{Chunk, ChunkStore, InsertError, StoreEvent};

/// What a snapshot holds: the view, the version it was taken at, what readers derived from
/// it for later readers, and, for a shared store's snapshot, where its last holder hands
/// it back to the writer.
#[derive(Debug)]
struct Frozen {
    view: StoreView,
    version: u64,
    derived: Derived,
    graveyard: Option<Sender<Arc<Frozen>>>,
}

impl Frozen {
    fn new(view: StoreView, version: u64, graveyard: Option<Sender<Arc<Frozen>>>) -> Arc<Self> {
        Arc::new(Self {
            view,
            version,
            derived: Derived::default(),
            graveyard,
        })
    }
}

/// Values the layers above work out from a frozen view and keep for its later readers
/// (a dataframe view's rows), one per type, made on first use. Typed by the layer that
/// owns each, so that this one knows none of them; a snapshot never changes, so nothing
/// here goes stale.
#[derive(Default)]
struct Derived(Mutex<Vec<Arc<dyn Any + Send + Sync>>>);

impl std::fmt::Debug for Derived {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Derived")
            .field("values", &self.0.lock().len())
            .finish()
    }
}

/// What a snapshot handed back to the writer is replaced with while it leaves.
static RETIRED: LazyLock<Arc<Frozen>> =
    LazyLock::new(|| Frozen::new(StoreView::default(), 0, None));

/// A read-only view of a store as of one moment: it answers every query (latest-at,
/// range, dataframes, figures, listings; every method of [`StoreView`], which it
/// dereferences to) exactly as the store did when it was taken, for as long as it is held,
/// whatever the store does meanwhile — inserts, compaction, garbage collection, drops.
///
/// Taking one is O(1) ([`ChunkStore::snapshot`], [`SharedStore::snapshot`]); cloning one
/// is one reference count. A snapshot keeps alive only what it can still answer from: the
/// chunks and index pieces the store has since dropped or replaced, and nothing else. It
/// is `Send + Sync + 'static`, so it can move to another thread or live in a cache.
///
/// ```
/// use chunkstore::{ChunkStore, LatestAtQuery, TimeInt};
/// # use chunkstore::{ChunkBuilder, ChunkId, EntityPath, RowId, Timeline};
/// # use arrow_array::{ArrayRef, Float64Array};
/// # use std::sync::Arc;
/// # let chunk = |frame: i64, value: f64| {
/// #     ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/robot").unwrap())
/// #         .with_row(RowId::new(), [(Timeline::sequence("frame"), frame)],
/// #             [("scalar", Arc::new(Float64Array::from(vec![value])) as ArrayRef)])
/// #         .build().unwrap()
/// # };
/// let mut store = ChunkStore::new();
/// store.insert(chunk(1, 1.0))?;
/// let before = store.snapshot();
/// store.insert(chunk(2, 2.0))?;
///
/// let query = LatestAtQuery::new("frame", TimeInt::new(10).unwrap());
/// let entity = EntityPath::parse("/robot")?;
/// assert_eq!(before.latest_at(&query, &entity, "scalar").unwrap().time(), TimeInt::new(1));
/// assert_eq!(store.latest_at(&query, &entity, "scalar").unwrap().time(), TimeInt::new(2));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
///
/// Nothing can change a snapshot: it has no mutating method, not even through `mut`.
///
/// ```compile_fail,E0599
/// let mut snapshot = chunkstore::ChunkStore::new().snapshot();
/// snapshot.gc(&chunkstore::GcOptions::everything());
/// ```
///
/// ```compile_fail,E0599
/// # use chunkstore::{ChunkBuilder, ChunkId, EntityPath};
/// let mut snapshot = chunkstore::ChunkStore::new().snapshot();
/// let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/a").unwrap()).build().unwrap();
/// snapshot.insert(chunk);
/// ```
#[derive(Clone, Debug)]
pub struct Snapshot(Arc<Frozen>);

impl Snapshot {
    pub(crate) fn new(view: StoreView, version: u64) -> Self {
        Self(Frozen::new(view, version, None))
    }

    /// The number of public mutations (inserts, garbage collections, compactions, drops,
    /// each counted once however much it changed) the store had made when the snapshot
    /// was taken. Two snapshots of one store with the same version see the same data.
    pub fn version(&self) -> u64 {
        self.0.version
    }

    /// The frozen view (also reachable by dereferencing the snapshot).
    pub fn view(&self) -> &StoreView {
        &self.0.view
    }

    /// The value of type `T` this snapshot keeps for its readers (see `Derived`), made
    /// empty on first use. Every clone of the snapshot shares it, as do all readers of a
    /// shared store's version.
    pub(crate) fn derived<T: Any + Default + Send + Sync>(&self) -> Arc<T> {
        let mut values = self.0.derived.0.lock();
        for value in values.iter() {
            if let Ok(value) = Arc::clone(value).downcast::<T>() {
                return value;
            }
        }
        let value = Arc::new(T::default());
        values.push(Arc::clone(&value) as Arc<dyn Any + Send + Sync>);
        value
    }
}

impl ChunkStore {
    /// Freezes the store's current view: a read-only [`Snapshot`] that
    /// answers every query as the store does now, whatever the store does later. O(1):
    /// it shares every index with the store, which copies what it changes while the
    /// snapshot holds it.
    ///
    /// ```
    /// use chunkstore::ChunkStore;
    ///
    /// let store = ChunkStore::new();
    /// let snapshot = store.snapshot();
    /// assert_eq!(snapshot.stats(), store.stats());
    /// ```
    pub fn snapshot(&self) -> Snapshot {
        Snapshot::new(self.view.clone(), self.num_mutations)
    }
}

/// The last holder of a version the shared store has moved past hands it back to the
/// writer, which frees it at its next write (or at [`SharedStore::reclaim`]): freeing is
/// the writer's work (the copies its writes made, the chunks a collection dropped), and a
/// reader's thread freeing memory the writer's thread allocated would also contend with the
/// writer inside the allocator. Measured with the `concurrent` workload: reader p99 under
/// ingest 1.3–1.9× its idle p99 this way, 3–18× when readers freed what they dropped last
/// (`docs/performance-log.md`). (Two holders dropping at once may both see another holder;
/// then the last frees it where it is, as any `Arc` would.)
impl Drop for Snapshot {
    fn drop(&mut self) {
        if Arc::strong_count(&self.0) == 1
            && let Some(graveyard) = self.0.graveyard.clone()
        {
            let frozen = std::mem::replace(&mut self.0, Arc::clone(&RETIRED));
            // A store already gone has no writer to hand it to: it is freed here.
            drop(graveyard.send(frozen));
        }
    }
}

impl std::ops::Deref for Snapshot {
    type Target = StoreView;

    fn deref(&self) -> &StoreView {
        &self.0.view
    }
}

/// A store shared between threads: one writer at a time mutates it, and every reader takes
/// [snapshots](SharedStore::snapshot) that never wait for the writer.
///
/// Every write (one call of [`SharedStore::write`] or of the methods built on it, however
/// many mutations it makes) ends by publishing a new snapshot, atomically: a reader sees
/// all of a write or none of it. Writers are serialized by a mutex among themselves;
/// readers take no lock at all. The store's [subscribers](ChunkStore::subscribe) receive
/// the events of each mutation in order, on the writer's thread, before the write
/// publishes its snapshot.
///
/// Cloning the handle is cheap; every clone refers to the same store.
///
/// ```
/// use chunkstore::{ChunkStore, LatestAtQuery, SharedStore, TimeInt};
/// # use chunkstore::{ChunkBuilder, ChunkId, EntityPath, RowId, Timeline};
/// # use arrow_array::{ArrayRef, Float64Array};
/// # use std::sync::Arc;
/// # let chunk = |frame: i64| {
/// #     ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/robot").unwrap())
/// #         .with_row(RowId::new(), [(Timeline::sequence("frame"), frame)],
/// #             [("scalar", Arc::new(Float64Array::from(vec![frame as f64])) as ArrayRef)])
/// #         .build().unwrap()
/// # };
/// let shared = SharedStore::new(ChunkStore::new());
///
/// // A writer thread streams rows in...
/// let writer = {
///     let shared = shared.clone();
///     std::thread::spawn(move || {
///         for frame in 0..100 {
///             shared.insert(chunk(frame)).unwrap();
///         }
///     })
/// };
/// // ...while a reader queries whatever was published last, never waiting.
/// let entity = EntityPath::parse("/robot")?;
/// let query = LatestAtQuery::new("frame", TimeInt::MAX);
/// loop {
///     let snapshot = shared.snapshot();
///     if let Some(cell) = snapshot.latest_at(&query, &entity, "scalar") {
///         assert!(cell.time() <= TimeInt::new(99));
///     }
///     if snapshot.stats().num_rows() == 100 {
///         break;
///     }
///     std::thread::yield_now();
/// }
/// writer.join().unwrap();
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug)]
pub struct SharedStore {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    writer: Mutex<Writer>,
    published: ArcSwap<Frozen>,
}

/// The writer's side: the store, and the versions its readers handed back to be freed.
#[derive(Debug)]
struct Writer {
    store: ChunkStore,
    retired: Receiver<Arc<Frozen>>,
    graveyard: Sender<Arc<Frozen>>,
}

impl Writer {
    /// Frees the versions readers handed back.
    fn free_retired(&self) {
        while let Ok(retired) = self.retired.try_recv() {
            drop(retired);
        }
    }

    /// Frees what readers handed back, then freezes the store's view as it is now.
    fn publish(&mut self) -> Arc<Frozen> {
        self.free_retired();
        Frozen::new(
            self.store.view.clone(),
            self.store.num_mutations,
            Some(self.graveyard.clone()),
        )
    }
}

impl SharedStore {
    /// Shares `store`, publishing its current view as the first snapshot.
    pub fn new(store: ChunkStore) -> Self {
        let (graveyard, retired) = std::sync::mpsc::channel();
        let mut writer = Writer {
            store,
            retired,
            graveyard,
        };
        let published = ArcSwap::new(writer.publish());
        Self {
            inner: Arc::new(Inner {
                writer: Mutex::new(writer),
                published,
            }),
        }
    }

    /// The latest published snapshot. Never blocks and never waits for a writer: one
    /// atomic load and one reference count.
    pub fn snapshot(&self) -> Snapshot {
        Snapshot(self.inner.published.load_full())
    }

    /// Runs `write` on the store, alone among writers, then publishes the store's new view
    /// (whatever `write` did, even nothing). Readers see either none of what `write` did or
    /// all of it. If `write` panics, nothing is published; the store keeps whatever the
    /// panic left, which the next write publishes.
    ///
    /// Batching many mutations in one `write` publishes once for all of them, which is
    /// cheaper (each publication makes the next write copy what it touches).
    pub fn write<R>(&self, write: impl FnOnce(&mut ChunkStore) -> R) -> R {
        let mut writer = self.inner.writer.lock();
        let result = write(&mut writer.store);
        let published = writer.publish();
        self.inner.published.store(published);
        result
    }

    /// [`ChunkStore::insert`], then publishes.
    ///
    /// # Errors
    /// As [`ChunkStore::insert`]; the store is then unchanged (and a snapshot is published
    /// all the same, equal to the last).
    pub fn insert(&self, chunk: impl Into<Arc<Chunk>>) -> Result<Vec<StoreEvent>, InsertError> {
        let chunk = chunk.into();
        self.write(|store| store.insert(chunk))
    }

    /// Inserts every chunk in order and publishes once, after the last: readers see the
    /// whole batch at once. Returns every insert's events.
    ///
    /// # Errors
    /// The first chunk [`ChunkStore::insert`] refuses (the error names it); the chunks
    /// before it stay in and are published, the ones after it are not inserted.
    pub fn insert_batch<I>(&self, chunks: I) -> Result<Vec<StoreEvent>, InsertError>
    where
        I: IntoIterator,
        I::Item: Into<Arc<Chunk>>,
    {
        self.write(|store| {
            let mut events = Vec::new();
            for chunk in chunks {
                events.extend(store.insert(chunk)?);
            }
            Ok(events)
        })
    }

    /// Frees now what readers handed back to the writer: the versions the store has moved
    /// past whose last snapshot a reader dropped (see [`Snapshot`]'s `Drop`). Every write
    /// does this first anyway; a program whose writer has gone quiet calls it to return
    /// that memory (the chunks a collection dropped, say) without writing. Waits for a
    /// write in progress, like a write.
    pub fn reclaim(&self) {
        self.inner.writer.lock().free_retired();
    }

    /// A copy of the store as it is now (O(store): its writer's structures are copied;
    /// the chunks are shared), taken between writes.
    pub fn to_store(&self) -> ChunkStore {
        self.inner.writer.lock().store.clone()
    }

    /// The store, if this is the last handle to it; the handle back otherwise.
    ///
    /// # Errors
    /// Another clone of the handle still refers to the store.
    pub fn try_into_store(self) -> Result<ChunkStore, Self> {
        Arc::try_unwrap(self.inner)
            .map(|inner| inner.writer.into_inner().store)
            .map_err(|inner| Self { inner })
    }
}

/// Checked at compile time: the store, its view, snapshots and the shared handle can all
/// move to and be shared between threads.
const _: () = {
    const fn send_sync<T: Send + Sync + 'static>() {}
    send_sync::<ChunkStore>();
    send_sync::<StoreView>();
    send_sync::<Snapshot>();
    send_sync::<SharedStore>();
};
