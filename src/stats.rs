//! Statistics and memory accounting: totals kept incrementally by every mutation (O(1) to
//! read), and the ledger that counts an Arrow buffer shared by several chunks once.
//!
//! A chunk's cost to the store is its own allocations ([`Chunk::heap_size_bytes`] minus
//! its buffers), an estimate of the index entries pointing at it, and its Arrow buffers.
//! Chunks that alone hold their buffers (the common case: built by an SDK or by
//! compaction) are counted directly; chunks sharing buffers (decoded from one IPC
//! message, or slices of one split chunk) go through a [`BufferLedger`] that counts each
//! allocation once, while any chunk references it.

use arrow_buffer::Buffer;

use crate::Chunk;
use crate::chunk::memory::{buffer_address, buffer_bytes};
use crate::index::SMALL_INDEX_BYTES_PER_ENTRY;

// The index estimates below were measured with the counting allocator of
// `tests/memory/main.rs` (20,000 single-row chunks inserted in order, with one and with six
// (timeline, component) entries each) when the global orders were B-trees, whose nodes
// filled in order are about half full. Kept as deques (`crate::ordered`) they cost less,
// so in-order stores are slightly overestimated; the memory test holds every shape it
// measures within 10% of the allocator.

/// Adds what a temporal index grew by (negative: shrank) to the store's and the entity's
/// heap figures.
pub(crate) fn add_index_bytes(stats: &mut StoreStats, entity: &mut EntityStats, delta: i64) {
    for total in [
        &mut stats.heap_bytes,
        &mut stats.temporal_heap_bytes,
        &mut entity.heap_bytes,
    ] {
        *total = total.saturating_add_signed(delta);
    }
}

/// Estimated heap of one entity's own bookkeeping, whatever its chunks: its slot in the
/// entity map, its path, and its small maps (element types, chunk set, timelines,
/// components, compaction groups). Measured with the counting allocator of
/// `tests/memory/main.rs` on its many-entity shapes (about 920 bytes an entity, since the small
/// maps keep their first entry inline; 1,800 while the component types were B-trees);
/// counted in `heap_bytes` and the entity's figure, in neither kind's.
pub(crate) const ENTITY_BYTES: u64 = 920;

/// Estimated heap of the store's bookkeeping per chunk: its slot in the chunk map, in the
/// entity's chunk set and in the garbage collector's row-id order.
const INDEX_BYTES_PER_CHUNK: u64 = 80;
/// Estimated heap per timeline of a chunk: its slots in the per-timeline time orders.
const INDEX_BYTES_PER_TIMELINE: u64 = 100;
/// Estimated heap of one component entry of a static chunk (its static winner slot and
/// chunk record; 490 while an entity's static chunks were a hash map).
const STATIC_BYTES_PER_ENTRY: u64 = 340;

/// Totals, kept up to date by every mutation, O(1) to read.
///
/// Heap bytes count a shared Arrow buffer once: in `heap_bytes` once for the whole store,
/// in `static_heap_bytes` and `temporal_heap_bytes` once per kind, so the two kinds can
/// add up to more than `heap_bytes` when static and temporal chunks share a buffer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct StoreStats {
    /// Static chunks held.
    pub num_static_chunks: u64,
    /// Rows in static chunks.
    pub num_static_rows: u64,
    /// Heap bytes of static chunks.
    pub static_heap_bytes: u64,
    /// Temporal chunks held.
    pub num_temporal_chunks: u64,
    /// Rows in temporal chunks.
    pub num_temporal_rows: u64,
    /// Heap bytes of temporal chunks.
    pub temporal_heap_bytes: u64,
    /// Heap bytes of the whole store: chunks, their buffers and the indices over them.
    pub heap_bytes: u64,
    /// Since the store was created: rows the caller inserted.
    pub rows_inserted: u64,
    /// Since the store was created: payload bytes ([`Chunk::payload_bytes`]) the caller
    /// inserted.
    pub payload_bytes_inserted: u64,
    /// Since the store was created: rows compaction copied (a row merged three times
    /// counts three times; a split that only slices copies nothing).
    pub rows_copied_by_compaction: u64,
    /// Since the store was created: payload bytes compaction wrote.
    pub payload_bytes_copied_by_compaction: u64,
}

