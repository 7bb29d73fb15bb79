//! `stats`: one JSON line of what a source holds: its store's statistics, timelines with
//! their spans, and entities; of a dataset, its totals and each segment, from the footers.

use chunkstore::ChunkStore;
use chunkstore::dataset::Dataset;

use crate::Failure;
use crate::load;
use crate::output::{flush, stdout, timeline_json, write_line};
use crate::source::Source;

/// `stats` of `source`.
pub fn run(source: &Source) -> Result<(), Failure> {
    match source {
        Source::Recording(recording) => {
            let loaded = load::load(&recording.path, &recording.options)?;
            store_stats(&loaded.store)
        }
        Source::Dataset(dataset) => dataset.with_dataset(false, dataset_stats),
    }
}

fn store_stats(store: &ChunkStore) -> Result<(), Failure> {
    let s = store.stats();
    // What there is to query: each timeline with its type and the times its data spans.
    let timelines: Vec<serde_json::Value> = store
        .timelines()
        .iter()
        .map(|timeline| timeline_json(timeline, store.time_range(timeline.name())))
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

/// One JSON line: the dataset's totals and timelines, and each segment from its footer.
fn dataset_stats(dataset: &Dataset) -> Result<(), Failure> {
    let segments: Vec<serde_json::Value> = dataset
        .segments()
        .iter()
        .map(|s| {
            serde_json::json!({
                "id": s.id,
                "application_id": s.application_id,
                "path": s.path.display().to_string(),
                "num_chunks": s.num_chunks,
                "num_static_chunks": s.num_static_chunks,
                "num_rows": s.num_rows,
                "file_bytes": s.file_bytes,
                "from_footer": s.from_footer,
                "index_file": s.index_file.as_ref().map(|p| p.display().to_string()),
                "num_entities": s.entities.len(),
                "timelines": s.timelines.iter().map(|(t, r)| timeline_json(t, Some(*r))).collect::<Vec<_>>(),
            })
        })
        .collect();
    let all = dataset.segments();
    let line = serde_json::json!({
        "num_segments": all.len(),
        "num_chunks": all.iter().map(|s| s.num_chunks).sum::<u64>(),
        "num_static_chunks": all.iter().map(|s| s.num_static_chunks).sum::<u64>(),
        "num_rows": all.iter().map(|s| s.num_rows).sum::<u64>(),
        "file_bytes": all.iter().map(|s| s.file_bytes).sum::<u64>(),
        "num_entities": dataset.entity_paths().len(),
        "timelines": dataset
            .timelines()
            .iter()
            .map(|t| timeline_json(t, dataset.time_range(t.name())))
            .collect::<Vec<_>>(),
        "entities": dataset.entity_paths().iter().map(ToString::to_string).collect::<Vec<_>>(),
        "segments": segments,
    });
    let mut out = stdout();
    write_line(&mut out, &line.to_string())?;
    flush(&mut out)
}
