//! `dataframe`: a dataframe view of the source (a recording's, or a dataset's with the
//! segment id first) as an Arrow IPC stream on stdout, the first rows as text on a
//! terminal, or an Arrow IPC file or a Parquet file (atomically) with `--out`.

use std::io::{IsTerminal as _, Write as _};
use std::path::Path;

use arrow_array::cast::AsArray;
use arrow_array::types::{DurationNanosecondType, Int64Type, TimestampNanosecondType};
use arrow_array::{Array, RecordBatch, RecordBatchReader};
use arrow_schema::{ArrowError, DataType, SchemaRef};
use chunkstore::dataset::Dataset;
use chunkstore::parquet::ParquetOptions;
use chunkstore::{DataframeQuery, EntityPathFilter, TimeRange, TimeType};
use indicatif::ProgressBar;

use crate::args::{DataframeArgs, TimeArg};
use crate::load::{self, Options};
use crate::source::{self, Source, refuse_to_overwrite_segment};
use crate::{Failure, output};

/// `dataframe INDEX` of `source`: a recording's table, or a dataset's (every segment's
/// table as one, the segment id first).
pub fn run(source: &Source, args: &DataframeArgs) -> Result<(), Failure> {
    // Arguments first: a bad one is named before a long load (times that are integers
    // are checked now; the others once the index's type is known).
    let asked = Asked::of(args)?;
    match source {
        Source::Recording(recording) => {
            if let Some(out) = &args.out {
                recording.refuse_to_overwrite(out)?;
            }
            of_recording(&recording.path, args, &recording.options, &asked)
        }
        Source::Dataset(dataset_source) => dataset_source.with_dataset(false, |dataset| {
            of_dataset(dataset, &dataset_source.dir, args, &asked)
        }),
    }
}

fn of_recording(
    source: &Path,
    args: &DataframeArgs,
    options: &Options,
    asked: &Asked<'_>,
) -> Result<(), Failure> {
    let loaded = load::load(source, options)?;
    let store = &loaded.store;
    let mut query = asked.query.clone();
    // The times, on the index's own type (an unknown index is named by the query below).
    if let Some(time_type) = store.time_type(&args.index) {
        query = asked.with_times(query, time_type)?;
    }
    let stream = store.dataframe(&query).map_err(|e| e.to_string())?;
    if let Some(filter) = &asked.filter {
        selects_something(filter, &store.entity_paths(), &args.contents, source)?;
    }
    let bar = Progress::over(args, store.time_range(&args.index), &query);
    write_table(stream, args, &[args.index.as_str()], &bar)
}

fn of_dataset(
    dataset: &Dataset,
    dir: &Path,
    args: &DataframeArgs,
    asked: &Asked<'_>,
) -> Result<(), Failure> {
    if let Some(out) = &args.out {
        refuse_to_overwrite_segment(dataset, out)?;
    }
    let mut query = asked.query.clone();
    if let Some(time_type) = dataset.time_type(&args.index) {
        query = asked.with_times(query, time_type)?;
    }
    if let Some(filter) = &asked.filter {
        selects_something(filter, &dataset.entity_paths(), &args.contents, dir)?;
    }
    let stream = dataset.dataframe(&query).map_err(|e| source::message(&e))?;
    let rows: u64 = dataset
        .segments()
        .iter()
        .filter(|s| s.time_type(&args.index).is_some())
        .map(|s| s.num_rows)
        .sum();
    let sorted_by = [chunkstore::SEGMENT_ID_COLUMN, args.index.as_str()];
    write_table(stream, args, &sorted_by, &Progress::rows(rows))
}

/// What the arguments of `dataframe` ask for, checked before anything is loaded.
struct Asked<'a> {
    /// The query without its times (read once the index's type is known).
    query: DataframeQuery,
    range: Option<(&'a TimeArg, &'a TimeArg)>,
    values: Option<&'a [TimeArg]>,
    /// `--contents`, parsed.
    filter: Option<EntityPathFilter>,
}

