//! Explicit removal (SEMANTICS.md section 7): dropping a time range of a timeline, or an
//! entity (and with it, optionally, its descendants). Unlike garbage collection, drops
//! remove rows, not only whole chunks: a chunk partly in a dropped range is replaced by a
//! chunk of its other rows.

use std::sync::Arc;

use crate::store::DeletionReason;
use crate::{Chunk, ChunkId, ChunkStore, EntityPath, StoreEvent, TimeColumn, TimeRange};

impl ChunkStore {
    /// Removes every row whose time on `timeline` is in `range`, from all its timelines;
    /// static data is untouched. A chunk partly in the range is replaced by a
    /// chunk of its other rows (a deletion, then an addition). Returns the events.
    ///
    /// Cost: the chunks of the timeline that end at or after `min`, times `log n`, plus
    /// the rows rewritten.
    pub fn drop_time_range(&mut self, timeline: &str, range: TimeRange) -> Vec<StoreEvent> {
        let mut events = Vec::new();
        if range.is_empty() {
            return events;
        }
        let (min, max) = (range.min(), range.max());
        let ordered = self
            .temporal_per_timeline
            .get(timeline)
            .into_iter()
            .flat_map(|chunks| chunks.by_max_time.iter_from(&(min, ChunkId::ZERO)))
            .map(|&(_, id)| id);
        let outside = self.chunks_outside_global_orders();
        let touched: Vec<ChunkId> = ordered
            .chain(outside.iter().map(|c| c.id()))
            .filter(|id| {
                self.chunks
                    .get(id)
                    .and_then(|s| s.chunk.time_column(timeline))
                    .is_some_and(|c| {
                        let bounds = c.time_range();
                        let (lo, hi) = (bounds.min(), bounds.max());
                        range.intersects(TimeRange::new(lo, hi))
                    })
            })
            .collect();
        for id in touched {
            let Some(chunk) = self.chunk(id).cloned() else {
                continue;
            };
            let Some(times) = chunk.time_column(timeline).map(TimeColumn::times) else {
                continue;
            };
            let kept: Vec<(usize, usize)> = (0..chunk.num_rows())
                .filter(|&row| !(min.as_i64()..=max.as_i64()).contains(&times[row]))
                .map(|row| (0, row))
                .collect();
            let rest = if kept.is_empty() {
                None
            } else {
                match Chunk::gather(&[&chunk], &kept) {
                    Ok(rest) => Some(rest),
                    // Copying rows of a valid chunk does not fail; if it ever did, the
                    // chunk would stay whole rather than lose rows outside the range.
                    Err(error) => {
                        debug_assert!(false, "keeping the rows of {id} outside {range}: {error}");
                        continue;
                    }
                }
            };
            // Removed before its rest is added: the rest covers the chunk's times, so
            // adding it first would overlap them and turn an in-order entity's sequence
            // index into the general one.
            self.remove_chunk(id, DeletionReason::Drop, &mut events);
            if let Some(rest) = rest {
                self.add_chunk(Arc::new(rest), &mut events);
            }
        }
        self.finish_mutation(events)
    }

