//! Planning a dataframe: which columns, in which order, with which Arrow fields.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::sync::Arc;

use arrow_array::Array;
use arrow_schema::{DataType, Field, FieldRef, Schema, SchemaRef};

use super::DataframeQuery;
use crate::{Chunk, ComponentDescriptor, ComponentName, EntityPath, StoreView, TimeType, Timeline};

/// One (entity, component) column.
#[derive(Clone, Debug)]
pub(crate) struct ColumnPlan {
    pub entity: EntityPath,
    pub component: ComponentName,
    /// The list's item field, as the first chunk found with the column has it.
    pub item_field: FieldRef,
    /// Archetype and component type, as the first chunk found with the column has them.
    pub descriptor: ComponentDescriptor,
    /// Does the entity hold static data for the component (static then wins)?
    pub is_static: bool,
}

/// The whole table: index columns first (the index among them), then data columns.
#[derive(Clone, Debug)]
pub(crate) struct TablePlan {
    pub index: Timeline,
    /// Every timeline of the selected columns and the index, sorted by name.
    pub index_columns: Vec<Timeline>,
    /// Where the index is among `index_columns`.
    pub index_position: usize,
    pub columns: Vec<ColumnPlan>,
    pub schema: SchemaRef,
}

impl TablePlan {
    pub fn new(store: &StoreView, query: &DataframeQuery, index_type: TimeType) -> Self {
        let index = Timeline::new(Arc::clone(&query.index), index_type);
        let mut timelines: BTreeSet<Timeline> = BTreeSet::from([index.clone()]);
        let mut columns = Vec::new();
        let mut entities = store.entity_paths();
        // Rerun's column order: part by part, each part in natural order.
        entities.sort_by(EntityPath::cmp_natural);
        for entity in entities {
            if !query.contents.matches(&entity) {
                continue;
            }
            let Some(entity_index) = store.entities.get(&entity) else {
                continue;
            };
            // Components with data: a static winner, or a temporal index on some timeline;
            // and the timelines each is on.
            let mut with_data: BTreeMap<ComponentName, (Arc<Chunk>, u32, bool)> = BTreeMap::new();
            let mut on_timelines: BTreeMap<ComponentName, BTreeSet<Timeline>> = BTreeMap::new();
            for (component, winner) in entity_index.static_winners.iter() {
                with_data.insert(
                    component.clone(),
                    (Arc::clone(&winner.chunk), winner.component_column, true),
                );
            }
            for (timeline, per_component) in entity_index.temporal_per_timeline_per_component.iter()
            {
                for (component, component_index) in per_component.iter() {
                    let Some(entry) = component_index.chunks().next() else {
                        continue;
                    };
                    if let Some(time_type) = store.time_type(timeline) {
                        on_timelines
                            .entry(component.clone())
                            .or_default()
                            .insert(Timeline::new(Arc::clone(timeline), time_type));
                    }
                    with_data.entry(component.clone()).or_insert_with(|| {
                        (Arc::clone(&entry.chunk), entry.component_column, false)
                    });
                }
            }
            // The write buffer's chunks are in no index, with data all the same.
            for chunk in entity_index.buffered.chunks() {
                for (time_position, time_column) in chunk.time_columns().iter().enumerate() {
                    let timeline = time_column.timeline();
                    for (position, column) in chunk.components().iter().enumerate() {
                        let Ok(position) = u32::try_from(position) else {
                            continue; // (columns < 2^32, checked in Chunk::from_raw)
                        };
                        if column.bounds(time_position).is_none() {
                            continue;
                        }
                        on_timelines
                            .entry(column.name().clone())
                            .or_default()
                            .insert(timeline.clone());
                        with_data
                            .entry(column.name().clone())
                            .or_insert_with(|| (Arc::clone(chunk), position, false));
                    }
                }
            }
            for (component, (chunk, column, is_static)) in with_data {
                if !query.kept.tombstones && component.is_clear() {
                    continue;
                }
                if !query.kept.semantically_empty
                    && !holds_data(store, &entity, &component, is_static)
                {
                    continue;
                }
                if let Some(on) = on_timelines.remove(&component) {
                    timelines.extend(on);
                }
                let column = &chunk.components()[column as usize];
                let DataType::List(item_field) = column.list_array().data_type() else {
                    continue; // component columns are lists (checked at construction)
                };
                columns.push(ColumnPlan {
                    entity: entity.clone(),
                    component,
                    item_field: Arc::clone(item_field),
                    descriptor: column.descriptor().clone(),
                    is_static,
                });
            }
        }
        let index_columns: Vec<Timeline> = timelines.into_iter().collect();
        let index_position = index_columns
            .iter()
            .position(|t| *t == index)
            .unwrap_or_default();
        let schema = Arc::new(schema_of(&index_columns, &columns));
        Self {
            index,
            index_columns,
            index_position,
            columns,
            schema,
        }
    }
}

