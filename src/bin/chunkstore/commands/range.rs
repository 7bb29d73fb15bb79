//! `range`: every value of every selected (entity, component) in `[MIN, MAX]`, one JSON
//! line each; of a recording, or of a dataset's segment (`--segment ID`).

use chunkstore::recording::Recording;
use chunkstore::{RangeQuery, TimeRange};

use crate::Failure;
use crate::answers::{answer_line, group_by_entity, render_cell, selected_pairs};
use crate::args::{Select, TimeArg};
use crate::load;
use crate::output::{flush, stdout, write_line};
use crate::source::Source;

/// `range TIMELINE MIN MAX` on `source`.
pub fn run(
    source: &Source,
    timeline: &str,
    (min, max): (&TimeArg, &TimeArg),
    select: &Select,
) -> Result<(), Failure> {
    source.with_one_recording(|open, path| answer(open, path, timeline, (min, max), select))
}

/// The answer of the recording `open` opens (`path` names it in errors).
fn answer(
    open: &dyn Fn() -> Result<Recording, String>,
    path: &std::path::Path,
    timeline: &str,
    (min, max): (&TimeArg, &TimeArg),
    select: &Select,
) -> Result<(), Failure> {
    // The same rule as `dataframe --range`, SQL and Python: a reversed range is a mistake
    // to name, not an empty answer that looks like success (named before loading where
    // the times are integers).
    let reversed = || format!("range {min} {max}: MIN is greater than MAX");
    if let (Some(a), Some(b)) = (min.integer(), max.integer())
        && a > b
    {
        return Err(reversed().into());
    }
    let mut recording = open()?;
    let time_type = load::timeline_type(&recording.reader(), timeline, path)?;
    let (lo, hi) = (min.on(time_type)?, max.on(time_type)?);
    if lo > hi {
        return Err(reversed().into());
    }
    write(&mut recording, timeline, TimeRange::new(lo, hi), select)
}

fn write(
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
