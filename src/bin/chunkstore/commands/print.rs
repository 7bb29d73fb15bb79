//! `print`: one line per chunk of a recording, in source order, as text or JSON; read as
//! a stream, nothing stored.

use std::path::Path;

use chunkstore::Chunk;
use chunkstore::recording::SourceKind;
use chunkstore::rrd::{RrdItem, RrdReader};

use crate::output::{flush, stdout, timeline_json, write_line};
use crate::source::Source;
use crate::{Failure, load, one_line};

/// `print` of `source` (a recording: a dataset has no one source order).
pub fn run(source: &Source, json: bool) -> Result<(), Failure> {
    match source {
        Source::Recording(recording) => print(&recording.path, json, &recording.options),
        Source::Dataset(dataset) => Err(dataset.unanswered()),
    }
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
            .map(|c| timeline_json(c.timeline(), Some(c.time_range())))
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
fn print(source: &Path, json: bool, options: &load::Options) -> Result<(), Failure> {
    let mut out = stdout();
    let name = source.display();
    let skip_bad = options.skip_bad;
    match SourceKind::detect(source).map_err(|e| e.to_string())? {
        SourceKind::Rrd => {
            // A file, or an object streamed in one GET.
            let (input, _) = chunkstore::storage::open_stream(source, &options.storage)
                .map_err(|e| chunkstore::storage::io_error_text(source, &e))?;
            let reader = RrdReader::new(std::io::BufReader::with_capacity(1 << 20, input))
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
            let options = load::Options::default()
                .with_config(chunkstore::StoreConfig::COMPACTION_OFF)
                .with_skip_bad(skip_bad)
                .with_storage(options.storage.clone());
            let loaded = load::load_in_order(source, &options)?;
            for chunk in &loaded.in_source_order {
                write_line(&mut out, &chunk_line(chunk, json))?;
            }
        }
    }
    flush(&mut out)
}