impl<'a> Asked<'a> {
    fn of(args: &'a DataframeArgs) -> Result<Self, Failure> {
        let mut query = DataframeQuery::new(args.index.as_str())
            .with_fill_latest_at(args.fill_latest_at)
            .with_tombstone_columns(!args.without_tombstones)
            .with_semantically_empty_columns(!args.without_empty_columns)
            .with_exact_index_values(args.exact);
        let range = match args.range.as_deref() {
            None => None,
            Some([min, max]) => {
                if let (Some(a), Some(b)) = (min.integer(), max.integer())
                    && a > b
                {
                    return Err(reversed(min, max));
                }
                Some((min, max))
            }
            Some(_) => return Err("--range takes two values, MIN and MAX".to_owned().into()),
        };
        if args.index_values.is_some() && args.range.is_some() {
            eprintln!("warning: --range plays no part with --index-values (one row per value)");
        }
        let mut filter = None;
        if !args.contents.is_empty() {
            let parsed = EntityPathFilter::parse(&args.contents).map_err(|e| e.to_string())?;
            query = query.with_contents(parsed.clone());
            filter = Some(parsed);
        }
        Ok(Self {
            query,
            range,
            values: args.index_values.as_deref(),
            filter,
        })
    }

    /// `query` with the range and sampled values asked for, read on the index's type.
    fn with_times(
        &self,
        query: DataframeQuery,
        time_type: TimeType,
    ) -> Result<DataframeQuery, Failure> {
        with_times(query, time_type, self.range, self.values)
    }
}

/// Writes the table where `args` says: `--out` (Parquet or Arrow IPC, atomically), a
/// terminal (the first rows as text) or a pipe (an Arrow IPC stream).
fn write_table(
    stream: impl RecordBatchReader,
    args: &DataframeArgs,
    sorted_by: &[&str],
    bar: &Progress,
) -> Result<(), Failure> {
    let index_position = stream.schema().index_of(&args.index).ok();
    let reader = WithProgress {
        inner: stream,
        bar,
        index_position,
    };
    let result = if let Some(out) = &args.out {
        // A sampled table's rows follow the values given, not the index.
        let mut options = ParquetOptions::default();
        if args.index_values.is_none() {
            for column in sorted_by {
                options = options.with_sorted_by(*column);
            }
        }
        output::write_file(out, reader, &options)
    } else if std::io::stdout().is_terminal() {
        // Binary Arrow IPC is of no use on a terminal: a person gets the first rows as
        // text, and the rest counted.
        terminal_table(reader, &bar.0)
    } else {
        let stdout = std::io::BufWriter::new(std::io::stdout().lock());
        chunkstore::ipc::write_ipc_stream(stdout, reader)
            .map(drop)
            .map_err(|e| output::stream_failure(&e))
    };
    bar.0.finish_and_clear();
    result
}

/// `--range MIN MAX` the wrong way round.
fn reversed(min: &TimeArg, max: &TimeArg) -> Failure {
    format!("--range {min} {max}: MIN is greater than MAX").into()
}

/// The query with its range and sampled values, read on the index's type.
fn with_times(
    mut query: DataframeQuery,
    time_type: TimeType,
    range: Option<(&TimeArg, &TimeArg)>,
    values: Option<&[TimeArg]>,
) -> Result<DataframeQuery, Failure> {
    if let Some((min, max)) = range {
        let (lo, hi) = (min.on(Some(time_type))?, max.on(Some(time_type))?);
        if lo > hi {
            return Err(reversed(min, max));
        }
        query = query.with_range(TimeRange::new(lo, hi));
    }
    if let Some(values) = values {
        let values = values
            .iter()
            .map(|v| v.on(Some(time_type)))
            .collect::<Result<Vec<_>, _>>()?;
        query = query.with_index_values(values);
    }
    Ok(query)
}

/// A filter that selects nothing is a mistake (a typo'd path), not an empty table.
fn selects_something(
    filter: &EntityPathFilter,
    entities: &[chunkstore::EntityPath],
    contents: &[String],
    source: &Path,
) -> Result<(), Failure> {
    if entities.iter().any(|entity| filter.matches(entity)) {
        return Ok(());
    }
    let names: Vec<String> = entities.iter().map(ToString::to_string).collect();
    Err(format!(
        "--contents {}: matches no entity of {} (its entities: {})",
        contents.join(" "),
        source.display(),
        if names.is_empty() {
            "none".to_owned()
        } else {
            names.join(", ")
        }
    )
    .into())
}

