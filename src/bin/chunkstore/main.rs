//! `chunkstore`: look inside recordings from a terminal (`.rrd` files, directories of
//! Arrow IPC chunk files, and datasets: directories of `.rrd` files), query them with SQL,
//! write them as `.rrd`, Arrow or Parquet, and serve them (`serve`).
//!
//! ```text
//! chunkstore [OPTIONS] <SOURCE> latest-at <TIMELINE> <TIME> [--contents EXPR]... [--component NAME]...
//! chunkstore [OPTIONS] <SOURCE> range <TIMELINE> <MIN> <MAX> [--contents EXPR]... [--component NAME]...
//! chunkstore [OPTIONS] <SOURCE> stats
//! chunkstore [OPTIONS] <SOURCE> print [--json]
//! chunkstore [OPTIONS] <SOURCE> convert <OUT>
//! chunkstore [OPTIONS] <SOURCE> dataframe <INDEX> [--contents EXPR]... [--range MIN MAX]
//!            [--index-values V[,V...] [--exact]] [--fill-latest-at]
//!            [--without-tombstones] [--without-empty-columns] [--out FILE]
//! chunkstore [OPTIONS] <SOURCE> sql <QUERY> [--json | --out FILE | --full]
//! chunkstore [OPTIONS] <SOURCE> hive <DIR> [--index TIMELINE [--bucket WIDTH]]
//! chunkstore serve [SOURCE]... [--addr HOST:PORT] [--persist FILE.rrd] [--memory-limit BYTES]
//!            [--read-mode follow|snapshot] [--token TOKEN]
//! ```
//!
//! `chunkstore --help` and `chunkstore <SOURCE> <COMMAND> --help` say the rest. Answers
//! are JSON lines; bad arguments or input print one line on stderr and exit with code 2;
//! a bug (a panic) prints one line and exits with 101.

mod args;
mod convert;
mod dataframe;
mod dataset;
mod load;
mod output;
#[cfg(feature = "server")]
mod serve;
mod sql;
mod table;

use std::cell::RefCell;
use std::ffi::OsString;
use std::process::ExitCode;

use args::{Cli, Command};
use chunkstore::TimeRange;

thread_local! {
    /// The last panic's message and place, for the one line printed if a panic escapes.
    static LAST_PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// Why the tool stopped early.
enum Failure {
    /// Bad arguments or input: one line on stderr, exit code 2.
    Message(String),
    /// Whoever read stdout stopped reading (`| head`): not an error.
    BrokenPipe,
}

impl From<String> for Failure {
    fn from(message: String) -> Self {
        Self::Message(message)
    }
}

/// Standard input copied to a temporary file, removed when dropped (and on SIGINT or
/// SIGTERM, as every unfinished output is).
struct StdinCopy {
    file: chunkstore::UnfinishedOutput,
}

impl StdinCopy {
    fn new() -> Result<Self, String> {
        let path = std::env::temp_dir().join(format!(
            "chunkstore-stdin-{}-{:x}",
            std::process::id(),
            chunkstore::RowId::new().as_u128()
        ));
        let (file, mut out) = chunkstore::UnfinishedOutput::create(&path, |path| {
            std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(path)
        })
        .map_err(|e| format!("{}: {e}", path.display()))?;
        let copy = Self { file };
        std::io::copy(&mut std::io::stdin().lock(), &mut out)
            .map_err(|e| format!("reading standard input: {e}"))?;
        Ok(copy)
    }

    fn path(&self) -> &std::path::Path {
        self.file.path()
    }
}

impl Drop for StdinCopy {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(self.file.path());
    }
}

/// `error` about the file at `path`, naming it once: the library's I/O errors name their
/// path already.
fn about_path(path: &std::path::Path, error: impl std::fmt::Display) -> String {
    let name = path.display().to_string();
    let text = error.to_string();
    if text.starts_with(&name) {
        text
    } else {
        format!("{name}: {text}")
    }
}

/// `text` on one line: a message quoting a file's bytes or Arrow's multi-line errors must
/// not spread over several.
fn one_line(text: &str) -> String {
    text.trim_end().replace(['\n', '\r'], " ")
}

fn main() -> ExitCode {
    // The default panic hook prints every panic, even one the library contains and turns
    // into an error (arrow-ipc panics on some malformed files; see `chunkstore::ipc`): the
    // user would see two messages for one bad file. This hook prints nothing and keeps the
    // message; a panic that escapes (a bug) is reported below, on one line.
    std::panic::set_hook(Box::new(|info| {
        let message = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| (*s).to_owned())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".to_owned());
        let place = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        LAST_PANIC.with(|last| *last.borrow_mut() = Some(format!("{message}{place}")));
    }));
    let args: Vec<OsString> = std::env::args_os().collect();
    // `chunkstore serve [SOURCE...]`: a command of its own shape (any number of sources,
    // a long-running process), parsed apart from `chunkstore <SOURCE> <COMMAND>`, and
    // before the Ctrl-C handler below: the server handles its own signals (it syncs its
    // log, then stops).
    if args.get(1).is_some_and(|a| a == "serve") {
        #[cfg(feature = "server")]
        return serve::main(&args);
        #[cfg(not(feature = "server"))]
        {
            eprintln!(
                "error: this chunkstore was built without the server: build it with \
                 `cargo build --release --features server`"
            );
            return ExitCode::from(2);
        }
    }
    // Ctrl-C or SIGTERM: the temporary files and directories of outputs being written
    // are removed (the outputs themselves are untouched: they only ever appear whole),
    // then the tool exits as an interrupted program does. A SIGKILL leaves them: see
    // `chunkstore::remove_unfinished_outputs`.
    let _ = ctrlc::set_handler(|| {
        chunkstore::remove_unfinished_outputs();
        eprintln!("error: interrupted");
        std::process::exit(130);
    });
    let cli = match args::parse(&args) {
        Ok(cli) => cli,
        Err(error) => return usage_error(&error),
    };
    match std::panic::catch_unwind(|| run(&cli)) {
        Ok(Ok(()) | Err(Failure::BrokenPipe)) => ExitCode::SUCCESS,
        Ok(Err(Failure::Message(message))) => {
            eprintln!("error: {}", one_line(&message));
            ExitCode::from(2)
        }
        Err(_) => {
            let message = LAST_PANIC
                .with(|last| last.borrow_mut().take())
                .unwrap_or_default();
            eprintln!(
                "error: internal error (a bug in chunkstore): {}",
                one_line(&message)
            );
            ExitCode::from(101)
        }
    }
}

