//! What the commands print: latest-at and range answers and stats as JSON lines (keys in a
//! fixed order), and the chunk listing of `print`.

use std::io::Write as _;
use std::path::Path;
use std::sync::Arc;

use arrow_array::{Array, ListArray, RecordBatch};
use arrow_schema::{Field, Schema};
use chunkstore::recording::{Recording, RecordingReader, SourceKind};
use chunkstore::rrd::{RrdItem, RrdReader};
use chunkstore::{
    Chunk, ChunkStore, ComponentColumn, ComponentName, EntityPath, EntityPathFilter, LatestAtQuery,
    RangeQuery, RowId, TimeInt, TimeRange, TimeType,
};

use crate::args::Select;
use crate::load;
use crate::{Failure, one_line};

pub(crate) type Out<'a> = std::io::BufWriter<std::io::StdoutLock<'a>>;

pub(crate) fn stdout() -> Out<'static> {
    std::io::BufWriter::new(std::io::stdout().lock())
}

pub(crate) fn write_line(out: &mut Out<'_>, line: &str) -> Result<(), Failure> {
    writeln!(out, "{line}").map_err(|e| stdout_failure(&e))
}

pub(crate) fn flush(out: &mut Out<'_>) -> Result<(), Failure> {
    out.flush().map_err(|e| stdout_failure(&e))
}

/// A failed write to stdout: a reader that went away is no error of ours.
fn stdout_failure(error: &std::io::Error) -> Failure {
    match error.kind() {
        std::io::ErrorKind::BrokenPipe => Failure::BrokenPipe,
        _ => Failure::Message(format!("stdout: {error}")),
    }
}

fn quote(s: &str) -> String {
    serde_json::Value::from(s).to_string()
}

