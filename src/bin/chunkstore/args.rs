//! The tool's arguments (clap), apart from everything else so that the `cli_args` fuzz
//! target can parse arbitrary argument lists with exactly this code: nothing here may
//! panic, whatever the arguments.

use std::ffi::OsString;
use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

use chunkstore::{StoreConfig, TimeInt, TimeType};

const EXAMPLES: &str = "\
Examples:
  chunkstore recording.rrd latest-at frame_id 30
  chunkstore recording.rrd range sim_time 0s 1.5s
  chunkstore recording.rrd latest-at log_time 2026-11-21T12:55:49Z
  chunkstore chunks/ stats
  chunkstore recording.rrd print --json
  chunkstore --compact recording.rrd convert optimized.rrd
  chunkstore recording.rrd dataframe frame_id --fill-latest-at --out robot.parquet
  chunkstore recording.rrd sql 'SELECT count(*) FROM frame_id WHERE frame_id < 100'
  chunkstore episodes/ dataframe frame_id --out episodes.parquet
  chunkstore --segment episode_17 episodes/ latest-at frame_id 30";

/// Look inside recordings: latest-at and range queries, statistics, a chunk listing,
/// conversion between `.rrd` files and directories of Arrow IPC chunk files, and
/// dataframes as Arrow IPC or Parquet.
#[derive(Parser, Debug)]
#[command(name = "chunkstore", version, after_help = EXAMPLES)]
pub struct Cli {
    #[command(flatten)]
    pub load: LoadArgs,

    /// Say on stderr, when the command ends, what it asked of object storage (requests and
    /// bytes).
    #[arg(long, short = 'v', global = true)]
    pub verbose: bool,

    /// An `.rrd` file, a directory of Arrow IPC chunk files, or one such file (told apart
    /// by their contents, not their names); `-` reads either kind of file from standard
    /// input. A directory of `.rrd` files is a dataset: each file a segment, named by its
    /// recording id (`dataframe`, `stats`, `sql`, `hive`, and `latest-at` and `range` with
    /// `--segment`). In object storage: `s3://bucket/run.rrd` (also `gs://`, `az://`,
    /// `abfs://`, `https://`), and a prefix ending in `/` is a dataset
    /// (`s3://bucket/episodes/`).
    pub source: PathBuf,

    #[command(subcommand)]
    pub command: Command,
}

/// How to load the source. The compaction options change how the store chunks the data,
/// never an answer (only `stats` shows the difference); defaults are `StoreConfig::DEFAULT`.
#[derive(Args, Debug)]
#[command(next_help_heading = "Global options (before or after the command)")]
pub struct LoadArgs {
    /// Most rows of a time-sorted chunk.
    #[arg(long, global = true, value_name = "N", allow_hyphen_values = true, value_parser = parse_count::<usize>)]
    pub max_rows: Option<usize>,
    /// Most rows of an unsorted chunk.
    #[arg(long, global = true, value_name = "N", allow_hyphen_values = true, value_parser = parse_count::<usize>)]
    pub max_rows_unsorted: Option<usize>,
    /// Most payload bytes of a chunk.
    #[arg(long, global = true, value_name = "N", allow_hyphen_values = true, value_parser = parse_count::<u64>)]
    pub max_bytes: Option<u64>,
    /// Run on-demand compaction once everything is loaded (`convert`: what `rerun rrd
    /// optimize` does).
    #[arg(long, global = true)]
    pub compact: bool,
    /// Skip a file, message or chunk that cannot be read, with one line on stderr for
    /// each, and load the rest (without it, the first one is an error).
    #[arg(long, global = true)]
    pub skip_bad: bool,
    /// The recording to read, by its recording id, where the source holds several (streams
    /// concatenated, or one stream with several recordings); without it, such a source is
    /// an error naming them.
    #[arg(long, global = true, value_name = "ID")]
    pub recording: Option<String>,
    /// Of a dataset SOURCE (a directory of `.rrd` files, each a segment named by its
    /// recording id): the segment `latest-at` and `range` read.
    #[arg(long, global = true, value_name = "ID")]
    pub segment: Option<String>,
    /// Of a dataset SOURCE: keep the index of each `.rrd` without a footer in DIR (made if
    /// missing), so that the next run reads the index instead of the whole file, and
    /// queries read the file in part. Never written beside the data.
    #[arg(long, global = true, value_name = "DIR")]
    pub index_cache: Option<std::path::PathBuf>,
    /// Of a dataset SOURCE: bytes of loaded segments kept between uses (e.g. 512MiB,
    /// 2GB; least recently used out first). By default a quarter of the machine's memory.
    #[arg(long, global = true, value_name = "BYTES", value_parser = parse_bytes)]
    pub memory_budget: Option<u64>,
    /// Decode a whole `.rrd` before answering, even where its footer would let a query
    /// decode only the chunks it needs.
    #[arg(long, global = true)]
    pub eager: bool,
    /// An option of the object store a URL SOURCE or output is in (`aws_endpoint=URL`,
    /// `aws_region=…`, `aws_allow_http=true`, `google_service_account=FILE`,
    /// `azure_storage_account_name=…`), on top of the environment's `AWS_*`, `GOOGLE_*`
    /// and `AZURE_*`; repeatable.
    #[arg(long = "storage-option", global = true, value_name = "KEY=VALUE", value_parser = parse_storage_option)]
    pub storage_options: Vec<(String, String)>,
}

