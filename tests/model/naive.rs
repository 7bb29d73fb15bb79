//! The naive model: every row in a list, scanned for every answer.

use super::*;

/// What a query answers: `(time, row id, cell)` (time `None` for static).
pub(crate) type Answer = (Option<i64>, u128, Vec<i64>);

/// A Clear as the model keeps it: `(entity, row id, times, recursive)`; `times` is `None`
/// for a static Clear, else each timeline's time (`None` where the Clear has none).
pub(crate) type ModelClear = (usize, u128, Option<[Option<i64>; 3]>, bool);

/// A temporal data row the model holds: `(entity, timelines, row)`.
pub(crate) type HeldRow = (usize, u8, ModelRow);

/// The naive model: every row in a list.
#[derive(Clone, Default)]
pub(crate) struct Model {
    pub(crate) rows: Vec<HeldRow>,
    /// Every Clear that hides (an overwritten static Clear keeps hiding, SEMANTICS.md section 5).
    pub(crate) clears: Vec<ModelClear>,
    /// The static chunks the store holds, oldest first: each answers for at least one
    /// component (the Clear component counts for a static Clear chunk).
    pub(crate) statics: Vec<ModelChunk>,
}

pub(crate) fn is_strict_ancestor(ancestor: usize, of: usize) -> bool {
    path(ENTITIES[ancestor]).is_ancestor_of(&path(ENTITIES[of]))
}

/// The cell of component `component` in a static row, or the Clear pseudo-component
/// (`component == COMPONENTS.len()`).
pub(crate) fn static_cell(row: &ModelRow, component: usize) -> Option<Vec<i64>> {
    match &row.content {
        Content::Data(cells) => cells.get(component).cloned().flatten(),
        Content::Clear(_) => (component == COMPONENTS.len()).then(Vec::new),
    }
}

impl Model {
    /// The static winner of `(entity, component)`: the greatest row id with a cell, the
    /// later insert on a tie; and the position of its chunk in `statics`.
    pub(crate) fn static_winner(&self, entity: usize, component: usize) -> Option<(usize, Answer)> {
        let mut best: Option<(usize, Answer)> = None;
        for (position, chunk) in self.statics.iter().enumerate() {
            if chunk.entity != entity {
                continue;
            }
            for row in &chunk.rows {
                if let Some(cell) = static_cell(row, component)
                    && best
                        .as_ref()
                        .is_none_or(|(_, (_, id, _))| row.row_id >= *id)
                {
                    best = Some((position, (None, row.row_id, cell)));
                }
            }
        }
        best
    }

    /// Keeps only the static chunks of `entity` that still answer for a component.
    pub(crate) fn drop_overwritten_statics(&mut self, entity: usize) {
        let winners: HashSet<usize> = (0..=COMPONENTS.len())
            .filter_map(|c| self.static_winner(entity, c).map(|(position, _)| position))
            .collect();
        let mut position = 0;
        self.statics.retain(|chunk| {
            let keep = chunk.entity != entity || winners.contains(&position);
            position += 1;
            keep
        });
    }

    /// Does the model hold `row` of `chunk`: a row of the same entity and layout, with the
    /// same row id, times and contents?
    pub(crate) fn holds(&self, chunk: &ModelChunk, row: &ModelRow) -> bool {
        let same_times = |other: &ModelRow| {
            (0..3).all(|i| !chunk.has_timeline(i) || other.times[i] == row.times[i])
        };
        if chunk.is_static() {
            return self.statics.iter().any(|held| {
                held.entity == chunk.entity
                    && held.is_clear == chunk.is_clear
                    && held.rows.contains(row)
            });
        }
        if chunk.is_clear {
            let Content::Clear(recursive) = row.content else {
                return false;
            };
            let times = [0, 1, 2].map(|i| chunk.time(row, i));
            return self
                .clears
                .contains(&(chunk.entity, row.row_id, Some(times), recursive));
        }
        self.rows.iter().any(|(entity, timelines, held)| {
            *entity == chunk.entity
                && *timelines == chunk.timelines
                && held.row_id == row.row_id
                && held.content == row.content
                && same_times(held)
        })
    }

    /// Adds the rows of `chunk` the model does not hold; returns whether any was new.
    pub(crate) fn insert(&mut self, chunk: &ModelChunk) -> bool {
        let new: Vec<ModelRow> = chunk
            .rows
            .iter()
            .filter(|row| !self.holds(chunk, row))
            .cloned()
            .collect();
        if new.is_empty() {
            return false;
        }
        for row in &new {
            if let Content::Clear(recursive) = row.content {
                let times = (!chunk.is_static()).then(|| [0, 1, 2].map(|i| chunk.time(row, i)));
                self.clears
                    .push((chunk.entity, row.row_id, times, recursive));
            }
        }
        if chunk.is_static() {
            self.statics.push(ModelChunk {
                rows: new,
                ..chunk.clone()
            });
            self.drop_overwritten_statics(chunk.entity);
        } else if !chunk.is_clear {
            self.rows.extend(
                new.into_iter()
                    .map(|row| (chunk.entity, chunk.timelines, row)),
            );
        }
        true
    }

