//! [`SegmentCache`]: loaded segments kept between uses, within a byte budget, the least
//! recently used evicted first. A segment in use stays alive while its user holds it
//! (a [`Snapshot`] is shared), so memory is the budget plus the segments being read.

use crate::Snapshot;

/// See the module docs.
#[derive(Debug)]
pub(super) struct SegmentCache {
    budget: u64,
    used: u64,
    /// Each kept segment: its number, its store, its heap bytes, and when last used.
    entries: Vec<Entry>,
    clock: u64,
}

#[derive(Debug)]
struct Entry {
    segment: usize,
    snapshot: Snapshot,
    bytes: u64,
    last_used: u64,
}

impl SegmentCache {
    pub fn new(budget: u64) -> Self {
        Self {
            budget,
            used: 0,
            entries: Vec::new(),
            clock: 0,
        }
    }

    /// The segment's store, if kept (now the most recently used).
    pub fn get(&mut self, segment: usize) -> Option<Snapshot> {
        self.clock += 1;
        let clock = self.clock;
        let entry = self.entries.iter_mut().find(|e| e.segment == segment)?;
        entry.last_used = clock;
        Some(entry.snapshot.clone())
    }

    /// Keeps a loaded segment, evicting the least recently used until it fits; one larger
    /// than the whole budget is not kept.
    pub fn insert(&mut self, segment: usize, snapshot: Snapshot) {
        let bytes = snapshot.stats().heap_bytes;
        if bytes > self.budget || self.entries.iter().any(|e| e.segment == segment) {
            return;
        }
        while self.used + bytes > self.budget {
            let Some(oldest) = self
                .entries
                .iter()
                .enumerate()
                .min_by_key(|(_, e)| e.last_used)
                .map(|(i, _)| i)
            else {
                break;
            };
            let evicted = self.entries.swap_remove(oldest);
            self.used -= evicted.bytes;
        }
        self.clock += 1;
        self.used += bytes;
        self.entries.push(Entry {
            segment,
            snapshot,
            bytes,
            last_used: self.clock,
        });
    }

    /// Bytes kept.
    #[cfg(test)]
    pub fn used(&self) -> u64 {
        self.used
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::{ArrayRef, Float64Array};

    use super::SegmentCache;
    use crate::{ChunkBuilder, ChunkId, ChunkStore, EntityPath, RowId, Snapshot, Timeline};

    fn store_of(rows: i64) -> Snapshot {
        let mut store = ChunkStore::new();
        let mut builder = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("e").unwrap());
        for frame in 0..rows {
            let value = Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
            builder = builder.with_row(
                RowId::new(),
                [(Timeline::sequence("frame"), frame)],
                [("x", value)],
            );
        }
        store.insert(builder.build().unwrap()).unwrap();
        store.snapshot()
    }

    /// The cache never holds more than its budget, evicts the least recently used first,
    /// and keeps nothing larger than the budget.
    #[test]
    fn the_least_recently_used_segment_goes_first_and_the_budget_holds() {
        let one = store_of(100).stats().heap_bytes;
        let mut cache = SegmentCache::new(2 * one + one / 2);
        cache.insert(0, store_of(100));
        cache.insert(1, store_of(100));
        assert!(cache.get(0).is_some(), "0 is now the most recently used");
        cache.insert(2, store_of(100));
        assert!(cache.get(1).is_none(), "1 was the least recently used");
        assert!(cache.get(0).is_some() && cache.get(2).is_some());
        assert!(cache.used() <= 2 * one + one / 2);
        cache.insert(3, store_of(10_000));
        assert!(cache.get(3).is_none(), "larger than the budget: not kept");
        assert!(
            cache.get(0).is_some() && cache.get(2).is_some(),
            "and nothing evicted for it"
        );
    }
}
