//! Dataframe queries in the model test: the model's own dataframe, built row by row from
//! its list, against the store's.

use super::*;

/// A dataframe query the model test runs: on `timeline`, over `[min, max]` or sampled at
/// `sample`, filled or not, over the entities `contents` picks, in batches of
/// `batch_rows`.
#[derive(Clone, Debug)]
#[allow(
    clippy::struct_excessive_bools,
    reason = "each is a switch of the query, drawn on its own"
)]
pub(crate) struct DataframeOp {
    pub(crate) timeline: usize,
    pub(crate) min: i64,
    pub(crate) max: i64,
    pub(crate) fill: bool,
    pub(crate) sample: Option<Vec<i64>>,
    /// `None`: the default (everything); `Some((e, true))`: `ENTITIES[e]`'s subtree;
    /// `Some((e, false))`: everything but it.
    pub(crate) contents: Option<(usize, bool)>,
    pub(crate) batch_rows: usize,
    /// `Some(mask)`: only the data columns whose position in the full view has its bit
    /// set (`DataframeQuery::with_columns`; the index column stays, and the other index
    /// columns unless bit 63 is set); the rows stay the full view's.
    pub(crate) columns: Option<u64>,
    /// `DataframeQuery::with_tombstone_columns` and `with_semantically_empty_columns`.
    pub(crate) tombstones: bool,
    pub(crate) empty_columns: bool,
    /// `DataframeQuery::with_exact_index_values`.
    pub(crate) exact: bool,
}

impl DataframeOp {
    /// Is data column `position` (in the full view) kept?
    pub(crate) fn keeps(&self, position: usize) -> bool {
        self.columns
            .is_none_or(|mask| position >= 64 || mask & (1 << position) != 0)
    }
}

pub(crate) fn dataframe_op() -> impl Strategy<Value = DataframeOp> {
    (
        0..3usize,
        query_time(),
        0..6i64,
        any::<bool>(),
        prop::option::weighted(0.3, prop::collection::vec(query_time(), 0..6)),
        prop::option::weighted(0.4, (0..ENTITIES.len(), any::<bool>())),
        1..5usize,
        prop::option::weighted(0.3, any::<u64>()),
        (
            prop::bool::weighted(0.8),
            prop::bool::weighted(0.8),
            any::<bool>(),
        ),
    )
        .prop_map(
            |(
                timeline,
                min,
                len,
                fill,
                sample,
                contents,
                batch_rows,
                columns,
                (tombstones, empty_columns, exact),
            )| DataframeOp {
                timeline,
                min,
                max: if len == 5 {
                    i64::MAX
                } else {
                    min.saturating_add(len)
                },
                fill,
                sample,
                contents,
                batch_rows,
                columns,
                tombstones,
                empty_columns,
                exact,
            },
        )
}

/// The component columns of the model, the Clear component last (`COMPONENTS.len()`).
pub(crate) const CLEAR_COMPONENT: usize = COMPONENTS.len();

pub(crate) fn component_name(component: usize) -> &'static str {
    COMPONENTS
        .get(component)
        .copied()
        .unwrap_or(ComponentName::CLEAR_IS_RECURSIVE)
}

/// A table as the model test reads one: data column names, index values, cells per column.
pub(crate) type Table<C> = (Vec<String>, Vec<i64>, Vec<Vec<C>>);

/// A dataframe cell as the model sees it: every acceptable value (rows that tie on their
/// whole index may answer either way); `None` for a null cell.
pub(crate) type DataframeCell = Vec<Cell>;