impl StoreStats {
    /// Chunks held, static and temporal.
    pub fn num_chunks(&self) -> u64 {
        self.num_static_chunks + self.num_temporal_chunks
    }

    /// Rows held, static and temporal.
    pub fn num_rows(&self) -> u64 {
        self.num_static_rows + self.num_temporal_rows
    }

    /// The figures a store's contents determine (not the running totals since creation),
    /// for comparing a store's kept stats with a recount.
    pub(crate) fn contents(&self) -> Self {
        Self {
            rows_inserted: 0,
            payload_bytes_inserted: 0,
            rows_copied_by_compaction: 0,
            payload_bytes_copied_by_compaction: 0,
            ..*self
        }
    }
}

/// The figures of one entity, kept like [`StoreStats`]. A buffer shared by chunks of
/// several entities counts once in each.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct EntityStats {
    /// Static chunks held.
    pub num_static_chunks: u64,
    /// Rows in static chunks.
    pub num_static_rows: u64,
    /// Temporal chunks held.
    pub num_temporal_chunks: u64,
    /// Rows in temporal chunks.
    pub num_temporal_rows: u64,
    /// Heap bytes of the entity's chunks, their buffers and index entries.
    pub heap_bytes: u64,
}

/// Reference counts of the Arrow allocations held by chunks that share buffers, so each
/// allocation is counted once.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct BufferLedger {
    /// Allocation address → (references by chunks, bytes).
    references: ahash::HashMap<usize, (u32, u64)>,
}

impl BufferLedger {
    /// Records one more chunk referencing `buffer`; returns the bytes that became
    /// counted (all of them for the first reference, none after).
    pub fn acquire(&mut self, buffer: &Buffer) -> u64 {
        let entry = self
            .references
            .entry(buffer_address(buffer))
            .or_insert_with(|| (0, buffer_bytes(buffer)));
        entry.0 += 1;
        if entry.0 == 1 { entry.1 } else { 0 }
    }

    /// Records one chunk fewer referencing `buffer`; returns the bytes that stopped being
    /// counted.
    pub fn release(&mut self, buffer: &Buffer) -> u64 {
        let address = buffer_address(buffer);
        let Some(entry) = self.references.get_mut(&address) else {
            return 0;
        };
        entry.0 -= 1;
        if entry.0 > 0 {
            return 0;
        }
        let bytes = entry.1;
        self.references.remove(&address);
        bytes
    }

    /// How many chunks reference the allocation at `address`.
    pub fn references(&self, address: usize) -> u32 {
        self.references.get(&address).map_or(0, |e| e.0)
    }
}

/// The store's share of memory accounting: the ledgers for the whole store and per kind.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct StoreLedgers {
    pub all: BufferLedger,
    pub static_: BufferLedger,
    pub temporal: BufferLedger,
}

/// The bytes a chunk costs besides its Arrow buffers.
pub(crate) fn fixed_bytes(chunk: &Chunk) -> u64 {
    // A temporal chunk's entries are counted at what a small index costs; a large index
    // reports what its B-trees add on top (`TemporalComponentIndex::extra_heap_bytes`).
    let entries = if chunk.is_static() {
        STATIC_BYTES_PER_ENTRY * chunk.components().len() as u64
    } else {
        SMALL_INDEX_BYTES_PER_ENTRY * (chunk.time_columns().len() * chunk.components().len()) as u64
    };
    chunk.own_heap_bytes()
        + INDEX_BYTES_PER_CHUNK
        + INDEX_BYTES_PER_TIMELINE * chunk.time_columns().len() as u64
        + entries
}