/// `--help` and `--version` print and succeed; any other argument error prints clap's
/// first line (which names the problem) and exits 2.
fn usage_error(error: &clap::Error) -> ExitCode {
    use clap::error::ErrorKind;
    if matches!(
        error.kind(),
        ErrorKind::DisplayHelp | ErrorKind::DisplayVersion
    ) {
        let _ = error.print();
        return ExitCode::SUCCESS;
    }
    if error.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
        // clap would print the whole help, whose first line (the about text) reads as the
        // error: say what is missing instead.
        eprintln!(
            "error: a SOURCE and a COMMAND are needed: chunkstore [OPTIONS] <SOURCE> <COMMAND> \
             (see --help)"
        );
        return ExitCode::from(2);
    }
    let text = error.render().to_string();
    // The error and what clap lists under it (the missing arguments), up to the usage.
    let said: Vec<&str> = text
        .lines()
        .take_while(|line| !line.trim().is_empty())
        .map(str::trim)
        .collect();
    let first = said.join(" ");
    let first = if first.is_empty() {
        "bad arguments"
    } else {
        first.as_str()
    };
    let first = first.strip_prefix("error: ").unwrap_or(first);
    eprintln!("error: {} (see --help)", one_line(first));
    ExitCode::from(2)
}

fn run(cli: &Cli) -> Result<(), Failure> {
    let config = cli.load.config()?;
    let options = load::Options {
        config,
        compact: cli.load.compact,
        skip_bad: cli.load.skip_bad,
        recording: cli.load.recording.clone(),
        ..load::Options::default()
    };
    // `-`: standard input, copied to a temporary file first (lazy reading seeks, and
    // sources are told apart by their first bytes); removed when the command ends.
    let stdin_copy = if cli.source.as_os_str() == "-" {
        Some(StdinCopy::new()?)
    } else {
        None
    };
    let source = stdin_copy
        .as_ref()
        .map_or(cli.source.as_path(), StdinCopy::path);
    if source.is_dir() && chunkstore::dataset::is_dataset_dir(source) {
        return dataset::run(cli, source, &options);
    }
    // The options only a dataset takes.
    let dataset_only = [
        cli.load
            .segment
            .as_ref()
            .map(|id| format!("--segment {id}")),
        cli.load
            .memory_budget
            .map(|bytes| format!("--memory-budget {bytes}")),
        cli.load
            .index_cache
            .as_ref()
            .map(|dir| format!("--index-cache {}", dir.display())),
    ];
    if let Some(option) = dataset_only.into_iter().flatten().next() {
        return Err(format!(
            "{option}: {} is not a dataset (a directory of .rrd files)",
            source.display()
        )
        .into());
    }
    match &cli.command {
        Command::LatestAt {
            timeline,
            time,
            select,
        } => latest_at(
            || load::open_for_queries(source, &options, cli.load.eager),
            source,
            timeline,
            time,
            select,
        ),
        Command::Range {
            timeline,
            min,
            max,
            select,
        } => range(
            || load::open_for_queries(source, &options, cli.load.eager),
            source,
            timeline,
            (min, max),
            select,
        ),
        Command::Stats => {
            let loaded = load::load(source, &options)?;
            output::stats(&loaded.store)
        }
        Command::Print { json } => output::print(source, *json, options.skip_bad),
        Command::Convert {
            out,
            application_id,
            recording_id,
        } => convert::convert(
            source,
            out,
            &options,
            application_id,
            recording_id.as_deref(),
        ),
        Command::Dataframe(args) => dataframe::dataframe(source, args, &options),
        Command::Sql(args) => sql::sql(source, args, &options),
        Command::Hive(args) => dataframe::hive(source, args, &options),
    }
}

/// `latest-at` on the recording `open` opens (`source` names it in errors).
pub(crate) fn latest_at(
    open: impl FnOnce() -> Result<chunkstore::recording::Recording, String>,
    source: &std::path::Path,
    timeline: &str,
    time: &args::TimeArg,
    select: &args::Select,
) -> Result<(), Failure> {
    let mut recording = open()?;
    let time_type = load::timeline_type(&recording.reader(), timeline, source)?;
    output::latest_at(&mut recording, timeline, time.on(time_type)?, select)
}

/// `range` on the recording `open` opens.
pub(crate) fn range(
    open: impl FnOnce() -> Result<chunkstore::recording::Recording, String>,
    source: &std::path::Path,
    timeline: &str,
    (min, max): (&args::TimeArg, &args::TimeArg),
    select: &args::Select,
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
    let time_type = load::timeline_type(&recording.reader(), timeline, source)?;
    let (lo, hi) = (min.on(time_type)?, max.on(time_type)?);
    if lo > hi {
        return Err(reversed().into());
    }
    output::range(&mut recording, timeline, TimeRange::new(lo, hi), select)
}
