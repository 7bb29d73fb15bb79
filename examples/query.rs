//! Look inside a directory of chunk files from a terminal.
//!
//! ```text
//! cargo run --release --example query -- [OPTIONS] <DIR> latest-at <TIMELINE> <TIME>
//! cargo run --release --example query -- [OPTIONS] <DIR> range <TIMELINE> <MIN> <MAX>
//! cargo run --release --example query -- [OPTIONS] <DIR> stats
//! ```
//!
//! `<DIR>` holds Arrow IPC files (file or stream format, names ending `.arrow`, `.arrows`,
//! `.ipc` or `.feather`), each with one or more chunk batches in the transport layout,
//! loaded in file-name order. Answers are JSON lines, ordered by entity path, component
//! name, then `(time, row id)`; cells are rendered by arrow's JSON writer. `chunk_id` is
//! the id of the chunk the row was loaded from (as written in the file), whatever
//! compaction made of it in the store. Bad arguments or unreadable files print one line
//! naming the problem and exit with code 2.
//!
//! Options set how the store compacts while loading (the defaults are
//! `StoreConfig::DEFAULT`'s); no answer depends on them, only `stats` shows the difference:
//! - `--max-rows N`: most rows of a time-sorted chunk;
//! - `--max-rows-unsorted N`: most rows of an unsorted chunk;
//! - `--max-bytes N`: most payload bytes of a chunk;
//! - `--compact`: run on-demand compaction once everything is loaded;
//! - `--skip-bad`: skip a file that cannot be read or a chunk the store refuses, with one
//!   line on stderr for each, and load the rest (without it, the first one is an error).
//!
//! A query naming a timeline the directory does not use, or a range whose start is after its
//! end, still answers (static data answers on every timeline, at every time) and exits 0,
//! with one warning line on stderr so that a typo does not go unnoticed. `stats` lists the
//! timelines (name, type, least and greatest time) and the entities.

use std::cell::RefCell;
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

use arrow_array::{Array, ListArray, RecordBatch};
use arrow_schema::{Field, Schema};
use chunkstore::{
    ChunkId, ChunkStore, ComponentColumn, LatestAtQuery, RangeQuery, RowId, StoreConfig, TimeInt,
    TimeRange, TimeType,
};

const USAGE: &str = "usage: query [--max-rows N] [--max-rows-unsorted N] [--max-bytes N] \
                     [--compact] [--skip-bad] <DIR> latest-at <TIMELINE> <TIME> | range \
                     <TIMELINE> <MIN> <MAX> | stats";

