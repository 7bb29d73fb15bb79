//! `latest-at`: the latest value of every selected (entity, component) at a time, one
//! JSON line each; of a recording, or of a dataset's segment (`--segment ID`).

use chunkstore::recording::Recording;
use chunkstore::{LatestAtQuery, TimeInt};

use crate::Failure;
use crate::answers::{answer_line, group_by_entity, render_cell, selected_pairs};
use crate::args::{Select, TimeArg};
use crate::load;
use crate::output::{flush, stdout, write_line};
use crate::source::Source;

/// `latest-at TIMELINE TIME` on `source`.
pub fn run(
    source: &Source,
    timeline: &str,
    time: &TimeArg,
    select: &Select,
) -> Result<(), Failure> {
    source.with_one_recording(|open, path| answer(open, path, timeline, time, select))
}

/// The answer of the recording `open` opens (`path` names it in errors).
fn answer(
    open: &dyn Fn() -> Result<Recording, String>,
    path: &std::path::Path,
    timeline: &str,
    time: &TimeArg,
    select: &Select,
) -> Result<(), Failure> {
    let mut recording = open()?;
    let time_type = load::timeline_type(&recording.reader(), timeline, path)?;
    write(&mut recording, timeline, time.on(time_type)?, select)
}

fn write(
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