/// Does the column of `component` at `entity` hold a cell that is neither null nor an
/// empty list: its static cell, where it has static data (which the column shows on every
/// row), else any temporal cell (indexed or in the write buffer)?
fn holds_data(
    store: &StoreView,
    entity: &EntityPath,
    component: &ComponentName,
    is_static: bool,
) -> bool {
    let Some(entity_index) = store.entities.get(entity) else {
        return false;
    };
    let has_cell = |list: &arrow_array::ListArray, rows: std::ops::Range<usize>| {
        rows.into_iter()
            .any(|row| list.is_valid(row) && list.value_length(row) > 0)
    };
    if is_static {
        return entity_index
            .static_winners
            .get(component)
            .is_some_and(|winner| {
                let list = winner.chunk.components()[winner.component_column as usize].list_array();
                has_cell(list, winner.row as usize..winner.row as usize + 1)
            });
    }
    let indexed = entity_index
        .temporal_per_timeline_per_component
        .iter()
        .filter_map(|(_, per_component)| per_component.get(component))
        .flat_map(|index| index.chunks())
        .any(|entry| {
            let list = entry.chunk.components()[entry.component_column as usize].list_array();
            has_cell(list, 0..list.len())
        });
    indexed
        || entity_index.buffered.chunks().any(|chunk| {
            chunk
                .component(component.as_str())
                .is_some_and(|column| has_cell(column.list_array(), 0..column.list_array().len()))
        })
}

/// Which of a plan's columns a stream builds ([`DataframeQuery::with_columns`]).
#[derive(Clone, Debug)]
pub(crate) struct Selection {
    /// Per index column of the plan: is it in the output?
    pub index: Vec<bool>,
    /// Per data column of the plan: is it in the output?
    pub data: Vec<bool>,
    /// The output's schema: the plan's, less the columns left out.
    pub schema: SchemaRef,
}

impl TablePlan {
    /// The columns `query` keeps (all of them unless it names some).
    pub fn selection(&self, query: &DataframeQuery) -> Result<Selection, super::DataframeError> {
        let Some(names) = query.columns() else {
            return Ok(Selection {
                index: vec![true; self.index_columns.len()],
                data: vec![true; self.columns.len()],
                schema: Arc::clone(&self.schema),
            });
        };
        let wanted: std::collections::HashSet<&str> = names.iter().map(String::as_str).collect();
        let keep: Vec<bool> = self
            .schema
            .fields()
            .iter()
            .map(|field| wanted.contains(field.name().as_str()))
            .collect();
        if let Some(missing) = names
            .iter()
            .find(|name| self.schema.fields().iter().all(|f| f.name() != *name))
        {
            return Err(super::DataframeError::UnknownColumn {
                name: missing.clone(),
                num_columns: self.schema.fields().len(),
            });
        }
        let kept: Vec<usize> = (0..keep.len()).filter(|&i| keep[i]).collect();
        let schema = Arc::new(self.schema.project(&kept).map_err(super::column_error)?);
        let (index, data) = keep.split_at(self.index_columns.len());
        Ok(Selection {
            index: index.to_vec(),
            data: data.to_vec(),
            schema,
        })
    }
}

/// Index fields (named by timeline, `rerun:kind=index`), then data fields named
/// `<entity>:<component>` with the entity, component and, where the source had them,
/// archetype and component type in their metadata, as Rerun writes them.
fn schema_of(index_columns: &[Timeline], columns: &[ColumnPlan]) -> Schema {
    let mut fields: Vec<Field> = index_columns
        .iter()
        .map(|timeline| {
            Field::new(timeline.name(), timeline.time_type().to_arrow(), true).with_metadata(
                HashMap::from([
                    ("rerun:kind".to_owned(), "index".to_owned()),
                    ("rerun:index_name".to_owned(), timeline.name().to_owned()),
                ]),
            )
        })
        .collect();
    for column in columns {
        let mut metadata = HashMap::from([
            ("rerun:kind".to_owned(), "data".to_owned()),
            ("rerun:entity_path".to_owned(), column.entity.to_string()),
            ("rerun:component".to_owned(), column.component.to_string()),
        ]);
        if let Some(archetype) = &column.descriptor.archetype {
            metadata.insert("rerun:archetype".to_owned(), archetype.to_string());
        }
        if let Some(component_type) = &column.descriptor.component_type {
            metadata.insert(
                "rerun:component_type".to_owned(),
                component_type.to_string(),
            );
        }
        if column.is_static {
            metadata.insert("rerun:is_static".to_owned(), "true".to_owned());
        }
        fields.push(
            Field::new(
                format!("{}:{}", column.entity, column.component),
                DataType::List(Arc::clone(&column.item_field)),
                true,
            )
            .with_metadata(metadata),
        );
    }
    Schema::new(fields)
}