fn parse_storage_option(text: &str) -> Result<(String, String), String> {
    chunkstore::storage::StorageOptions::parse_pair(text)
}

impl LoadArgs {
    /// The `--storage-option`s.
    pub fn storage(&self) -> chunkstore::storage::StorageOptions {
        self.storage_options.iter().cloned().collect()
    }

    pub fn config(&self) -> Result<StoreConfig, String> {
        let mut config = StoreConfig::DEFAULT;
        if let Some(n) = self.max_rows {
            config = config.with_max_rows(n);
        }
        if let Some(n) = self.max_rows_unsorted {
            config = config.with_max_rows_unsorted(n);
        }
        if let Some(n) = self.max_bytes {
            config = config.with_max_bytes(n);
        }
        config.validate().map_err(|e| e.to_string())?;
        Ok(config)
    }
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// The latest value of every entity and component at a time, one JSON line each.
    #[command(
        after_help = "Example:\n  chunkstore recording.rrd latest-at frame_id 30",
        allow_negative_numbers = true
    )]
    LatestAt {
        /// The timeline.
        timeline: String,
        /// The time: an integer (nanoseconds on duration and timestamp timelines), a
        /// duration such as `1.5s`, or a timestamp such as `2026-11-21T12:55:49Z`.
        #[arg(value_parser = parse_time)]
        time: TimeArg,
        #[command(flatten)]
        select: Select,
    },
    /// Every value of every entity and component in `[MIN, MAX]`, one JSON line each.
    #[command(
        after_help = "Example:\n  chunkstore recording.rrd range frame_id 10 20",
        allow_negative_numbers = true
    )]
    Range {
        /// The timeline.
        timeline: String,
        /// The range's start (included), written as `latest-at`'s TIME.
        #[arg(value_parser = parse_time)]
        min: TimeArg,
        /// The range's end (included).
        #[arg(value_parser = parse_time)]
        max: TimeArg,
        #[command(flatten)]
        select: Select,
    },
    /// The store's statistics, timelines and entities, as one JSON line.
    #[command(after_help = "Example:\n  chunkstore recording.rrd stats")]
    Stats,
    /// One line per chunk, in source order: id, entity, rows, timelines with their
    /// least and greatest time, components.
    #[command(after_help = "Example:\n  chunkstore recording.rrd print --json | head")]
    Print {
        /// JSON lines instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Write the source as an `.rrd` file (OUT ends in `.rrd`) or as a directory of Arrow
    /// IPC chunk files (any other OUT), atomically: OUT appears whole or not at all.
    /// Chunks are written as loaded (in source order), or compacted with `--compact`.
    #[command(
        after_help = "Examples:\n  chunkstore chunks/ convert recording.rrd\n  \
                            chunkstore --compact recording.rrd convert optimized.rrd\n  \
                            chunkstore recording.rrd convert chunks/"
    )]
    Convert {
        /// Where to write.
        out: PathBuf,
        /// The application id of what is written from chunk files that name no recording
        /// (an `.rrd`, or a directory `convert` wrote, keeps its own store info).
        #[arg(long, default_value = "chunkstore")]
        application_id: String,
        /// The recording id of what is written from chunk files that name no recording
        /// (default: the source's name).
        #[arg(long)]
        recording_id: Option<String>,
    },
    /// A table on one timeline: a row per time, a column per entity and component (Rerun's
    /// dataframe view), as an Arrow IPC stream on stdout, or a file with `--out`.
    #[command(after_help = DATAFRAME_EXAMPLES, allow_negative_numbers = true)]
    Dataframe(DataframeArgs),
    /// A SQL query (DataFusion's dialect) over the source's tables: one per timeline,
    /// named after it (its dataframe view: index columns, then `"<entity>:<component>"`
    /// list columns), and `chunks` (every stored row across entities); and the table
    /// function `latest_at('<timeline>', <time>)`. Prints a table, JSON lines with
    /// `--json`, or writes a file with `--out`. Needs a build with the `datafusion`
    /// feature.
    #[command(after_help = SQL_EXAMPLES)]
    Sql(SqlArgs),
    /// Write a partitioned Parquet dataset in Hive layout to the new directory DIR, which
    /// DuckDB, Polars, Spark, pyarrow and DataFusion-based engines read as one table: the
    /// raw chunk table by entity (`entity=<path>/part-0.parquet`), or with `--bucket` a
    /// timeline's dataframe view by buckets of index values
    /// (`<timeline>_bucket=<k>/part-0.parquet`). DIR appears whole or not at all.
    #[command(after_help = HIVE_EXAMPLES)]
    Hive(HiveArgs),
}

