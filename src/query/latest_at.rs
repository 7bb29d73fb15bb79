//! Latest-at: the value of a component at an entity as of a time.

use std::sync::Arc;

use super::QueryCell;
use crate::chunk::ComponentTimeBounds;
use crate::index::TemporalComponentIndex;
use crate::{Chunk, EntityPath, RowId, StoreView, TimeInt};

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
    chunk: &'a Arc<Chunk>,
    component_column: u32,
    row: u32,
    row_id: Option<RowId>,
}

impl<'a> Candidate<'a> {
    /// A chunk's greatest cell of the component on the timeline, known from its bounds.
    fn greatest(
        chunk: &'a Arc<Chunk>,
        component_column: u32,
        bounds: &ComponentTimeBounds,
    ) -> Self {
        Self {
            time: bounds.max_time,
            chunk,
            component_column,
            row: bounds.max_row,
            row_id: Some(bounds.max_row_id),
        }
    }

    fn row_id(&self) -> RowId {
        self.row_id
            .unwrap_or_else(|| self.chunk.row_ids()[self.row as usize])
    }

    /// Does this candidate come after `other` by index `(time, row id)`, and of two in
    /// different chunks with equal indices, by chunk id? The chunk id makes the answer a
    /// function of the chunks held, whichever path found them (index, write buffer), and
    /// the same order garbage collection's `protect_latest` keeps (SEMANTICS.md section 3).
    fn is_after(&self, other: &Self) -> bool {
        if self.time != other.time {
            return self.time > other.time;
        }
        match self.row_id().cmp(&other.row_id()) {
            std::cmp::Ordering::Equal => self.chunk.id() > other.chunk.id(),
            unequal => unequal.is_gt(),
        }
    }
}

/// Keeps the later of `best` and `candidate`.
fn keep_latest<'a>(best: &mut Option<Candidate<'a>>, candidate: Option<Candidate<'a>>) {
    if let Some(candidate) = candidate
        && best.as_ref().is_none_or(|best| candidate.is_after(best))
    {
        *best = Some(candidate);
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
            && !is_a_clear(&answer)
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
        let mut best = entity_index
            .temporal_per_timeline_per_component
            .get(query.timeline())
            .and_then(|per_component| per_component.get(component))
            .and_then(|index| latest_in_index(index, query.at));
        if !entity_index.buffered.is_empty() {
            entity_index.buffered.for_each_candidate(
                query.timeline(),
                component,
                query.at,
                |chunk, time_column, component_column, bounds| {
                    // As in an index: a chunk ending by the time answers with its greatest
                    // cell, known from its bounds; only one straddling it is searched.
                    let candidate = if bounds.max_time <= query.at {
                        Some(Candidate::greatest(chunk, component_column, &bounds))
                    } else if bounds.min_time <= query.at {
                        latest_in_chunk(chunk, time_column, component_column, query.at)
                    } else {
                        None
                    };
                    keep_latest(&mut best, candidate);
                },
            );
        }
        let best = best?;
        Some(QueryCell {
            chunk: Arc::clone(best.chunk),
            component_column: best.component_column,
            row: best.row,
            time: Some(best.time),
        })
    }
}

fn latest_in_index(index: &TemporalComponentIndex, at: TimeInt) -> Option<Candidate<'_>> {
    let mut best: Option<Candidate<'_>> = None;
    index.for_each_latest_at_candidate(at, |entry, straddles| {
        let candidate = if straddles {
            latest_in_chunk(&entry.chunk, entry.time_column, entry.component_column, at)
        } else {
            Some(Candidate::greatest(
                &entry.chunk,
                entry.component_column,
                &entry.bounds,
            ))
        };
        keep_latest(&mut best, candidate);
    });
    best
}

/// Is the cell one of the Clear column's? The chunk's flag first: it shares the answer's
/// first cache line, where the column's name is two lines further.
fn is_a_clear(cell: &QueryCell) -> bool {
    cell.chunk.has_clears() && cell.column().name().is_clear()
}

/// The non-null cell with the greatest index at or before `at` inside one chunk.
#[expect(
    clippy::cast_possible_truncation,
    reason = "rows < 2^32, checked in Chunk::from_raw"
)]
fn latest_in_chunk(
    chunk: &Arc<Chunk>,
    time_column: u32,
    component_column: u32,
    at: TimeInt,
) -> Option<Candidate<'_>> {
    let times = &chunk.time_columns()[time_column as usize];
    let column = &chunk.components()[component_column as usize];
    let end = times.num_positions_at_or_before_touching(at.as_i64(), |row| column.touch_cell(row));
    (0..end)
        .rev()
        .map(|pos| times.row_at(pos))
        .find(|&row| column.is_valid_in_bounds(row))
        .map(|row| Candidate {
            time: TimeInt::saturating(times.times()[row]),
            chunk,
            component_column,
            row: row as u32,
            row_id: None,
        })
}
