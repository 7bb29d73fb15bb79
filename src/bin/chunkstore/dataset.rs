//! A dataset SOURCE: a directory of `.rrd` files, each a segment named by its recording id
//! (`chunkstore::dataset`). `dataframe` streams every segment's table as one, `stats`
//! reads the footers alone, `latest-at` and `range` read one segment (`--segment ID`).

use std::path::Path;

use chunkstore::dataset::{Dataset, DatasetError, DatasetOptions};

use crate::args::{Cli, Command, DataframeArgs, HiveArgs};
use crate::dataframe::{
    Asked, Progress, hive_failure, hive_layout, selects_something, write_table,
};
use crate::load::Options;
use crate::{Failure, output};

pub fn run(cli: &Cli, dir: &Path, options: &Options) -> Result<(), Failure> {
    let ipc_files = chunkstore::ipc::chunk_files(dir).map_err(|e| e.to_string())?;
    if let Some(first) = ipc_files.first() {
        return Err(format!(
            "{}: holds both .rrd files (a dataset) and Arrow IPC chunk files ({}, one \
             recording): keep one kind in a directory",
            dir.display(),
            first.display()
        )
        .into());
    }
    if let Some(recording) = &cli.load.recording {
        return Err(format!(
            "--recording {recording}: a dataset's recordings are its segments (--segment ID \
             reads one)"
        )
        .into());
    }
    let mut dataset_options = DatasetOptions {
        config: options.config,
        skip_bad: options.skip_bad,
        index_cache: cli.load.index_cache.clone(),
        ..DatasetOptions::default()
    };
    if let Some(budget) = cli.load.memory_budget {
        dataset_options.memory_budget = budget;
    }
    // A dataframe's arguments and a new directory's path are checked before the files
    // are opened.
    let asked = match &cli.command {
        Command::Dataframe(args) => Some(Asked::of(args)?),
        Command::Hive(args) => {
            chunkstore::hive_export::check_new_dataset(&args.dir, &hive_layout(args))
                .map_err(|error| hive_failure(&args.dir, error))?;
            None
        }
        _ => None,
    };
    let dataset = Dataset::open(dir, &dataset_options).map_err(|e| message(&e))?;
    if matches!(
        cli.command,
        Command::LatestAt { .. } | Command::Range { .. }
    ) {
        // One segment is read: what was said of the others (found while looking for it)
        // is one line, not one per file.
        let others = dataset.take_warnings();
        if !others.is_empty() {
            eprintln!(
                "warning: {} warnings about other files of {} (`chunkstore {} --skip-bad stats` \
                 lists them)",
                others.len(),
                dir.display(),
                dir.display()
            );
        }
    }
    warn(&dataset);
    let result = match &cli.command {
        Command::Stats => stats(&dataset),
        Command::Dataframe(args) => match asked {
            Some(asked) => dataframe(&dataset, dir, args, &asked),
            None => Ok(()),
        },
        Command::LatestAt {
            timeline,
            time,
            select,
        } => {
            let (id, path) = segment(cli, &dataset)?;
            crate::latest_at(|| open(&dataset, &id), &path, timeline, time, select)
        }
        Command::Range {
            timeline,
            min,
            max,
            select,
        } => {
            let (id, path) = segment(cli, &dataset)?;
            crate::range(|| open(&dataset, &id), &path, timeline, (min, max), select)
        }
        Command::Sql(args) => sql(&dataset, args),
        Command::Hive(args) => hive(&dataset, args),
        Command::Print { .. } | Command::Convert { .. } => Err(format!(
            "{}: a dataset answers dataframe, sql, stats, hive, and latest-at and range \
                 with --segment ID; not this command yet",
            dir.display()
        )
        .into()),
    };
    warn(&dataset);
    result
}

#[cfg(feature = "datafusion")]
fn sql(dataset: &Dataset, args: &crate::args::SqlArgs) -> Result<(), Failure> {
    crate::sql::sql_dataset(dataset, args)
}

#[cfg(not(feature = "datafusion"))]
fn sql(_dataset: &Dataset, _args: &crate::args::SqlArgs) -> Result<(), Failure> {
    Err(crate::sql::WITHOUT_SQL.to_owned().into())
}

/// One warning line per thing skipped (`--skip-bad`).
fn warn(dataset: &Dataset) {
    for warning in dataset.take_warnings() {
        eprintln!("warning: {}", crate::one_line(&warning));
    }
}