thread_local! {
    /// The last panic's message and place, for the one line printed if a panic escapes.
    static LAST_PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

fn main() -> ExitCode {
    // The default panic hook prints every panic, even one the library contains and turns
    // into an error (arrow-ipc panics on some malformed files; see `chunkstore::io`): the
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
    let args: Vec<OsString> = std::env::args_os().skip(1).collect();
    match std::panic::catch_unwind(|| run(&args)) {
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

/// `text` on one line: a message quoting a file's bytes or Arrow's multi-line errors must
/// not spread over several.
fn one_line(text: &str) -> String {
    text.trim_end().replace(['\n', '\r'], " ")
}

enum Command {
    LatestAt {
        timeline: String,
        at: TimeInt,
    },
    Range {
        timeline: String,
        min: TimeInt,
        max: TimeInt,
    },
    Stats,
}

fn parse_time(text: &str, what: &str) -> Result<TimeInt, String> {
    let value: i64 = text
        .parse()
        .map_err(|_| format!("{what} {text:?} is not an i64"))?;
    TimeInt::new(value)
        .ok_or_else(|| format!("{what} {value} is reserved (i64::MIN is never a valid time)"))
}

fn parse_command(args: &[&str]) -> Result<Command, String> {
    match args {
        ["latest-at", timeline, time] => Ok(Command::LatestAt {
            timeline: (*timeline).to_owned(),
            at: parse_time(time, "time")?,
        }),
        ["range", timeline, min, max] => Ok(Command::Range {
            timeline: (*timeline).to_owned(),
            min: parse_time(min, "range start")?,
            max: parse_time(max, "range end")?,
        }),
        ["stats"] => Ok(Command::Stats),
        [] => Err(format!("missing command; {USAGE}")),
        [other, ..] if !["latest-at", "range", "stats"].contains(other) => {
            Err(format!("unknown command {other:?}; {USAGE}"))
        }
        [command, ..] => Err(format!("wrong number of arguments for {command}; {USAGE}")),
    }
}

/// How to load: the store's configuration, whether to compact afterwards, and whether to
/// skip what cannot be loaded.
struct LoadOptions {
    config: StoreConfig,
    compact: bool,
    skip_bad: bool,
}

/// An argument as text: every argument but `<DIR>` must be UTF-8.
fn text(arg: &OsString, position: usize) -> Result<&str, String> {
    arg.to_str().ok_or_else(|| {
        format!(
            "argument {position} ({:?}) is not valid UTF-8",
            arg.to_string_lossy()
        )
    })
}

/// Parses the options before `<DIR>`; returns them and the arguments left.
fn parse_options(all: &[OsString]) -> Result<(LoadOptions, &[OsString]), String> {
    let mut options = LoadOptions {
        config: StoreConfig::DEFAULT,
        compact: false,
        skip_bad: false,
    };
    let mut args = all;
    while let [flag, rest @ ..] = args {
        let position = all.len() - args.len() + 1;
        let Some(flag) = flag.to_str() else {
            break; // not an option: `<DIR>`, which may be any path
        };
        if !flag.starts_with("--") || flag == "--help" {
            break;
        }
        if flag == "--compact" || flag == "--skip-bad" {
            if flag == "--compact" {
                options.compact = true;
            } else {
                options.skip_bad = true;
            }
            args = rest;
            continue;
        }
        let [value, rest @ ..] = rest else {
            return Err(format!("{flag} needs a value; {USAGE}"));
        };
        let value = text(value, position + 1)?;
        let number = || -> Result<u64, String> {
            value
                .parse()
                .map_err(|_| format!("{flag} {value:?} is not a non-negative integer"))
        };
        let as_usize = |n: u64| usize::try_from(n).map_err(|_| format!("{flag} {n} is too large"));
        match flag {
            "--max-rows" => options.config.max_rows = as_usize(number()?)?,
            "--max-rows-unsorted" => options.config.max_rows_unsorted = as_usize(number()?)?,
            "--max-bytes" => options.config.max_bytes = number()?,
            _ => return Err(format!("unknown option {flag:?}; {USAGE}")),
        }
        args = rest;
    }
    options.config.validate().map_err(|e| e.to_string())?;
    Ok((options, args))
}

fn run(args: &[OsString]) -> Result<(), Failure> {
    let (options, rest) = parse_options(args)?;
    let [dir, rest @ ..] = rest else {
        return Err(format!("missing <DIR>; {USAGE}").into());
    };
    if dir == "-h" || dir == "--help" {
        println!("{USAGE}");
        return Ok(());
    }
    let first_command_arg = args.len() - rest.len() + 1;
    let rest: Vec<&str> = rest
        .iter()
        .enumerate()
        .map(|(i, arg)| text(arg, first_command_arg + i))
        .collect::<Result<_, _>>()?;
    let command = parse_command(&rest)?;
    let dir = Path::new(dir);
    let loaded = load(dir, &options)?;
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let written = match command {
        Command::LatestAt { timeline, at } => {
            warn_if_unknown(&loaded.store, &timeline, dir);
            latest_at(&loaded, &LatestAtQuery::new(timeline, at), &mut out)
        }
        Command::Range { timeline, min, max } => {
            warn_if_unknown(&loaded.store, &timeline, dir);
            if min > max {
                eprintln!(
                    "warning: the range [{min}, {max}] is empty (its start is after its end): \
                     only static data answers"
                );
            }
            range(
                &loaded,
                &RangeQuery::new(timeline, TimeRange::new(min, max)),
                &mut out,
            )
        }
        Command::Stats => stats(&loaded.store, &mut out),
    };
    written?;
    std::io::Write::flush(&mut out).map_err(|e| stdout_failure(&e))
}

/// One warning line if no chunk of the directory uses `timeline`: the query still answers
/// (with static data only), but a misspelt name should not pass unnoticed.
fn warn_if_unknown(store: &ChunkStore, timeline: &str, dir: &Path) {
    if store.time_type(timeline).is_some() {
        return;
    }
    let known: Vec<String> = store
        .timelines()
        .iter()
        .map(|t| format!("{:?}", t.name()))
        .collect();
    let known = if known.is_empty() {
        "none".to_owned()
    } else {
        known.join(", ")
    };
    eprintln!(
        "warning: no data of {} is on timeline {timeline:?} (its timelines: {known}): only \
         static data answers",
        dir.display()
    );
}

fn chunk_files(dir: &Path) -> Result<Vec<PathBuf>, String> {
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut files = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| format!("{}: {e}", dir.display()))?.path();
        let is_ipc = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| ["arrow", "arrows", "ipc", "feather"].contains(&e));
        if is_ipc && path.is_file() {
            files.push(path);
        }
    }
    files.sort();
    if files.is_empty() {
        return Err(format!(
            "{}: no Arrow IPC files (.arrow, .arrows, .ipc, .feather)",
            dir.display()
        ));
    }
    Ok(files)
}