const HIVE_EXAMPLES: &str = "\
Examples:
  chunkstore recording.rrd hive by_entity/ --index frame_id
  chunkstore recording.rrd hive by_second/ --index log_time --bucket 1000000000
  chunkstore episodes/ hive episodes_hive/ --index frame --bucket 100   (a partition per segment)
  chunkstore s3://bucket/episodes/ hive s3://bucket/tables/episodes/ --delta
  chunkstore new_episode.rrd hive s3://bucket/tables/episodes/ --delta --append
  duckdb -c \"SELECT entity, count(*) FROM read_parquet('by_entity/**/*.parquet', \\
      hive_partitioning = true) GROUP BY entity\"";

/// The arguments of `hive`.
#[derive(Args, Debug)]
pub struct HiveArgs {
    /// The directory to create (with `--delta`, also a URL: `s3://bucket/prefix/`).
    pub dir: PathBuf,
    /// The timeline: rows in its order within each entity's file, or the timeline whose
    /// index values `--bucket` groups.
    #[arg(long, value_name = "TIMELINE")]
    pub index: Option<String>,
    /// Partition a dataframe view on `--index` by buckets of this many index values (in
    /// nanoseconds on duration and timestamp timelines) instead of the chunk table by
    /// entity.
    #[arg(long, value_name = "WIDTH", requires = "index")]
    pub bucket: Option<i64>,
    /// Write a Delta Lake table: the copy, partitioned by segment first (a recording is a
    /// segment), with a `_delta_log/` that Spark, DuckDB, Polars and deltalake read as one
    /// table. Committed at once, locally or in a bucket.
    #[arg(long)]
    pub delta: bool,
    /// Add the source's segments to the existing Delta table DIR, as one commit (a segment
    /// it holds already is refused).
    #[arg(long, requires = "delta")]
    pub append: bool,
}