fn message(error: &DatasetError) -> String {
    match error {
        DatasetError::Open(_) if !error.to_string().contains("--skip-bad") => {
            format!("{error} (--skip-bad skips what cannot be read)")
        }
        _ => error.to_string(),
    }
}

/// The segment `--segment` names, and its file.
fn segment(cli: &Cli, dataset: &Dataset) -> Result<(String, std::path::PathBuf), Failure> {
    let Some(id) = &cli.load.segment else {
        let ids: Vec<&str> = dataset
            .segments()
            .iter()
            .take(5)
            .map(|s| s.id.as_str())
            .collect();
        let more = if dataset.segments().len() > ids.len() {
            ", ..."
        } else {
            ""
        };
        return Err(format!(
            "a dataset's segment is read one at a time: --segment ID (one of {} segments: \
             {}{more})",
            dataset.segments().len(),
            ids.join(", ")
        )
        .into());
    };
    let segment = dataset
        .segment(id)
        .ok_or_else(|| message(&dataset.unknown_segment_error(id)))?;
    Ok((segment.id.clone(), segment.path.clone()))
}

fn open(dataset: &Dataset, id: &str) -> Result<chunkstore::recording::Recording, String> {
    dataset.recording(id).map_err(|e| message(&e))
}

/// An error if `out` is one of the dataset's segments.
pub fn refuse_to_overwrite(dataset: &Dataset, out: Option<&Path>) -> Result<(), Failure> {
    if let Some(out) = out
        && let Ok(out) = out.canonicalize()
        && let Some(segment) = dataset
            .segments()
            .iter()
            .find(|s| s.path.canonicalize().is_ok_and(|p| p == out))
    {
        return Err(format!(
            "{}: the output would overwrite segment {:?}",
            segment.path.display(),
            segment.id
        )
        .into());
    }
    Ok(())
}

fn dataframe(
    dataset: &Dataset,
    dir: &Path,
    args: &DataframeArgs,
    asked: &Asked<'_>,
) -> Result<(), Failure> {
    refuse_to_overwrite(dataset, args.out.as_deref())?;
    let mut query = asked.query.clone();
    if let Some(time_type) = dataset.time_type(&args.index) {
        query = asked.with_times(query, time_type)?;
    }
    if let Some(filter) = &asked.filter {
        selects_something(filter, &dataset.entity_paths(), &args.contents, dir)?;
    }
    let stream = dataset.dataframe(&query).map_err(|e| message(&e))?;
    let rows: u64 = dataset
        .segments()
        .iter()
        .filter(|s| s.time_type(&args.index).is_some())
        .map(|s| s.num_rows)
        .sum();
    let sorted_by = [chunkstore::SEGMENT_ID_COLUMN, args.index.as_str()];
    write_table(stream, args, &sorted_by, &Progress::rows(rows))
}

/// `hive`: the dataset as one Hive-partitioned Parquet dataset, a partition per segment
/// (and in it per entity, or per time bucket), a bar over the segments written.
fn hive(dataset: &Dataset, args: &HiveArgs) -> Result<(), Failure> {
    let bar = crate::load::progress(dataset.segments().len() as u64, "writing", false);
    let summary = dataset
        .write_hive(&args.dir, &hive_layout(args), &|_, _| bar.inc(1))
        .map_err(|error| match error {
            DatasetError::Hive(error) => hive_failure(&args.dir, error),
            other => message(&other).into(),
        });
    bar.finish_and_clear();
    let summary = summary?;
    let segments: std::collections::BTreeSet<&std::path::Path> = summary
        .files
        .iter()
        .filter_map(|(file, _)| file.parent()?.parent())
        .collect();
    eprintln!(
        "wrote {} rows in {} files of {} segments under {}",
        summary.rows(),
        summary.files.len(),
        segments.len(),
        args.dir.display()
    );
    Ok(())
}

/// One JSON line: the dataset's totals and timelines, and each segment from its footer.
fn stats(dataset: &Dataset) -> Result<(), Failure> {
    let timeline_json = |timeline: &chunkstore::Timeline, range: Option<chunkstore::TimeRange>| {
        serde_json::json!({
            "name": timeline.name(),
            "type": output::type_name(timeline.time_type()),
            "min": range.map(|r| r.min().as_i64()),
            "max": range.map(|r| r.max().as_i64()),
        })
    };
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
    let mut out = output::stdout();
    output::write_line(&mut out, &line.to_string())?;
    output::flush(&mut out)
}