/// The store, and the chunk each row was loaded from (compaction may have moved it).
struct Loaded {
    store: ChunkStore,
    source_chunk: ahash::HashMap<RowId, ChunkId>,
}

impl Loaded {
    /// The id of the chunk `row_id` was loaded from; `stored` if unknown.
    fn source_chunk(&self, row_id: RowId, stored: ChunkId) -> ChunkId {
        self.source_chunk.get(&row_id).copied().unwrap_or(stored)
    }
}

fn load(dir: &Path, options: &LoadOptions) -> Result<Loaded, String> {
    let mut store = ChunkStore::with_config(options.config).map_err(|e| e.to_string())?;
    let mut source_chunk = ahash::HashMap::default();
    // With `--skip-bad`, what was skipped: printed once something loaded, else the error
    // names the first (one line either way).
    let mut skipped: Vec<String> = Vec::new();
    let mut num_loaded = 0;
    for file in chunk_files(dir)? {
        let name = file.display();
        let chunks = match chunkstore::io::read_chunks_from_path(&file) {
            Ok(chunks) => chunks,
            Err(error) if options.skip_bad => {
                skipped.push(format!("{name}: {}", one_line(&error.to_string())));
                continue;
            }
            Err(error) => return Err(format!("{name}: {error} (--skip-bad loads the rest)")),
        };
        for chunk in chunks {
            let chunk = Arc::new(chunk);
            let id = chunk.id();
            match store.insert(Arc::clone(&chunk)) {
                Ok(_) => {}
                Err(error) if options.skip_bad => {
                    skipped.push(format!("{id} of {name}: {}", one_line(&error.to_string())));
                    continue;
                }
                Err(error) => return Err(format!("{name}: {error} (--skip-bad loads the rest)")),
            }
            for &row_id in chunk.row_ids() {
                source_chunk.entry(row_id).or_insert(id);
            }
        }
        num_loaded += 1;
    }
    if num_loaded == 0 {
        return Err(format!(
            "{}: none of its files could be read (the first: {})",
            dir.display(),
            skipped.first().map_or("", String::as_str)
        ));
    }
    for what in skipped {
        eprintln!("warning: skipped {what}");
    }
    if options.compact {
        store.compact();
    }
    Ok(Loaded {
        store,
        source_chunk,
    })
}

type Out<'a> = std::io::BufWriter<std::io::StdoutLock<'a>>;

fn write_line(out: &mut Out<'_>, line: &str) -> Result<(), Failure> {
    use std::io::Write as _;
    writeln!(out, "{line}").map_err(|e| stdout_failure(&e))
}