const SQL_EXAMPLES: &str = "\
Examples:
  chunkstore recording.rrd sql 'SHOW TABLES'
  chunkstore recording.rrd sql 'SELECT frame_id, \"/robot/arm:joint_torque\" FROM frame_id \\
      WHERE frame_id BETWEEN 100 AND 200 LIMIT 5'
  chunkstore recording.rrd sql \"SELECT entity_path, count(*) FROM chunks \\
      WHERE entity_path LIKE '/robot/%' GROUP BY entity_path\" --json
  chunkstore recording.rrd sql \"SELECT * FROM latest_at('frame_id', 42)\" --out answer.parquet";

/// The arguments of `sql`.
#[derive(Args, Debug)]
pub struct SqlArgs {
    /// The query.
    pub query: String,
    /// One JSON object per result row instead of a table.
    #[arg(long, conflicts_with = "out")]
    pub json: bool,
    /// On a terminal, print every row and whole cells (by default a terminal gets the
    /// first 40 rows, each cell cut to 40 characters; a pipe or file always gets all).
    #[arg(long, conflicts_with_all = ["out", "json"])]
    pub full: bool,
    /// Write the result as an Arrow IPC file (or Parquet, for a name ending `.parquet`)
    /// instead of printing it.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

const DATAFRAME_EXAMPLES: &str = "\
Examples:
  chunkstore recording.rrd dataframe frame_id --out table.arrow
  chunkstore recording.rrd dataframe sim_time --contents '/world/**' --contents '-/world/map/**' \\
      --range 0 2000000000 --fill-latest-at --out table.parquet
  chunkstore recording.rrd dataframe frame_id --index-values 0,10,20 | python3 -c \\
      'import pyarrow.ipc, sys; print(pyarrow.ipc.open_stream(sys.stdin.buffer).read_all())'";

/// Which (entity, component) pairs `latest-at` and `range` answer for (by default every
/// one the source has).
#[derive(Args, Debug, Clone, Default)]
pub struct Select {
    /// Only these entities: `/a/b` (exactly), `/a/**` (and its subtree), `-/a/**`
    /// (exclude), as `dataframe --contents`; repeat it for several rules.
    #[arg(long, value_name = "EXPR", allow_hyphen_values = true)]
    pub contents: Vec<String>,
    /// Only this component (e.g. `Transform3D:translation`); repeat it for several.
    #[arg(long, value_name = "NAME")]
    pub component: Vec<String>,
}

/// The arguments of `dataframe`.
#[derive(Args, Debug)]
#[allow(
    clippy::struct_excessive_bools,
    reason = "each is a command-line flag of its own"
)]
pub struct DataframeArgs {
    /// The index timeline: one row per distinct time on it.
    pub index: String,
    /// Which entities: `/a/b` (exactly), `/a/**` (and its subtree), `-/a/**` (exclude);
    /// repeat it for several rules (the most specific one wins). Default: every entity
    /// but `/__properties`.
    #[arg(long, value_name = "EXPR", allow_hyphen_values = true)]
    pub contents: Vec<String>,
    /// Only rows whose index lies in `[MIN, MAX]` (both included).
    #[arg(long, num_args = 2, value_names = ["MIN", "MAX"], value_parser = parse_time,
          allow_hyphen_values = true)]
    pub range: Option<Vec<TimeArg>>,
    /// One row per value, in the order given, each cell the latest-at value there.
    #[arg(long, value_name = "V[,V...]", value_delimiter = ',', value_parser = parse_time,
          allow_hyphen_values = true)]
    pub index_values: Option<Vec<TimeArg>>,
    /// Fill each empty cell with the latest value at or before its row's time.
    #[arg(long)]
    pub fill_latest_at: bool,
    /// With --index-values: each row shows only what was logged (or cleared) at exactly
    /// that value, as Rerun's reader does without fill, instead of the latest-at answer.
    #[arg(long, requires = "index_values")]
    pub exact: bool,
    /// Leave out the `Clear:is_recursive` (tombstone) columns, as Rerun's reader does by
    /// default.
    #[arg(long)]
    pub without_tombstones: bool,
    /// Leave out the columns whose every cell is null or empty, as Rerun's reader does by
    /// default.
    #[arg(long)]
    pub without_empty_columns: bool,
    /// Write an Arrow IPC file (or Parquet, for a name ending `.parquet`) instead of an
    /// IPC stream on stdout.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

