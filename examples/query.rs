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
//! - `--compact`: run on-demand compaction once everything is loaded.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

use arrow_array::{Array, ListArray, RecordBatch};
use arrow_schema::{Field, Schema};
use chunkstore::{
    ChunkId, ChunkStore, ComponentColumn, LatestAtQuery, RangeQuery, RowId, StoreConfig, TimeInt,
};

const USAGE: &str = "usage: query [--max-rows N] [--max-rows-unsorted N] [--max-bytes N] \
                     [--compact] <DIR> latest-at <TIMELINE> <TIME> | range <TIMELINE> <MIN> \
                     <MAX> | stats";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("error: {message}");
            ExitCode::from(2)
        }
    }
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

fn parse_command(args: &[String]) -> Result<Command, String> {
    let strs: Vec<&str> = args.iter().map(String::as_str).collect();
    match strs.as_slice() {
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

/// How to load: the store's configuration, and whether to compact afterwards.
struct LoadOptions {
    config: StoreConfig,
    compact: bool,
}

/// Parses the options before `<DIR>`; returns them and the arguments left.
fn parse_options(mut args: &[String]) -> Result<(LoadOptions, &[String]), String> {
    let mut options = LoadOptions {
        config: StoreConfig::DEFAULT,
        compact: false,
    };
    while let [flag, rest @ ..] = args {
        if !flag.starts_with("--") || flag == "--help" {
            break;
        }
        if flag == "--compact" {
            options.compact = true;
            args = rest;
            continue;
        }
        let [value, rest @ ..] = rest else {
            return Err(format!("{flag} needs a value; {USAGE}"));
        };
        let number = || -> Result<u64, String> {
            value
                .parse()
                .map_err(|_| format!("{flag} {value:?} is not a non-negative integer"))
        };
        let as_usize = |n: u64| usize::try_from(n).map_err(|_| format!("{flag} {n} is too large"));
        match flag.as_str() {
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

fn run(args: &[String]) -> Result<(), String> {
    let (options, args) = parse_options(args)?;
    let [dir, rest @ ..] = args else {
        return Err(format!("missing <DIR>; {USAGE}"));
    };
    if dir == "-h" || dir == "--help" {
        println!("{USAGE}");
        return Ok(());
    }
    let command = parse_command(rest)?;
    let loaded = load(Path::new(dir), &options)?;
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    match command {
        Command::LatestAt { timeline, at } => {
            latest_at(&loaded, &LatestAtQuery::new(timeline, at), &mut out)
        }
        Command::Range { timeline, min, max } => {
            range(&loaded, &RangeQuery::new(timeline, min, max), &mut out)
        }
        Command::Stats => stats(&loaded.store, &mut out),
    }
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
    for file in chunk_files(dir)? {
        let name = file.display();
        let chunks =
            chunkstore::io::read_chunks_from_path(&file).map_err(|e| format!("{name}: {e}"))?;
        for chunk in chunks {
            for &row_id in chunk.row_ids() {
                source_chunk.entry(row_id).or_insert(chunk.id());
            }
            store.insert(chunk).map_err(|e| format!("{name}: {e}"))?;
        }
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

fn write_line(out: &mut Out<'_>, line: &str) -> Result<(), String> {
    use std::io::Write as _;
    writeln!(out, "{line}").map_err(|e| format!("stdout: {e}"))
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

fn latest_at(loaded: &Loaded, query: &LatestAtQuery, out: &mut Out<'_>) -> Result<(), String> {
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

fn range(loaded: &Loaded, query: &RangeQuery, out: &mut Out<'_>) -> Result<(), String> {
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

fn stats(store: &ChunkStore, out: &mut Out<'_>) -> Result<(), String> {
    let s = store.stats();
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
    });
    write_line(out, &line.to_string())
}