/// A failed write to stdout: a reader that went away is no error of ours.
fn stdout_failure(error: &std::io::Error) -> Failure {
    match error.kind() {
        std::io::ErrorKind::BrokenPipe => Failure::BrokenPipe,
        _ => Failure::Message(format!("stdout: {error}")),
    }
}

/// One answer as a JSON line, keys in the documented order.
fn answer_line(
    entity: &str,
    component: &str,
    time: Option<TimeInt>,
    row_id: RowId,
    chunk_id: chunkstore::ChunkId,
    value: &str,
) -> String {
    let quote = |s: &str| serde_json::Value::from(s).to_string();
    let time = time.map_or_else(|| "null".to_owned(), |t| t.as_i64().to_string());
    format!(
        "{{\"entity\":{},\"component\":{},\"time\":{time},\"row_id\":\"{row_id}\",\"chunk_id\":\"{chunk_id}\",\"value\":{value}}}",
        quote(entity),
        quote(component)
    )
}

/// Renders one list cell with arrow's JSON writer: a one-row batch, one column.
fn render_cell(column: &ComponentColumn, row: usize) -> Result<String, String> {
    let list: ListArray = column.list_array().slice(row, 1);
    let schema = Schema::new(vec![Field::new("v", list.data_type().clone(), true)]);
    let batch =
        RecordBatch::try_new(Arc::new(schema), vec![Arc::new(list)]).map_err(|e| e.to_string())?;
    let mut buffer = Vec::new();
    let mut writer = arrow_json::LineDelimitedWriter::new(&mut buffer);
    writer.write(&batch).map_err(|e| e.to_string())?;
    writer.finish().map_err(|e| e.to_string())?;
    let text = String::from_utf8(buffer).map_err(|e| e.to_string())?;
    text.trim_end()
        .strip_prefix("{\"v\":")
        .and_then(|rest| rest.strip_suffix('}'))
        .map(str::to_owned)
        .ok_or_else(|| format!("unexpected JSON rendering {text:?}"))
}

fn latest_at(loaded: &Loaded, query: &LatestAtQuery, out: &mut Out<'_>) -> Result<(), Failure> {
    let store = &loaded.store;
    for entity in store.entity_paths() {
        let entity_text = entity.to_string();
        for component in store.component_names(&entity) {
            let Some(answer) = store.latest_at(query, &entity, component.as_str()) else {
                continue;
            };
            let value = render_cell(answer.component(), answer.row())?;
            let line = answer_line(
                &entity_text,
                component.as_str(),
                answer.time(),
                answer.row_id(),
                loaded.source_chunk(answer.row_id(), answer.chunk_id()),
                &value,
            );
            write_line(out, &line)?;
        }
    }
    Ok(())
}

fn range(loaded: &Loaded, query: &RangeQuery, out: &mut Out<'_>) -> Result<(), Failure> {
    let store = &loaded.store;
    for entity in store.entity_paths() {
        let entity_text = entity.to_string();
        for component in store.component_names(&entity) {
            for row in store.range(query, &entity, component.as_str()).iter() {
                let value = render_cell(row.column(), row.row())?;
                let line = answer_line(
                    &entity_text,
                    component.as_str(),
                    row.time(),
                    row.row_id(),
                    loaded.source_chunk(row.row_id(), row.chunk().id()),
                    &value,
                );
                write_line(out, &line)?;
            }
        }
    }
    Ok(())
}

fn stats(store: &ChunkStore, out: &mut Out<'_>) -> Result<(), Failure> {
    let s = store.stats();
    // What there is to query: each timeline with its type and the times its data spans.
    let timelines: Vec<serde_json::Value> = store
        .timelines()
        .iter()
        .map(|timeline| {
            let range = store.time_range(timeline.name());
            serde_json::json!({
                "name": timeline.name(),
                "type": match timeline.time_type() {
                    TimeType::Sequence => "sequence",
                    TimeType::DurationNs => "duration_ns",
                    TimeType::TimestampNs => "timestamp_ns",
                },
                "min": range.map(|(min, _)| min.as_i64()),
                "max": range.map(|(_, max)| max.as_i64()),
            })
        })
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
    write_line(out, &line.to_string())
}