/// One answer as a JSON line, keys in the documented order.
fn answer_line(
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
fn render_cell(column: &ComponentColumn, row: usize) -> Result<String, String> {
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

pub fn latest_at(
    recording: &mut Recording,
    timeline: &str,
    at: TimeInt,
    select: &Select,
) -> Result<(), Failure> {
    let query = LatestAtQuery::new(timeline, at);
    let mut out = stdout();
    let pairs = selected_pairs(&recording.reader(), select)?;
    for (entity, components) in group_by_entity(&pairs) {
        let entity_text = entity.to_string();
        for component in components {
            let answer = recording
                .reader()
                .latest_at(&query, entity, component.as_str())
                .map_err(|e| e.to_string())?;
            let Some(answer) = answer else {
                continue;
            };
            let value = render_cell(answer.column(), answer.row())?;
            let line = answer_line(
                &entity_text,
                component.as_str(),
                answer.time(),
                answer.row_id(),
                recording.row_source(answer.row_id(), answer.chunk_id()),
                &value,
            );
            write_line(&mut out, &line)?;
        }
    }
    flush(&mut out)
}

/// `pairs` (sorted by entity) as runs of one entity and its components.
fn group_by_entity(
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

pub fn range(
    recording: &mut Recording,
    timeline: &str,
    range: TimeRange,
    select: &Select,
) -> Result<(), Failure> {
    let query = RangeQuery::new(timeline, range);
    let mut out = stdout();
    let pairs = selected_pairs(&recording.reader(), select)?;
    for (entity, components) in group_by_entity(&pairs) {
        let entity_text = entity.to_string();
        for component in components {
            let rows = recording
                .reader()
                .range(&query, entity, component.as_str())
                .map_err(|e| e.to_string())?;
            for row in rows.iter() {
                let value = render_cell(row.column(), row.row())?;
                let line = answer_line(
                    &entity_text,
                    component.as_str(),
                    row.time(),
                    row.row_id(),
                    recording.row_source(row.row_id(), row.chunk().id()),
                    &value,
                );
                write_line(&mut out, &line)?;
            }
        }
    }
    flush(&mut out)
}

pub(crate) fn type_name(time_type: TimeType) -> &'static str {
    match time_type {
        TimeType::Sequence => "sequence",
        TimeType::DurationNs => "duration_ns",
        TimeType::TimestampNs => "timestamp_ns",
    }
}

pub fn stats(store: &ChunkStore) -> Result<(), Failure> {
    let s = store.stats();
    // What there is to query: each timeline with its type and the times its data spans.
    let timelines: Vec<serde_json::Value> = store
        .timelines()
        .iter()
        .map(|timeline| {
            let range = store.time_range(timeline.name());
            serde_json::json!({
                "name": timeline.name(),
                "type": type_name(timeline.time_type()),
                "min": range.map(|r| r.min().as_i64()),
                "max": range.map(|r| r.max().as_i64()),
            })
        })
        .collect();
    let entities: Vec<String> = store
        .entity_paths()
        .iter()
        .map(ToString::to_string)
        .collect();
    let line = serde_json::json!({
        "num_chunks": s.num_chunks(),
        "num_static_chunks": s.num_static_chunks,
        "num_temporal_chunks": s.num_temporal_chunks,
        "num_rows": s.num_rows(),
        "num_static_rows": s.num_static_rows,
        "num_temporal_rows": s.num_temporal_rows,
        "heap_bytes": s.heap_bytes,
        "static_heap_bytes": s.static_heap_bytes,
        "temporal_heap_bytes": s.temporal_heap_bytes,
        "num_entities": store.entity_paths().len(),
        "timelines": timelines,
        "entities": entities,
    });
    let mut out = stdout();
    write_line(&mut out, &line.to_string())?;
    flush(&mut out)
}

/// One chunk's line: text or JSON.
fn chunk_line(chunk: &Chunk, json: bool) -> String {
    let components: Vec<&str> = chunk
        .components()
        .iter()
        .map(|c| c.name().as_str())
        .collect();
    if json {
        let timelines: Vec<serde_json::Value> = chunk
            .time_columns()
            .iter()
            .map(|c| {
                let bounds = c.time_range();
                let (min, max) = (bounds.min(), bounds.max());
                serde_json::json!({
                    "name": c.timeline().name(),
                    "type": type_name(c.timeline().time_type()),
                    "min": min.as_i64(),
                    "max": max.as_i64(),
                })
            })
            .collect();
        return serde_json::json!({
            "chunk_id": chunk.id().to_string(),
            "entity": chunk.entity_path().to_string(),
            "rows": chunk.num_rows(),
            "static": chunk.is_static(),
            "timelines": timelines,
            "components": components,
        })
        .to_string();
    }
    let times: Vec<String> = chunk
        .time_columns()
        .iter()
        .map(|c| {
            let bounds = c.time_range();
            let (min, max) = (bounds.min(), bounds.max());
            format!(
                "{}=[{}, {}]",
                c.timeline().name(),
                min.as_i64(),
                max.as_i64()
            )
        })
        .collect();
    let times = if times.is_empty() {
        "static".to_owned()
    } else {
        times.join(" ")
    };
    format!(
        "{} {} rows={} {times} components={}",
        chunk.id(),
        chunk.entity_path(),
        chunk.num_rows(),
        components.join(",")
    )
}

/// Lists the source's chunks in source order, streaming (nothing is stored).
pub fn print(source: &Path, json: bool, skip_bad: bool) -> Result<(), Failure> {
    let mut out = stdout();
    let name = source.display();
    match SourceKind::detect(source).map_err(|e| e.to_string())? {
        SourceKind::Rrd => {
            let file = std::fs::File::open(source).map_err(|e| format!("{name}: {e}"))?;
            let reader = RrdReader::new(std::io::BufReader::with_capacity(1 << 20, file))
                .map_err(|e| format!("{name}: {e}"))?;
            load::warn_if_newer(reader.header(), source);
            for item in reader {
                match item {
                    Ok(RrdItem::Chunk { chunk, .. }) => {
                        write_line(&mut out, &chunk_line(&chunk, json))?;
                    }
                    Ok(_) => {}
                    Err(error) if skip_bad => {
                        flush(&mut out)?;
                        eprintln!("warning: {name}: {}", one_line(&error.to_string()));
                    }
                    Err(error) => {
                        flush(&mut out)?;
                        return Err(format!("{name}: {error} (--skip-bad prints the rest)").into());
                    }
                }
            }
        }
        SourceKind::ChunkDirectory | SourceKind::IpcFile => {
            let options = load::Options {
                config: chunkstore::StoreConfig::COMPACTION_OFF,
                skip_bad,
                ..load::Options::default()
            };
            let loaded = load::load_in_order(source, &options)?;
            for chunk in &loaded.in_source_order {
                write_line(&mut out, &chunk_line(chunk, json))?;
            }
        }
    }
    flush(&mut out)
}
