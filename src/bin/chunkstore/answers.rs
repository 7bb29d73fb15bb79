//! Latest-at and range answers as JSON lines, one per (entity, component, row), keys in a
//! fixed order: the (entity, component) pairs a selection keeps, and each cell rendered by
//! Arrow's JSON writer.

use std::sync::Arc;

use arrow_array::{Array, ListArray, RecordBatch};
use arrow_schema::{Field, Schema};
use chunkstore::recording::RecordingReader;
use chunkstore::{ComponentColumn, ComponentName, EntityPath, EntityPathFilter, RowId, TimeInt};

use crate::Failure;
use crate::args::Select;

fn quote(s: &str) -> String {
    serde_json::Value::from(s).to_string()
}

/// One answer as a JSON line, keys in the documented order.
pub fn answer_line(
    entity: &str,
    component: &str,
    time: Option<TimeInt>,
    row_id: RowId,
    chunk_id: chunkstore::ChunkId,
    value: &str,
) -> String {
    let time = time.map_or_else(|| "null".to_owned(), |t| t.as_i64().to_string());
    format!(
        "{{\"entity\":{},\"component\":{},\"time\":{time},\"row_id\":\"{row_id}\",\"chunk_id\":\"{chunk_id}\",\"value\":{value}}}",
        quote(entity),
        quote(component)
    )
}

/// Renders one list cell with arrow's JSON writer: a one-row batch, one column.
pub fn render_cell(column: &ComponentColumn, row: usize) -> Result<String, String> {
    let list: ListArray = column.list_array().slice(row, 1);
    let schema = Schema::new(vec![Field::new("v", list.data_type().clone(), true)]);
    let batch =
        RecordBatch::try_new(Arc::new(schema), vec![Arc::new(list)]).map_err(|e| e.to_string())?;
    let mut buffer = Vec::new();
    let mut writer = arrow_json::LineDelimitedWriter::new(&mut buffer);
    writer.write(&batch).map_err(|e| e.to_string())?;
    writer.finish().map_err(|e| e.to_string())?;
    let text = String::from_utf8(buffer).map_err(|e| e.to_string())?;
    text.trim_end()
        .strip_prefix("{\"v\":")
        .and_then(|rest| rest.strip_suffix('}'))
        .map(str::to_owned)
        .ok_or_else(|| format!("unexpected JSON rendering {text:?}"))
}

/// The (entity, component) pairs `select` keeps, in answer order (entity path, then
/// component name); an error where a selection was given and keeps nothing (a typo must
/// not pass for an empty answer).
pub fn selected_pairs(
    answers: &RecordingReader<'_>,
    select: &Select,
) -> Result<Vec<(EntityPath, ComponentName)>, Failure> {
    let filter = if select.contents.is_empty() {
        None
    } else {
        Some(EntityPathFilter::parse(&select.contents).map_err(|e| e.to_string())?)
    };
    let mut pairs = Vec::new();
    for entity in answers.entity_paths() {
        if filter.as_ref().is_some_and(|f| !f.matches(&entity)) {
            continue;
        }
        for component in answers.component_names(&entity) {
            if select.component.is_empty()
                || select.component.iter().any(|c| c == component.as_str())
            {
                pairs.push((entity.clone(), component));
            }
        }
    }
    if pairs.is_empty() && (filter.is_some() || !select.component.is_empty()) {
        let what: Vec<String> = select
            .contents
            .iter()
            .map(|c| format!("--contents {c}"))
            .chain(select.component.iter().map(|c| format!("--component {c}")))
            .collect();
        return Err(format!(
            "{}: selects no (entity, component) of the source (`stats` lists its entities)",
            what.join(" ")
        )
        .into());
    }
    Ok(pairs)
}

/// `pairs` (sorted by entity) as runs of one entity and its components.
pub fn group_by_entity(
    pairs: &[(EntityPath, ComponentName)],
) -> Vec<(&EntityPath, Vec<&ComponentName>)> {
    let mut groups: Vec<(&EntityPath, Vec<&ComponentName>)> = Vec::new();
    for (entity, component) in pairs {
        match groups.last_mut() {
            Some((last, components)) if *last == entity => components.push(component),
            _ => groups.push((entity, vec![component])),
        }
    }
    groups
}