impl Model {
    /// The Clears that apply to `entity`'s data: its own, and its ancestors' recursive ones.
    pub(crate) fn clears_of(&self, entity: usize) -> impl Iterator<Item = &ModelClear> + '_ {
        self.clears.iter().filter(move |(at, _, _, recursive)| {
            *at == entity || (*recursive && is_strict_ancestor(*at, entity))
        })
    }

    /// The temporal events of a column on `timeline`: `(time, row id, cell)`, data rows
    /// and, for a data component, the Clears that apply (an empty cell).
    pub(crate) fn column_events(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
    ) -> Vec<(i64, u128, Vec<i64>)> {
        let mut events: Vec<(i64, u128, Vec<i64>)> = Vec::new();
        if component == CLEAR_COMPONENT {
            for &(at, row_id, times, recursive) in &self.clears {
                if let (true, Some(times)) = (at == entity, times)
                    && let Some(time) = times[timeline]
                {
                    events.push((time, row_id, vec![i64::from(recursive)]));
                }
            }
        } else {
            events.extend(
                self.temporal_cells(entity, component, timeline)
                    .map(|(time, row_id, cell)| (time.unwrap(), row_id, cell)),
            );
        }
        events
    }

    /// The temporal Clears a column shows as an empty list at their own time on
    /// `timeline`, `(time, row id)`: for a data component, the Clears that apply to it
    /// (which also hide its values); for the Clear component, which no Clear hides, its
    /// strict ancestors' recursive Clears.
    pub(crate) fn column_clear_events(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
    ) -> Vec<(i64, u128)> {
        let marking: Box<dyn Iterator<Item = &ModelClear>> =
            if component == CLEAR_COMPONENT {
                Box::new(self.clears.iter().filter(move |&&(at, _, _, recursive)| {
                    recursive && is_strict_ancestor(at, entity)
                }))
            } else {
                Box::new(self.clears_of(entity))
            };
        marking
            .filter_map(|&(_, row_id, times, _)| Some((times?[timeline]?, row_id)))
            .collect()
    }

    /// The Clears that hide a column's values at or before a time: none for the Clear
    /// component.
    pub(crate) fn column_hiding_clears(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
    ) -> Vec<(i64, u128)> {
        if component == CLEAR_COMPONENT {
            return Vec::new();
        }
        self.column_clear_events(entity, component, timeline)
    }

    pub(crate) fn has_static_clear(&self, entity: usize, component: usize) -> Option<u128> {
        if component == CLEAR_COMPONENT {
            return None;
        }
        self.clears_of(entity)
            .filter(|(_, _, times, _)| times.is_none())
            .map(|&(_, row_id, _, _)| row_id)
            .max()
    }

    /// Does the column exist: static data, or temporal data on some timeline?
    pub(crate) fn column_has_data(&self, entity: usize, component: usize) -> bool {
        self.static_winner(entity, component).is_some()
            || (0..TIMELINES.len())
                .any(|timeline| !self.column_events(entity, component, timeline).is_empty())
    }

    /// Does the column hold a cell that is neither null nor empty (its static winner's,
    /// where it has static data; else any temporal one)? The Clear component's cells are
    /// its one-flag lists.
    pub(crate) fn column_holds_data(&self, entity: usize, component: usize) -> bool {
        if component == CLEAR_COMPONENT {
            return self.column_has_data(entity, component);
        }
        if let Some((_, (_, _, cell))) = self.static_winner(entity, component) {
            return !cell.is_empty();
        }
        (0..TIMELINES.len()).any(|timeline| {
            self.column_events(entity, component, timeline)
                .iter()
                .any(|(_, _, cell)| !cell.is_empty())
        })
    }

    /// A static column's cell: the static winner, or null (no answer) if a static Clear
    /// hides it.
    pub(crate) fn static_column_cell(
        &self,
        entity: usize,
        component: usize,
    ) -> Option<DataframeCell> {
        let (position, (_, row_id, mut cell)) = self.static_winner(entity, component)?;
        if component == CLEAR_COMPONENT {
            // `static_cell` stands in an empty cell for a Clear; the column shows its flag.
            let flag =
                self.statics[position]
                    .rows
                    .iter()
                    .rev()
                    .find_map(|row| match row.content {
                        Content::Clear(recursive) if row.row_id == row_id => Some(recursive),
                        _ => None,
                    })?;
            cell = vec![i64::from(flag)];
        }
        let hidden = self
            .has_static_clear(entity, component)
            .is_some_and(|c| row_id <= c);
        Some(vec![if hidden { None } else { Some(cell) }])
    }

    /// The cell of a temporal column at `at` as filling and sampling see it: the
    /// latest-at answer, null where there is none or a Clear hides it.
    pub(crate) fn column_cell_at(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
        at: i64,
    ) -> DataframeCell {
        if self.has_static_clear(entity, component).is_some() {
            return vec![None];
        }
        let events: Vec<_> = self
            .column_events(entity, component, timeline)
            .into_iter()
            .filter(|(time, ..)| *time <= at)
            .collect();
        let best = events
            .iter()
            .map(|(time, row_id, _)| (*time, *row_id))
            .max();
        let clear = self
            .column_hiding_clears(entity, component, timeline)
            .into_iter()
            .filter(|(time, _)| *time <= at)
            .max();
        match (best, clear) {
            (Some(best), Some(clear)) if best <= clear => vec![None],
            (Some(best), _) => events
                .into_iter()
                .filter(|(time, row_id, _)| (*time, *row_id) == best)
                .map(|(_, _, cell)| Some(cell))
                .collect(),
            (None, _) => vec![None],
        }
    }

    /// The sparse cell of a temporal column at `time`, `None` if it has no event there:
    /// the row of greatest row id; an empty list where a Clear at that time came later
    /// (its mark); null where a static Clear hides the row.
    pub(crate) fn column_cell_exactly_at(
        &self,
        entity: usize,
        component: usize,
        timeline: usize,
        time: i64,
    ) -> Option<DataframeCell> {
        let events: Vec<_> = self
            .column_events(entity, component, timeline)
            .into_iter()
            .filter(|(t, ..)| *t == time)
            .collect();
        let best = events.iter().map(|(_, row_id, _)| *row_id).max();
        let clear = self
            .column_clear_events(entity, component, timeline)
            .into_iter()
            .filter(|(t, _)| *t == time)
            .map(|(_, row_id)| row_id)
            .max();
        let hidden_by_static = self.has_static_clear(entity, component).is_some();
        match (best, clear) {
            (Some(best), Some(clear)) if best <= clear || hidden_by_static => {
                Some(vec![Some(vec![])])
            }
            (Some(_), None) if hidden_by_static => Some(vec![None]),
            (Some(best), _) => Some(
                events
                    .into_iter()
                    .filter(|(_, row_id, _)| *row_id == best)
                    .map(|(_, _, cell)| Some(cell))
                    .collect(),
            ),
            (None, Some(_)) => Some(vec![Some(vec![])]),
            (None, None) => None,
        }
    }

    /// The model's table: column names, index values, and per column its cells.
    pub(crate) fn dataframe(&self, op: &DataframeOp) -> Table<DataframeCell> {
        let selected = |entity: usize| match op.contents {
            None => true,
            Some((root, include)) => {
                path(ENTITIES[entity]).starts_with(&path(ENTITIES[root])) == include
            }
        };
        let mut columns: Vec<(chunkstore::EntityPath, &str, usize, usize)> = Vec::new();
        for entity in (0..ENTITIES.len()).filter(|&e| selected(e)) {
            for component in 0..=COMPONENTS.len() {
                if self.column_has_data(entity, component)
                    && (op.tombstones || component != CLEAR_COMPONENT)
                    && (op.empty_columns || self.column_holds_data(entity, component))
                {
                    columns.push((
                        path(ENTITIES[entity]),
                        component_name(component),
                        entity,
                        component,
                    ));
                }
            }
        }
        columns.sort_by(|a, b| (&a.0, a.1).cmp(&(&b.0, b.1)));
        let names = columns
            .iter()
            .map(|(p, name, ..)| format!("{p}:{name}"))
            .collect();
        let timeline = op.timeline;
        let times: Vec<i64> = if let Some(values) = &op.sample {
            values.clone()
        } else {
            let mut times = BTreeSet::new();
            for &(_, _, entity, component) in &columns {
                if self.static_winner(entity, component).is_some() {
                    continue;
                }
                for (time, ..) in self.column_events(entity, component, timeline) {
                    times.insert(time);
                }
                for (time, _) in self.column_clear_events(entity, component, timeline) {
                    times.insert(time);
                }
            }
            times
                .into_iter()
                .filter(|t| op.min <= *t && *t <= op.max)
                .collect()
        };
        let cells = columns
            .iter()
            .map(|&(_, _, entity, component)| {
                times
                    .iter()
                    .map(|&time| {
                        if let Some(cell) = self.static_column_cell(entity, component) {
                            return cell;
                        }
                        if op.sample.is_some() && op.exact {
                            return self
                                .column_cell_exactly_at(entity, component, timeline, time)
                                .unwrap_or_else(|| vec![None]);
                        }
                        if op.sample.is_some() {
                            return self.column_cell_at(entity, component, timeline, time);
                        }
                        match self.column_cell_exactly_at(entity, component, timeline, time) {
                            Some(cell) => cell,
                            None if op.fill => {
                                self.column_cell_at(entity, component, timeline, time)
                            }
                            None => vec![None],
                        }
                    })
                    .collect()
            })
            .collect();
        (names, times, cells)
    }
}