/// A count (rows, bytes): a whole number, not negative, said so when it is.
fn parse_count<T: std::str::FromStr>(text: &str) -> Result<T, String> {
    if text.starts_with('-') {
        return Err(format!("{text} is negative: a count is 0 or more"));
    }
    text.parse()
        .map_err(|_| format!("{text:?} is not a whole number"))
}

/// A time as written on the command line: checked now to be a time of some timeline, and
/// read on the timeline's own type once the source is open (`1.5s` only on a duration
/// timeline, a date only on a timestamp one).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TimeArg(pub String);

impl TimeArg {
    /// The time on a timeline of `time_type`; on one of no type (a source without
    /// temporal data, where any time answers the same), in the first form it reads in.
    pub fn on(&self, time_type: Option<TimeType>) -> Result<TimeInt, String> {
        let Some(time_type) = time_type else {
            return TIME_TYPES
                .iter()
                .find_map(|kind| kind.parse_time(&self.0).ok())
                .ok_or_else(|| format!("{:?} is not a time", self.0));
        };
        time_type.parse_time(&self.0).map_err(|e| e.to_string())
    }

    /// The time, where it is an integer (which means the same on every timeline).
    pub fn integer(&self) -> Option<TimeInt> {
        TimeType::Sequence.parse_time(&self.0).ok()
    }
}

impl std::fmt::Display for TimeArg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// Every type of time, in the order a time of no known type is read in.
const TIME_TYPES: [TimeType; 3] = [
    TimeType::Sequence,
    TimeType::DurationNs,
    TimeType::TimestampNs,
];

fn parse_time(text: &str) -> Result<TimeArg, String> {
    if text.trim().parse::<i64>() == Ok(i64::MIN) {
        return Err(format!(
            "{text} is reserved (i64::MIN is never a valid time)"
        ));
    }
    if TIME_TYPES.iter().any(|kind| kind.parse_time(text).is_ok()) {
        return Ok(TimeArg(text.to_owned()));
    }
    Err(format!(
        "{text:?} is not a time: an integer, a duration such as 1.5s, or a timestamp such as \
         2026-11-21T12:55:49Z"
    ))
}

/// Parses the arguments (the first is the program's name).
///
/// # Errors
/// clap's error: usage problems, and `--help` / `--version` (which are not failures).
pub fn parse(args: &[OsString]) -> Result<Cli, clap::Error> {
    Cli::try_parse_from(args)
}

/// Parses a byte count: an integer, optionally followed by B, KB, MB, GB, TB (powers of
/// 1000) or KiB, MiB, GiB, TiB (powers of 1024).
pub fn parse_bytes(text: &str) -> Result<u64, String> {
    let text = text.trim();
    let split = text
        .find(|c: char| !c.is_ascii_digit())
        .unwrap_or(text.len());
    let (number, unit) = text.split_at(split);
    let number: u64 = number
        .parse()
        .map_err(|_| format!("{text:?} is not a byte count (such as 512MiB or 2GB)"))?;
    let scale: u64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1,
        "kb" => 1_000,
        "mb" => 1_000_000,
        "gb" => 1_000_000_000,
        "tb" => 1_000_000_000_000,
        "kib" => 1 << 10,
        "mib" => 1 << 20,
        "gib" => 1 << 30,
        "tib" => 1 << 40,
        other => {
            return Err(format!(
                "{other:?} is not a byte unit (B, KB, MB, GB, TB, KiB, MiB, GiB, TiB)"
            ));
        }
    };
    number
        .checked_mul(scale)
        .ok_or_else(|| format!("{text:?} is too large"))
}
