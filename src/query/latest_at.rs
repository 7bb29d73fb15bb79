//! Latest-at: the value of a component at an entity as of a time.

use std::sync::Arc;

use super::QueryCell;
use crate::index::{IndexedChunk, TemporalComponentIndex};
use crate::{ChunkStore, EntityPath, RowId, TimeInt};

/// "As of time `at` on `timeline`".
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LatestAtQuery {
    timeline: Arc<str>,
    at: TimeInt,
}

impl LatestAtQuery {
    /// A query on the named timeline at `at`.
    pub fn new(timeline: impl Into<Arc<str>>, at: TimeInt) -> Self {
        Self {
            timeline: timeline.into(),
            at,
        }
    }

    /// The timeline's name.
    pub fn timeline(&self) -> &str {
        &self.timeline
    }

    /// The time.
    pub fn at(&self) -> TimeInt {
        self.at
    }
}

/// A candidate answer: its index `(time, row id)`, and where it is.
type Candidate<'a> = ((TimeInt, RowId), &'a IndexedChunk, u32);

impl ChunkStore {
    /// The cell of `component` at `entity` as of the query's time, per SEMANTICS.md:
    /// static data wins outright; otherwise the non-null cell with the greatest
    /// `(time, row id)` at or before the time; then a Clear may hide it (`None`).
    ///
    /// Cost: O(log n) in the chunks of this (entity, timeline, component), plus one
    /// binary search in each chunk whose span strictly contains the time, plus one lookup
    /// per ancestor that ever logged a Clear.
    pub fn latest_at(
        &self,
        query: &LatestAtQuery,
        entity: &EntityPath,
        component: &str,
    ) -> Option<QueryCell> {
        let answer = self.latest_at_unfiltered(query, entity, component)?;
        let hidden = !self.clears.is_empty()
            && !answer.component().name().is_clear()
            && self.clears.is_hidden(
                entity,
                query.timeline(),
                query.at,
                answer.time,
                answer.row_id,
            );
        (!hidden).then_some(answer)
    }

    /// Latest-at before Clears are applied.
    fn latest_at_unfiltered(
        &self,
        query: &LatestAtQuery,
        entity: &EntityPath,
        component: &str,
    ) -> Option<QueryCell> {
        let entity_index = self.entities.get(entity)?;
        if let Some(winner) = entity_index.static_winners.get(component) {
            return Some(QueryCell {
                chunk: Arc::clone(&winner.chunk),
                component_column: winner.component_column,
                row: winner.row,
                time: None,
                row_id: winner.row_id,
            });
        }
        let index = entity_index
            .temporal_per_timeline_per_component
            .get(query.timeline())?
            .get(component)?;
        let ((time, row_id), entry, row) = latest_in_index(index, query.at)?;
        Some(QueryCell {
            chunk: Arc::clone(&entry.chunk),
            component_column: entry.component_column,
            row,
            time: Some(time),
            row_id,
        })
    }
}

fn latest_in_index(index: &TemporalComponentIndex, at: TimeInt) -> Option<Candidate<'_>> {
    let mut best: Option<Candidate<'_>> = index.latest_ending_at_or_before(at).map(|entry| {
        let b = entry.bounds;
        ((b.max_time, b.max_row_id), entry, b.max_row)
    });
    index.for_each_straddling(at, |entry| {
        if let Some(candidate) = latest_in_chunk(entry, at)
            && best.as_ref().is_none_or(|(key, ..)| candidate.0 > *key)
        {
            best = Some(candidate);
        }
    });
    best
}

/// The non-null cell with the greatest index at or before `at` inside one chunk.
#[expect(
    clippy::cast_possible_truncation,
    reason = "rows < 2^32, checked in Chunk::from_raw"
)]
fn latest_in_chunk(entry: &IndexedChunk, at: TimeInt) -> Option<Candidate<'_>> {
    let chunk = &entry.chunk;
    let times = &chunk.time_columns()[entry.time_column as usize];
    let column = &chunk.components()[entry.component_column as usize];
    let end = times.num_positions_at_or_before(at.as_i64());
    (0..end)
        .rev()
        .map(|pos| times.row_at(pos))
        .find(|&row| column.is_valid(row))
        .map(|row| {
            let key = chunk.index_of_row(entry.time_column as usize, row);
            (key, entry, row as u32)
        })
}