/// The store's table for `op`, read back as the model writes tables.
pub(crate) fn dataframe_answer(store: &ChunkStore, op: &DataframeOp) -> Option<Table<Cell>> {
    let mut query = DataframeQuery::new(TIMELINES[op.timeline].0)
        .with_range(TimeRange::new(t(op.min), t(op.max)))
        .with_fill_latest_at(op.fill)
        .with_batch_rows(op.batch_rows)
        .with_tombstone_columns(op.tombstones)
        .with_semantically_empty_columns(op.empty_columns)
        .with_exact_index_values(op.exact);
    if let Some(values) = &op.sample {
        query = query.with_index_values(values.iter().map(|&v| t(v)));
    }
    if let Some((entity, include)) = op.contents {
        let subtree = format!("{}/**", path(ENTITIES[entity])).replacen("//", "/", 1);
        let rule = if include {
            subtree
        } else {
            format!("-{subtree}")
        };
        query = query.with_contents(EntityPathFilter::parse([rule]).unwrap());
    }
    if op.columns.is_some() {
        let Ok(full) = store.dataframe_schema(&query) else {
            return None; // an unknown index: refused with or without columns
        };
        let mut data = 0;
        let kept: Vec<String> = full
            .fields()
            .iter()
            .filter(|f| {
                if !f.name().contains(':') {
                    // The index column; the others unless the mask's top bit is set (no
                    // cell then raises them, and a sorted chunk's rows may go at once).
                    return f.name() == TIMELINES[op.timeline].0
                        || op.columns.is_some_and(|mask| mask >> 63 == 0);
                }
                data += 1;
                op.keeps(data - 1)
            })
            .map(|f| f.name().clone())
            .collect();
        query = query.with_columns(kept);
    }
    // Half the queries read through a stream that owns its snapshot (as the Python
    // package's readers do): the same table either way. Half of those first read the
    // same view in two open-ended parts split inside the range, as SQL's scans do: the
    // snapshot keeps those rows, and the query takes its own from them.
    let stream = if op.batch_rows % 2 == 1 {
        let snapshot = store.snapshot();
        if op.batch_rows == 3 && op.sample.is_none() {
            let split = t(op.min);
            for part in [
                TimeRange::new(split, TimeInt::MAX),
                TimeRange::new(TimeInt::MIN, TimeInt::saturating(op.min - 1)),
            ] {
                if let Ok(stream) = snapshot
                    .clone()
                    .into_dataframe(&query.clone().with_range(part))
                {
                    stream.for_each(|batch| drop(batch.unwrap()));
                }
            }
        }
        snapshot.into_dataframe(&query)
    } else {
        store.dataframe(&query)
    };
    let stream = match stream {
        Ok(stream) => stream,
        Err(chunkstore::DataframeError::UnknownIndex { .. }) => return None,
        Err(e) => panic!("{e}"),
    };
    let schema = stream.schema();
    let names: Vec<String> = schema.fields().iter().map(|f| f.name().clone()).collect();
    let index_position = names
        .iter()
        .position(|n| n == TIMELINES[op.timeline].0)
        .unwrap();
    let data_names: Vec<String> = names.iter().filter(|n| n.contains(':')).cloned().collect();
    let first_data = names.len() - data_names.len();
    let mut times = Vec::new();
    let mut cells: Vec<Vec<Cell>> = vec![Vec::new(); data_names.len()];
    for batch in stream {
        let batch = batch.unwrap();
        assert!(
            batch.num_rows() <= op.batch_rows,
            "a batch holds at most batch_rows rows"
        );
        let index = batch.column(index_position).to_data();
        let index = Int64Array::from(
            index
                .into_builder()
                .data_type(arrow_schema::DataType::Int64)
                .build()
                .unwrap(),
        );
        times.extend(index.iter().map(Option::unwrap));
        for (i, column) in batch.columns()[first_data..].iter().enumerate() {
            let list = column.as_list::<i32>();
            let component = data_names[i].rsplit_once(':').map_or("", |(_, c)| c);
            let component = if data_names[i].ends_with(ComponentName::CLEAR_IS_RECURSIVE) {
                ComponentName::CLEAR_IS_RECURSIVE
            } else {
                component
            };
            for row in 0..list.len() {
                cells[i].push(list.is_valid(row).then(|| {
                    let cell = list.value(row);
                    if component == ComponentName::CLEAR_IS_RECURSIVE {
                        cell.as_boolean()
                            .iter()
                            .map(|b| i64::from(b.unwrap()))
                            .collect()
                    } else {
                        decode(component, &cell)
                    }
                }));
            }
        }
    }
    Some((data_names, times, cells))
}

