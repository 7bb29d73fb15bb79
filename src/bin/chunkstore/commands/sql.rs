//! `sql`: a SQL query over the source's tables (`chunkstore::sql`), printed as a table, as
//! JSON lines, or written to an Arrow IPC or Parquet file.

use crate::Failure;
use crate::args::SqlArgs;
use crate::source::Source;

/// What `sql` says in a build without the `datafusion` feature.
#[cfg(not(feature = "datafusion"))]
pub const WITHOUT_SQL: &str = "this chunkstore was built without SQL: build it with \
                               `cargo build --release --features cli,datafusion`";

/// `sql QUERY` over `source`'s tables.
#[cfg(not(feature = "datafusion"))]
pub fn run(_source: &Source, _args: &SqlArgs) -> Result<(), Failure> {
    Err(WITHOUT_SQL.to_owned().into())
}

/// `sql QUERY` over `source`'s tables: a recording's (its snapshot's), or a dataset's
/// (with the segment id).
#[cfg(feature = "datafusion")]
pub fn run(source: &Source, args: &SqlArgs) -> Result<(), Failure> {
    let ctx = chunkstore::sql::session_context();
    match source {
        Source::Recording(recording) => {
            if let Some(out) = &args.out {
                recording.refuse_to_overwrite(out)?;
            }
            let loaded = crate::load::load(&recording.path, &recording.options)?;
            let snapshot = loaded.store.snapshot();
            chunkstore::sql::register(&ctx, &snapshot).map_err(|e| e.to_string())?;
            answer(&ctx, args)
        }
        Source::Dataset(dataset) => dataset.with_dataset(false, |dataset| {
            if let Some(out) = &args.out {
                crate::source::refuse_to_overwrite_segment(dataset, out)?;
            }
            chunkstore::sql::register_dataset(&ctx, dataset).map_err(|e| e.to_string())?;
            answer(&ctx, args)
        }),
    }
}

/// Runs the query in `ctx` and writes its answer as `args` asks. The answer streams to a
/// file or as JSON lines (a dataset's table may be far larger than memory); a table
/// printed is collected first, to size its columns.
#[cfg(feature = "datafusion")]
fn answer(ctx: &datafusion::prelude::SessionContext, args: &SqlArgs) -> Result<(), Failure> {
    use std::io::{IsTerminal as _, Write};

    use arrow_array::{RecordBatch, RecordBatchReader as _};

    let reader = chunkstore::sql::SqlReader::run(ctx, &args.query).map_err(|e| e.to_string())?;
    let schema = reader.schema();
    if let Some(out) = &args.out {
        let parquet = chunkstore::parquet::ParquetOptions::default();
        return crate::output::write_file(out, reader, &parquet);
    }
    let mut stdout = std::io::BufWriter::new(std::io::stdout().lock());
    if args.json {
        let mut writer = arrow_json::LineDelimitedWriter::new(&mut stdout);
        let mut written = Ok(());
        for batch in reader {
            if let Err(e) = batch.and_then(|batch| writer.write(&batch)) {
                written = Err(e);
                break;
            }
        }
        let written = written.and_then(|()| writer.finish());
        return finish_stdout(written, stdout);
    }
    let batches: Vec<RecordBatch> = reader.collect::<Result<_, _>>().map_err(|e| match e {
        arrow_schema::ArrowError::ExternalError(e) => e.to_string(),
        other => other.to_string(),
    })?;
    let written = if std::io::stdout().is_terminal() && !args.full {
        // A person reading: the first rows, each cell cut to a width (a wide result took
        // seconds to print whole); the rest is counted.
        crate::table::write(
            &mut stdout,
            &schema,
            &batches,
            crate::table::Limits::TERMINAL,
        )
        .map(|omitted| {
            if omitted > 0 {
                eprintln!(
                    "({omitted} more rows: --full prints every row and cell, --json or \
                         --out FILE gives them to a program)"
                );
            }
        })
    } else {
        datafusion::arrow::util::pretty::pretty_format_batches_with_schema(schema, &batches)
            .and_then(|table| {
                writeln!(stdout, "{table}")
                    .map_err(|e| arrow_schema::ArrowError::IoError(e.to_string(), e))
            })
    };
    finish_stdout(written, stdout)
}

/// Flushes what was written to stdout; a closed pipe is the reader's choice, any other
/// failure an error.
#[cfg(feature = "datafusion")]
fn finish_stdout(
    written: Result<(), arrow_schema::ArrowError>,
    mut stdout: impl std::io::Write,
) -> Result<(), Failure> {
    match written.and_then(|()| {
        stdout
            .flush()
            .map_err(|e| arrow_schema::ArrowError::IoError(e.to_string(), e))
    }) {
        Ok(()) => Ok(()),
        Err(arrow_schema::ArrowError::IoError(_, e))
            if e.kind() == std::io::ErrorKind::BrokenPipe =>
        {
            Err(Failure::BrokenPipe)
        }
        // The query failed while its rows streamed out.
        Err(arrow_schema::ArrowError::ExternalError(e)) => Err(e.to_string().into()),
        Err(e) => Err(format!("stdout: {e}").into()),
    }
}