/// Adds (`acquire`) or removes a chunk to or from the figures of the store and of its
/// entity. `ledgered` says whether the chunk's buffers go through the ledgers (see the
/// module docs); it must be the same on removal as it was on addition.
pub(crate) fn account(
    chunk: &Chunk,
    ledgered: bool,
    acquire: bool,
    stats: &mut StoreStats,
    ledgers: &mut StoreLedgers,
    entity_stats: &mut EntityStats,
    entity_ledger: &mut BufferLedger,
) {
    let mut change = FigureChange::default();
    change.count(chunk, ledgered, acquire, ledgers, entity_ledger);
    change.apply(acquire, stats, entity_stats);
}

/// What chunks of one entity add to or take from the figures, summed
/// ([`FigureChange::count`]) and then applied once ([`FigureChange::apply`]): a merge
/// takes a whole fan out of the figures with one update of each, not one per chunk.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct FigureChange {
    heap_bytes: u64,
    entity_heap_bytes: u64,
    static_heap_bytes: u64,
    temporal_heap_bytes: u64,
    num_static_chunks: u64,
    num_static_rows: u64,
    num_temporal_chunks: u64,
    num_temporal_rows: u64,
}

impl FigureChange {
    /// Counts `chunk` (of the entity whose ledger is `entity_ledger`), acquiring or
    /// releasing its buffers in the ledgers now if it is `ledgered`.
    #[inline]
    pub fn count(
        &mut self,
        chunk: &Chunk,
        ledgered: bool,
        acquire: bool,
        ledgers: &mut StoreLedgers,
        entity_ledger: &mut BufferLedger,
    ) {
        let fixed = fixed_bytes(chunk);
        let (mut all, mut kind, mut entity) = (fixed, fixed, fixed);
        if ledgered {
            let kind_ledger = if chunk.is_static() {
                &mut ledgers.static_
            } else {
                &mut ledgers.temporal
            };
            for buffer in chunk.buffers() {
                if acquire {
                    all += ledgers.all.acquire(buffer);
                    kind += kind_ledger.acquire(buffer);
                    entity += entity_ledger.acquire(buffer);
                } else {
                    all += ledgers.all.release(buffer);
                    kind += kind_ledger.release(buffer);
                    entity += entity_ledger.release(buffer);
                }
            }
        } else {
            let bytes = chunk.buffer_bytes();
            all += bytes;
            kind += bytes;
            entity += bytes;
        }
        let rows = chunk.num_rows() as u64;
        self.heap_bytes += all;
        self.entity_heap_bytes += entity;
        if chunk.is_static() {
            self.static_heap_bytes += kind;
            self.num_static_chunks += 1;
            self.num_static_rows += rows;
        } else {
            self.temporal_heap_bytes += kind;
            self.num_temporal_chunks += 1;
            self.num_temporal_rows += rows;
        }
    }

    /// Adds (`acquire`) or removes what was counted to or from the figures of the store
    /// and of the entity.
    #[inline]
    pub fn apply(self, acquire: bool, stats: &mut StoreStats, entity_stats: &mut EntityStats) {
        let apply = |total: &mut u64, amount: u64| {
            *total = if acquire {
                *total + amount
            } else {
                total.saturating_sub(amount)
            };
        };
        apply(&mut stats.heap_bytes, self.heap_bytes);
        apply(&mut entity_stats.heap_bytes, self.entity_heap_bytes);
        if self.num_static_chunks > 0 {
            apply(&mut stats.num_static_chunks, self.num_static_chunks);
            apply(&mut stats.num_static_rows, self.num_static_rows);
            apply(&mut stats.static_heap_bytes, self.static_heap_bytes);
            apply(&mut entity_stats.num_static_chunks, self.num_static_chunks);
            apply(&mut entity_stats.num_static_rows, self.num_static_rows);
        }
        if self.num_temporal_chunks > 0 {
            apply(&mut stats.num_temporal_chunks, self.num_temporal_chunks);
            apply(&mut stats.num_temporal_rows, self.num_temporal_rows);
            apply(&mut stats.temporal_heap_bytes, self.temporal_heap_bytes);
            apply(
                &mut entity_stats.num_temporal_chunks,
                self.num_temporal_chunks,
            );
            apply(&mut entity_stats.num_temporal_rows, self.num_temporal_rows);
        }
    }
}