    /// Every temporal row of `entity` with a time on `timeline` and a non-null cell of
    /// `component`, as an answer.
    pub(crate) fn temporal_cells(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
    ) -> impl Iterator<Item = Answer> + '_ {
        self.rows.iter().filter_map(move |(e, timelines, row)| {
            let time = (timelines & (1 << timeline) != 0).then_some(row.times[timeline])?;
            let Content::Data(cells) = &row.content else {
                return None;
            };
            let cell = cells[component].clone()?;
            (*e == entity).then_some((Some(time), row.row_id, cell))
        })
    }

    /// Every acceptable latest-at answer (several when rows tie on `(time, row id)` with
    /// different cells); empty for none.
    pub(crate) fn latest_at(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
        at: i64,
    ) -> Vec<Answer> {
        let candidates: Vec<Answer> =
            if let Some((_, winner)) = self.static_winner(entity, component) {
                vec![winner]
            } else {
                let rows: Vec<Answer> = self
                    .temporal_cells(entity, component, timeline)
                    .filter(|(time, ..)| time.is_some_and(|time| time <= at))
                    .collect();
                let Some(best) = rows.iter().map(|(time, id, _)| (*time, *id)).max() else {
                    return Vec::new();
                };
                rows.into_iter()
                    .filter(|(time, id, _)| (*time, *id) == best)
                    .collect()
            };
        candidates
            .into_iter()
            .filter(|(time, row_id, _)| !self.is_hidden(entity, timeline, at, *time, *row_id))
            .collect()
    }

    pub(crate) fn is_hidden(
        &self,
        entity: usize,
        timeline: usize,
        at: i64,
        time: Option<i64>,
        row_id: u128,
    ) -> bool {
        self.clears
            .iter()
            .any(|&(clear_entity, clear_row_id, clear_times, recursive)| {
                let applies = clear_entity == entity
                    || (recursive && is_strict_ancestor(clear_entity, entity));
                if !applies {
                    return false;
                }
                match (clear_times, time) {
                    (None, None) => row_id <= clear_row_id,
                    (None, Some(_)) => true,
                    (Some(_), None) => false,
                    (Some(times), Some(time)) => times[timeline].is_some_and(|clear_time| {
                        clear_time <= at && (time, row_id) <= (clear_time, clear_row_id)
                    }),
                }
            })
    }

    /// The range answer, sorted by `(time, row id, cell)` (the order among rows of equal
    /// index is unspecified, so both sides are compared sorted this way).
    pub(crate) fn range(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
        min: i64,
        max: i64,
    ) -> Vec<Answer> {
        if let Some((_, winner)) = self.static_winner(entity, component) {
            return vec![winner];
        }
        let mut rows: Vec<Answer> = self
            .temporal_cells(entity, component, timeline)
            .filter(|(time, ..)| time.is_some_and(|time| min <= time && time <= max))
            .collect();
        rows.sort();
        rows
    }

    /// Forgets one row per row of `chunk` (a chunk garbage collection removed).
    pub(crate) fn forget_chunk(&mut self, chunk: &Chunk) {
        let entity = ENTITIES
            .iter()
            .position(|e| path(e) == *chunk.entity_path())
            .unwrap();
        for row in 0..chunk.num_rows() {
            let (timelines, row) = model_row_of(chunk, row);
            let position = match row.content {
                Content::Clear(recursive) => {
                    let times =
                        [0, 1, 2].map(|i| (timelines & (1 << i) != 0).then_some(row.times[i]));
                    let clear = (entity, row.row_id, Some(times), recursive);
                    self.clears.iter().position(|c| *c == clear).map(|p| {
                        self.clears.remove(p);
                    })
                }
                Content::Data(_) => {
                    let same = |(e, l, held): &HeldRow| {
                        *e == entity
                            && *l == timelines
                            && held.row_id == row.row_id
                            && held.content == row.content
                            && (0..3).all(|i| l & (1 << i) == 0 || held.times[i] == row.times[i])
                    };
                    self.rows.iter().position(same).map(|p| {
                        self.rows.remove(p);
                    })
                }
            };
            assert!(position.is_some(), "the model held every collected row");
        }
    }
}
