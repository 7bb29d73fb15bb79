//! Latest-at: the value of a component at an entity as of a time.

use std::sync::Arc;

use super::QueryCell;
use crate::index::{IndexedChunk, TemporalComponentIndex};
use crate::{EntityPath, RowId, StoreView, TimeInt};

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

/// A candidate answer: its time, where it is, and its row id if already known (an index
/// entry keeps its chunk's greatest; inside a chunk it is read only to break a tie).
struct Candidate<'a> {
    time: TimeInt,
    entry: &'a IndexedChunk,
    row: u32,
    row_id: Option<RowId>,
}

impl Candidate<'_> {
    fn row_id(&self) -> RowId {
        self.row_id
            .unwrap_or_else(|| self.entry.chunk.row_ids()[self.row as usize])
    }

    /// Does this candidate have a greater index `(time, row id)` than `other`?
    fn is_after(&self, other: &Self) -> bool {
        self.time > other.time || (self.time == other.time && self.row_id() > other.row_id())
    }
}

impl StoreView {
    /// The cell of `component` at `entity` as of the query's time, per SEMANTICS.md section 3:
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
                answer.row_id(),
            );
        (!hidden).then_some(answer)
    }

    /// Latest-at before Clears are applied.
    pub(crate) fn latest_at_unfiltered(
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
            });
        }
        let index = entity_index
            .temporal_per_timeline_per_component
            .get(query.timeline())?
            .get(component)?;
        let best = latest_in_index(index, query.at)?;
        Some(QueryCell {
            chunk: Arc::clone(&best.entry.chunk),
            component_column: best.entry.component_column,
            row: best.row,
            time: Some(best.time),
        })
    }
}

fn latest_in_index(index: &TemporalComponentIndex, at: TimeInt) -> Option<Candidate<'_>> {
    let mut best: Option<Candidate<'_>> =
        index.latest_ending_at_or_before(at).map(|entry| Candidate {
            time: entry.bounds.max_time,
            entry,
            row: entry.bounds.max_row,
            row_id: Some(entry.bounds.max_row_id),
        });
    index.for_each_straddling(at, |entry| {
        if let Some(candidate) = latest_in_chunk(entry, at)
            && best.as_ref().is_none_or(|best| candidate.is_after(best))
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
        .find(|&row| column.is_valid_in_bounds(row))
        .map(|row| Candidate {
            time: TimeInt::saturating(times.times()[row]),
            entry,
            row: row as u32,
            row_id: None,
        })
}