pub(crate) fn check_dataframe(
    store: &ChunkStore,
    model: &Model,
    op: &DataframeOp,
) -> Result<(), TestCaseError> {
    let (expected_names, expected_times, expected_cells) = model.dataframe(op);
    // Columns left out by `with_columns` are gone; the rows are the full view's.
    let (expected_names, expected_cells): (Vec<String>, Vec<Vec<DataframeCell>>) = expected_names
        .into_iter()
        .zip(expected_cells)
        .enumerate()
        .filter(|(position, _)| op.keeps(*position))
        .map(|(_, column)| column)
        .unzip();
    let Some((names, times, cells)) = dataframe_answer(store, op) else {
        // A timeline the store never saw: the model has nothing on it either.
        let index_known = store.time_type(TIMELINES[op.timeline].0).is_some();
        prop_assert!(!index_known && (op.sample.is_some() || expected_times.is_empty()));
        return Ok(());
    };
    prop_assert_eq!(&names, &expected_names, "dataframe {:?}: columns", op);
    prop_assert_eq!(&times, &expected_times, "dataframe {:?}: index values", op);
    for (((name, ours), expected), _) in names.iter().zip(&cells).zip(&expected_cells).zip(0..) {
        for (row, (cell, acceptable)) in ours.iter().zip(expected).enumerate() {
            prop_assert!(
                acceptable.contains(cell),
                "dataframe {:?}: {} at row {} (time {}): store {:?}, model {:?}",
                op,
                name,
                row,
                times[row],
                cell,
                acceptable
            );
        }
    }
    Ok(())
}