/// The first rows of the table as text on the terminal, the rest counted on stderr.
fn terminal_table(reader: impl RecordBatchReader, bar: &ProgressBar) -> Result<(), Failure> {
    let limits = crate::table::Limits::TERMINAL;
    let schema = reader.schema();
    let mut shown: Vec<RecordBatch> = Vec::new();
    let mut kept = 0;
    let mut beyond = 0;
    for batch in reader {
        let batch = batch.map_err(|e| e.to_string())?;
        if kept < limits.rows {
            kept += batch.num_rows();
            shown.push(batch);
        } else {
            beyond += batch.num_rows();
        }
    }
    bar.finish_and_clear();
    let mut stdout = std::io::BufWriter::new(std::io::stdout().lock());
    let omitted = crate::table::write(&mut stdout, &schema, &shown, limits)
        .and_then(|omitted| {
            stdout
                .flush()
                .map_err(|e| ArrowError::IoError(e.to_string(), e))?;
            Ok(omitted)
        })
        .map_err(|e| output::stream_failure(&chunkstore::ipc::IpcError::Ipc(e)))?;
    if omitted + beyond > 0 {
        eprintln!(
            "({} more rows: --out FILE writes the whole table, and a pipe gets it as an Arrow \
             IPC stream)",
            omitted + beyond
        );
    }
    Ok(())
}

/// The last value of an index column (never null: it is the row's index).
fn last_time(column: &dyn Array) -> Option<i64> {
    let values: &[i64] = match column.data_type() {
        DataType::Int64 => column.as_primitive::<Int64Type>().values(),
        DataType::Duration(_) => column.as_primitive::<DurationNanosecondType>().values(),
        DataType::Timestamp(..) => column.as_primitive::<TimestampNanosecondType>().values(),
        _ => &[],
    };
    values.last().copied()
}

/// A progress bar over the index values (or the sampled values), when stderr is a
/// terminal.
struct Progress(ProgressBar, Option<i64>);

impl Progress {
    fn new(len: u64, start: Option<i64>) -> Self {
        Self(load::progress(len, "writing", false), start)
    }

    /// Over about `rows` rows (moved by each batch's rows).
    fn rows(rows: u64) -> Self {
        Self::new(rows, None)
    }

    /// Over the sampled values, or the index's times `span` (of the data) within the
    /// query's range.
    fn over(args: &DataframeArgs, span: Option<TimeRange>, query: &DataframeQuery) -> Self {
        match (&args.index_values, span) {
            (Some(values), _) => Self::new(values.len() as u64, None),
            (None, Some(range)) => {
                let (min, max) = (
                    range.min().max(query.range().min()),
                    range.max().min(query.range().max()),
                );
                let span = max.as_i64().abs_diff(min.as_i64()).saturating_add(1);
                Self::new(span, Some(min.as_i64()))
            }
            (None, None) => Self::new(0, None),
        }
    }
}

/// The dataframe's batches, moving the bar as they pass.
struct WithProgress<'a, R> {
    inner: R,
    bar: &'a Progress,
    index_position: Option<usize>,
}

impl<R: RecordBatchReader> Iterator for WithProgress<'_, R> {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        let batch = self.inner.next()?;
        if let Ok(batch) = &batch {
            match (self.bar.1, self.index_position) {
                (Some(start), Some(position)) => {
                    if let Some(last) = last_time(batch.column(position).as_ref()) {
                        self.bar
                            .0
                            .set_position(last.abs_diff(start).saturating_add(1));
                    }
                }
                _ => self.bar.0.inc(batch.num_rows() as u64),
            }
        }
        Some(batch)
    }
}

impl<R: RecordBatchReader> RecordBatchReader for WithProgress<'_, R> {
    fn schema(&self) -> SchemaRef {
        self.inner.schema()
    }
}