    /// Retention: removes every row older than `span` behind the newest time on
    /// `timeline`, i.e. whose time there is below `newest − span` (a
    /// [`ChunkStore::drop_time_range`] up to it), so that the timeline keeps the last
    /// `span` of data. Static data and rows without `timeline` stay. Returns the events
    /// (none if nothing is that old, or the store has no data on `timeline`).
    ///
    /// ```
    /// # use std::sync::Arc;
    /// # use arrow_array::{ArrayRef, Float64Array};
    /// # use chunkstore::*;
    /// let mut store = ChunkStore::new();
    /// let frame = Timeline::sequence("frame");
    /// for t in 0..10 {
    ///     let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/e")?)
    ///         .with_row(RowId::new(), [(frame.clone(), t)],
    ///                   [("x", Arc::new(Float64Array::from(vec![1.0])) as ArrayRef)])
    ///         .build()?;
    ///     store.insert(Arc::new(chunk))?;
    /// }
    /// store.retain_recent("frame", 3); // keeps frames 6 to 9
    /// let range = store.time_range("frame").unwrap();
    /// assert_eq!((range.min().as_i64(), range.max().as_i64()), (6, 9));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn retain_recent(&mut self, timeline: &str, span: u64) -> Vec<StoreEvent> {
        self.retain_recent_on(&[(timeline, span)])
    }

    /// Retention on several timelines at once: each `(timeline, span)` as
    /// [`ChunkStore::retain_recent`], every newest time measured before anything is
    /// removed (so that the order of the rules does not matter: a row that one rule
    /// removes does not move another timeline's newest time first). A row goes if any rule
    /// removes it.
    pub fn retain_recent_on(&mut self, rules: &[(&str, u64)]) -> Vec<StoreEvent> {
        let ranges: Vec<(&str, TimeRange)> = rules
            .iter()
            .filter_map(|&(timeline, span)| {
                let held = self.time_range(timeline)?;
                // The oldest time kept; everything below goes.
                let keep_from = i128::from(held.max().as_i64()) - i128::from(span);
                if keep_from <= i128::from(held.min().as_i64()) {
                    return None;
                }
                let below = i64::try_from(keep_from - 1).unwrap_or(i64::MAX);
                let range = TimeRange::new(crate::TimeInt::MIN, crate::TimeInt::saturating(below));
                Some((timeline, range))
            })
            .collect();
        ranges
            .into_iter()
            .flat_map(|(timeline, range)| self.drop_time_range(timeline, range))
            .collect()
    }

    /// Removes all of `entity`'s data, static included, and its Clears; with `recursive`,
    /// its descendants' too. Returns the events.
    pub fn drop_entity(&mut self, entity: &EntityPath, recursive: bool) -> Vec<StoreEvent> {
        let mut targets: Vec<ChunkId> = Vec::new();
        for (path, index) in &self.entities {
            if (path == entity || (recursive && entity.is_ancestor_of(path)))
                && let Some(view) = self.view.entities.at(index.slot)
            {
                targets.extend(index.held_chunks(view, &self.chunks).map(|c| c.id()));
            }
        }
        targets.sort_unstable();
        let mut events = Vec::with_capacity(targets.len());
        let stored = targets
            .iter()
            .filter_map(|id| self.chunks.remove(id))
            .collect();
        self.take_out_all(stored, DeletionReason::Drop, &mut events);
        crate::clear::ClearIndex::remove_entity(&mut self.view.clears, entity, recursive);
        self.finish_mutation(events)
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::{ArrayRef, Float64Array};

    use super::*;
    use crate::index::TemporalComponentIndex;
    use crate::{ChunkBuilder, RowId, StoreConfig, TimeInt, Timeline};

    /// A range drop inside one chunk of an in-order entity keeps its index a sequence: the
    /// chunk leaves before the rest of its rows come back.
    #[test]
    fn a_partial_range_drop_keeps_a_sequence() {
        let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).unwrap();
        let (frame, entity) = (Timeline::sequence("frame"), EntityPath::parse("e").unwrap());
        for c in 0..40i64 {
            let mut builder = ChunkBuilder::new(ChunkId::new(), entity.clone());
            for r in 0..10 {
                let value = Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
                builder =
                    builder.with_row(RowId::new(), [(frame.clone(), c * 10 + r)], [("x", value)]);
            }
            store.insert(builder.build().unwrap()).unwrap();
        }
        let is_sequence = |store: &ChunkStore| {
            let index = store.view.entities[&entity]
                .temporal_per_timeline_per_component
                .get("frame")
                .and_then(|per_component| per_component.get("x"));
            matches!(index, Some(TemporalComponentIndex::Sequence(_)))
        };
        assert!(is_sequence(&store));
        // Inside the last chunk, the first, and one in the middle.
        for (min, max) in [(393, 395), (2, 4), (203, 205)] {
            let range = TimeRange::new(TimeInt::new(min).unwrap(), TimeInt::new(max).unwrap());
            let events = store.drop_time_range("frame", range);
            assert_eq!(
                events.len(),
                2,
                "the chunk's deletion, then its rest's addition"
            );
            assert!(matches!(events[0], StoreEvent::Deletion { .. }));
            assert!(matches!(events[1], StoreEvent::Addition(_)));
            store.sanity_check().unwrap();
            assert!(is_sequence(&store));
        }
        assert_eq!(store.stats().num_temporal_rows, 400 - 9);
    }

    /// An in-order entity's index is a sequence up to `SEQUENCE_MAX_CHUNKS` chunks and the
    /// three views past it (which a write under a snapshot copies a path of, not whole);
    /// answers do not change with the form.
    #[test]
    fn a_sequence_past_its_bound_takes_the_views() {
        use crate::LatestAtQuery;
        use crate::index::SEQUENCE_MAX_CHUNKS;

        let bound = i64::try_from(SEQUENCE_MAX_CHUNKS).unwrap();
        let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).unwrap();
        let (frame, entity) = (Timeline::sequence("frame"), EntityPath::parse("e").unwrap());
        let form = |store: &ChunkStore| match store.view.entities[&entity]
            .temporal_per_timeline_per_component
            .get("frame")
            .and_then(|per_component| per_component.get("x"))
        {
            Some(TemporalComponentIndex::Sequence(_)) => "sequence",
            Some(TemporalComponentIndex::Large(_)) => "large",
            _ => "small",
        };
        for c in 0..=bound {
            if c == bound {
                assert_eq!(form(&store), "sequence");
            }
            let value = Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
            let chunk = ChunkBuilder::new(ChunkId::new(), entity.clone())
                .with_row(RowId::new(), [(frame.clone(), 2 * c)], [("x", value)])
                .build()
                .unwrap();
            store.insert(chunk).unwrap();
        }
        assert_eq!(form(&store), "large");
        store.sanity_check().unwrap();
        for t in [0, 1, 999, 2 * bound, i64::MAX] {
            let query = LatestAtQuery::new("frame", TimeInt::new(t).unwrap());
            let cell = store.latest_at(&query, &entity, "x").unwrap();
            let expected = (t / 2).min(bound);
            assert_eq!(cell.time(), TimeInt::new(2 * expected), "latest-at {t}");
        }
    }
}
