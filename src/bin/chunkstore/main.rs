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
//! chunkstore [OPTIONS] <SOURCE> hive <DIR> [--index TIMELINE [--bucket WIDTH]] [--delta [--append]]
//! chunkstore serve [SOURCE]... [--addr HOST:PORT] [--persist FILE.rrd] [--memory-limit BYTES]
//!            [--read-mode follow|snapshot] [--token TOKEN]
//! ```
//!
//! `chunkstore --help` and `chunkstore <SOURCE> <COMMAND> --help` say the rest. Answers
//! are JSON lines; bad arguments or input print one line on stderr and exit with code 2;
//! a bug (a panic) prints one line and exits with 101.

mod answers;
mod args;
mod commands;
mod load;
mod output;
mod source;
mod table;

use std::cell::RefCell;
use std::ffi::OsString;
use std::process::ExitCode;

use args::{Cli, Command};
use commands::{convert, dataframe, hive, hive_delta, latest_at, print, range, sql, stats};
use source::Source;

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
        return commands::serve::main(&args);
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
    // `chunkstore::output::remove_unfinished_outputs`.
    let _ = ctrlc::set_handler(|| {
        // An upload is aborted first (its thread then exits): no parts left in a bucket.
        if output::cancel_upload() {
            return;
        }
        chunkstore::output::remove_unfinished_outputs();
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

/// Runs the command on the SOURCE: each command answers for the kinds of source it
/// reads (`commands/`).
fn run(cli: &Cli) -> Result<(), Failure> {
    output::set_storage(cli.load.storage());
    let source = Source::of(cli)?;
    let result = run_command(cli, &source);
    if cli.verbose {
        #[cfg(feature = "object-store")]
        eprintln!(
            "object storage: {}",
            chunkstore::storage::object::counters()
        );
    }
    result
}

fn run_command(cli: &Cli, source: &Source) -> Result<(), Failure> {
    match &cli.command {
        Command::LatestAt {
            timeline,
            time,
            select,
        } => latest_at::run(source, timeline, time, select),
        Command::Range {
            timeline,
            min,
            max,
            select,
        } => range::run(source, timeline, (min, max), select),
        Command::Stats => stats::run(source),
        Command::Print { json } => print::run(source, *json),
        Command::Convert {
            out,
            application_id,
            recording_id,
        } => convert::run(source, out, application_id, recording_id.as_deref()),
        Command::Dataframe(args) => dataframe::run(source, args),
        Command::Sql(args) => sql::run(source, args),
        Command::Hive(args) if args.delta => hive_delta::run(source, args),
        Command::Hive(args) => hive::run(source, args),
    }
}
