//! What the server holds, recording by recording: the `recordings` SQL table, and the
//! Flight action that drops one ([`DROP_ACTION`]).

use std::collections::BTreeMap;
use std::sync::Arc;

use arrow_array::{ArrayRef, RecordBatch, StringArray, UInt64Array};
use arrow_schema::{ArrowError, DataType, Field, Schema};
use chunkstore::TimeType;
use chunkstore::hub::HubRecording;

/// The table's name in the server's SQL.
pub const TABLE: &str = "recordings";

/// The Flight `DoAction` type that drops a recording; its body is the recording id
/// (UTF-8), as `rerun_segment_id` shows it.
pub const DROP_ACTION: &str = "chunkstore.drop_recording";

/// One row per recording, in order of arrival: `rerun_segment_id` (its recording id, as
/// in every other table), `application_id`, `chunks`, `rows`, `heap_bytes`, then for each
/// timeline any recording has, by name, `{timeline}_first` and `{timeline}_last` (typed as
/// the timeline; null where the recording has no data there).
pub fn table(recordings: &[HubRecording]) -> Result<RecordBatch, ArrowError> {
    let mut timelines: BTreeMap<String, TimeType> = BTreeMap::new();
    for recording in recordings {
        for timeline in recording.snapshot.view().timelines() {
            timelines
                .entry(timeline.name().to_owned())
                .or_insert_with(|| timeline.time_type());
        }
    }
    let stats: Vec<_> = recordings.iter().map(|r| r.snapshot.stats()).collect();
    let text = |f: &dyn Fn(&HubRecording) -> String| -> ArrayRef {
        Arc::new(StringArray::from_iter_values(recordings.iter().map(f)))
    };
    let number = |values: Vec<u64>| -> ArrayRef { Arc::new(UInt64Array::from(values)) };
    let mut fields = vec![
        Field::new(chunkstore::SEGMENT_ID_COLUMN, DataType::Utf8, false),
        Field::new("application_id", DataType::Utf8, false),
        Field::new("chunks", DataType::UInt64, false),
        Field::new("rows", DataType::UInt64, false),
        Field::new("heap_bytes", DataType::UInt64, false),
    ];
    let mut columns = vec![
        text(&|r| r.info.store_id.recording_id.to_string()),
        text(&|r| r.info.store_id.application_id.to_string()),
        number(
            stats
                .iter()
                .map(|s| s.num_static_chunks + s.num_temporal_chunks)
                .collect(),
        ),
        number(
            stats
                .iter()
                .map(|s| s.num_static_rows + s.num_temporal_rows)
                .collect(),
        ),
        number(stats.iter().map(|s| s.heap_bytes).collect()),
    ];
    for (name, time_type) in &timelines {
        let ranges: Vec<_> = recordings
            .iter()
            .map(|r| r.snapshot.view().time_range(name))
            .collect();
        for (suffix, end) in [("first", false), ("last", true)] {
            let values = ranges
                .iter()
                .map(|range| range.map(|r| if end { r.max() } else { r.min() }.as_i64()))
                .collect();
            fields.push(Field::new(
                format!("{name}_{suffix}"),
                time_type.to_arrow(),
                true,
            ));
            columns.push(time_type.array(values));
        }
    }
    RecordBatch::try_new(Arc::new(Schema::new(fields)), columns)
}
