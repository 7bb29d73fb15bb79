//! The SOURCE every command reads: a recording (an `.rrd` file, a directory of Arrow IPC
//! chunk files, one such file, or `-` for standard input) or a dataset (a directory of
//! `.rrd` files, each a segment named by its recording id: `chunkstore::dataset`). Told
//! apart once, with the options only one kind takes checked here; each command then
//! answers for the kinds it reads. The one check that an output would not overwrite what
//! is read is here too.

use std::path::{Path, PathBuf};

use chunkstore::dataset::{Dataset, DatasetError, DatasetOptions};
use chunkstore::recording::Recording;

use crate::Failure;
use crate::args::Cli;
use crate::load;

/// What a command reads.
pub enum Source {
    Recording(RecordingSource),
    Dataset(DatasetSource),
}

/// A recording SOURCE, as the global options say to open it.
pub struct RecordingSource {
    /// The file or directory (for `-`, the copy of standard input).
    pub path: PathBuf,
    pub options: load::Options,
    /// `--eager`: decode the whole `.rrd` before answering.
    pub eager: bool,
    /// Standard input's copy, removed when the command ends.
    _stdin: Option<StdinCopy>,
}

/// A dataset SOURCE, not yet opened: a command checks its own arguments first.
pub struct DatasetSource {
    pub dir: PathBuf,
    options: DatasetOptions,
    /// `--segment`: the segment `latest-at` and `range` read.
    segment: Option<String>,
    /// A prefix's listing, made to tell a dataset from a chunk directory: opening the
    /// dataset does not list it again.
    #[cfg(feature = "object-store")]
    listed: Option<chunkstore::storage::object::ListedObjects>,
}

impl Source {
    /// The SOURCE the command line names, with the global options: an error for an option
    /// the source's kind does not take, or a directory holding both kinds of files.
    pub fn of(cli: &Cli) -> Result<Self, Failure> {
        let config = cli.load.config()?;
        let mut options = load::Options::default()
            .with_config(config)
            .with_compact(cli.load.compact)
            .with_skip_bad(cli.load.skip_bad)
            .with_storage(cli.load.storage());
        if let Some(recording) = &cli.load.recording {
            options = options.with_recording(recording.as_str());
        }
        // `-`: standard input, copied to a temporary file first (lazy reading seeks, and
        // sources are told apart by their first bytes); removed when the command ends.
        let stdin = if cli.source.as_os_str() == "-" {
            Some(StdinCopy::new()?)
        } else {
            None
        };
        let path = stdin
            .as_ref()
            .map_or_else(|| cli.source.clone(), |copy| copy.path().to_owned());
        // A URL ending in `/` is a prefix: a dataset of the `.rrd` objects under it, or,
        // where it holds Arrow IPC files and no `.rrd`, one recording's chunk directory.
        let listed = prefix_listing(&path, &options)?;
        let is_dataset = match &listed {
            Some(listed) => holds_a_dataset(listed),
            None => {
                chunkstore::storage::is_prefix_url(&path)
                    || (path.is_dir() && chunkstore::dataset::is_dataset_dir(&path))
            }
        };
        if is_dataset {
            return DatasetSource::of(cli, path, &options, listed).map(Self::Dataset);
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
                path.display()
            )
            .into());
        }
        Ok(Self::Recording(RecordingSource {
            path,
            options,
            eager: cli.load.eager,
            _stdin: stdin,
        }))
    }

    /// Runs `answer` on the one recording a query reads: the SOURCE (lazily where its
    /// footer allows), or a dataset's `--segment`. `answer` is given the recording's opener
    /// (so that it may check its arguments first) and the path that names it in errors.
    pub fn with_one_recording(
        &self,
        answer: impl FnOnce(&dyn Fn() -> Result<Recording, String>, &Path) -> Result<(), Failure>,
    ) -> Result<(), Failure> {
        match self {
            Self::Recording(recording) => answer(
                &|| load::open_for_queries(&recording.path, &recording.options, recording.eager),
                &recording.path,
            ),
            Self::Dataset(source) => source.with_dataset(true, |dataset| {
                let (id, path) = source.segment(dataset)?;
                answer(&|| dataset.recording(&id).map_err(|e| message(&e)), &path)
            }),
        }
    }
}

impl RecordingSource {
    /// The recording as a dataset of one segment (its recording id), opened by its
    /// footer: for the commands that write a dataset's table (`hive --delta`).
    pub fn as_dataset(&self) -> Result<DatasetSource, Failure> {
        if self.path.is_dir() || chunkstore::storage::is_prefix_url(&self.path) {
            return Err(format!(
                "{}: a directory of chunk files; a table's segments are .rrd recordings \
                 (`convert` it to one first)",
                self.path.display()
            )
            .into());
        }
        Ok(DatasetSource {
            dir: self.path.clone(),
            options: DatasetOptions::default()
                .with_config(self.options.config)
                .with_skip_bad(self.options.skip_bad)
                .with_storage(self.options.storage.clone()),
            segment: None,
            #[cfg(feature = "object-store")]
            listed: None,
        })
    }

    /// An error if writing `out` would overwrite the source.
    pub fn refuse_to_overwrite(&self, out: &Path) -> Result<(), Failure> {
        refuse_to_overwrite(out, [(self.path.as_path(), "the source".to_owned())])
    }
}

/// The listing of `path` if it is a prefix URL (one LIST), to tell what it holds.
#[cfg(feature = "object-store")]
fn prefix_listing(path: &Path, options: &load::Options) -> Result<Option<Listed>, Failure> {
    if !chunkstore::storage::is_prefix_url(path) {
        return Ok(None);
    }
    chunkstore::storage::object::list_rrd_objects(&path.to_string_lossy(), &options.storage)
        .map(Some)
        .map_err(|e| e.to_string().into())
}

#[cfg(not(feature = "object-store"))]
#[expect(
    clippy::unnecessary_wraps,
    reason = "the same signature as with the feature, where it lists"
)]
fn prefix_listing(_path: &Path, _options: &load::Options) -> Result<Option<Listed>, Failure> {
    Ok(None)
}

#[cfg(feature = "object-store")]
type Listed = chunkstore::storage::object::ListedObjects;
/// Without the feature nothing is listed.
#[cfg(not(feature = "object-store"))]
type Listed = std::convert::Infallible;

/// A prefix is a dataset unless it holds chunk files and no `.rrd` (then a recording's
/// chunk directory; holding neither, it is the dataset's error to name).
#[cfg(feature = "object-store")]
fn holds_a_dataset(listed: &Listed) -> bool {
    !listed.objects.is_empty() || listed.chunk_files.is_empty()
}

#[cfg(not(feature = "object-store"))]
#[expect(
    clippy::trivially_copy_pass_by_ref,
    reason = "by reference as with the feature; nothing is listed without it"
)]
fn holds_a_dataset(listed: &Listed) -> bool {
    match *listed {}
}

#[cfg(feature = "object-store")]
fn listed_chunk_files(listed: &Listed) -> Vec<PathBuf> {
    listed.chunk_files.iter().map(PathBuf::from).collect()
}

#[cfg(not(feature = "object-store"))]
#[expect(
    clippy::trivially_copy_pass_by_ref,
    reason = "by reference as with the feature; nothing is listed without it"
)]
fn listed_chunk_files(listed: &Listed) -> Vec<PathBuf> {
    match *listed {}
}

impl DatasetSource {
    fn of(
        cli: &Cli,
        dir: PathBuf,
        options: &load::Options,
        listed: Option<Listed>,
    ) -> Result<Self, Failure> {
        let ipc_files = match &listed {
            Some(listed) => listed_chunk_files(listed),
            None if chunkstore::storage::url_scheme(&dir).is_some() => Vec::new(),
            None => chunkstore::ipc::chunk_files(&dir).map_err(|e| e.to_string())?,
        };
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
                "--recording {recording}: a dataset's recordings are its segments (--segment \
                 ID reads one)"
            )
            .into());
        }
        let mut dataset_options = DatasetOptions::default()
            .with_config(options.config)
            .with_skip_bad(options.skip_bad)
            .with_storage(options.storage.clone());
        if let Some(dir) = &cli.load.index_cache {
            dataset_options = dataset_options.with_index_cache(dir);
        }
        if let Some(budget) = cli.load.memory_budget {
            dataset_options = dataset_options.with_memory_budget(budget);
        }
        Ok(Self {
            dir,
            options: dataset_options,
            segment: cli.load.segment.clone(),
            #[cfg(feature = "object-store")]
            listed,
        })
    }

    /// Opens the dataset (footers only) and runs `command` on it, with a warning line for
    /// each thing skipped (`--skip-bad`) before and after. Where it reads `one_segment`,
    /// what was said of the other files is summed up in one line.
    pub fn with_dataset(
        &self,
        one_segment: bool,
        command: impl FnOnce(&Dataset) -> Result<(), Failure>,
    ) -> Result<(), Failure> {
        #[cfg(feature = "object-store")]
        let opened = match &self.listed {
            Some(listed) => Dataset::open_listed(&self.dir, listed, &self.options),
            None => Dataset::open(&self.dir, &self.options),
        };
        #[cfg(not(feature = "object-store"))]
        let opened = Dataset::open(&self.dir, &self.options);
        let dataset = opened.map_err(|e| message(&e))?;
        if one_segment {
            let others = dataset.take_warnings();
            if !others.is_empty() {
                eprintln!(
                    "warning: {} warnings about other files of {} (`chunkstore {} --skip-bad \
                     stats` lists them)",
                    others.len(),
                    self.dir.display(),
                    self.dir.display()
                );
            }
        }
        warn(&dataset);
        let result = command(&dataset);
        warn(&dataset);
        result
    }

    /// The segment `--segment` names, and its file.
    pub fn segment(&self, dataset: &Dataset) -> Result<(String, PathBuf), Failure> {
        let Some(id) = &self.segment else {
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

    /// An error for a command a dataset does not answer.
    pub fn unanswered(&self) -> Failure {
        format!(
            "{}: a dataset answers dataframe, sql, stats, hive, and latest-at and range with \
             --segment ID; not this command yet",
            self.dir.display()
        )
        .into()
    }
}

/// An error if writing `out` would overwrite one of the dataset's segments.
pub fn refuse_to_overwrite_segment(dataset: &Dataset, out: &Path) -> Result<(), Failure> {
    let segments = dataset.segments().iter();
    refuse_to_overwrite(
        out,
        segments.map(|s| (s.path.as_path(), format!("segment {:?}", s.id))),
    )
}

/// The one check that an output is none of the files read (`inputs`, each with how the
/// message names it): the same file under another name counts, a new file never does.
fn refuse_to_overwrite<'a>(
    out: &Path,
    inputs: impl IntoIterator<Item = (&'a Path, String)>,
) -> Result<(), Failure> {
    if chunkstore::storage::url_scheme(out).is_some() {
        // An object is the same as another by its URL (a bucket has no links).
        for (input, name) in inputs {
            if input == out {
                return Err(format!("{}: the output would overwrite {name}", out.display()).into());
            }
        }
        return Ok(());
    }
    let Ok(written) = out.canonicalize() else {
        return Ok(());
    };
    for (input, name) in inputs {
        if input.canonicalize().is_ok_and(|read| read == written) {
            return Err(format!("{}: the output would overwrite {name}", out.display()).into());
        }
    }
    Ok(())
}

/// One warning line per thing skipped (`--skip-bad`).
fn warn(dataset: &Dataset) {
    for warning in dataset.take_warnings() {
        eprintln!("warning: {}", crate::one_line(&warning));
    }
}

/// A dataset's error as the tool words it: with the option that gets past it.
pub fn message(error: &DatasetError) -> String {
    match error {
        DatasetError::Open(_) if !error.to_string().contains("--skip-bad") => {
            format!("{error} (--skip-bad skips what cannot be read)")
        }
        _ => error.to_string(),
    }
}

/// Standard input copied to a temporary file, removed when dropped (and on SIGINT or
/// SIGTERM, as every unfinished output is).
struct StdinCopy {
    file: chunkstore::output::UnfinishedOutput,
}

impl StdinCopy {
    fn new() -> Result<Self, String> {
        let path = std::env::temp_dir().join(format!(
            "chunkstore-stdin-{}-{:x}",
            std::process::id(),
            chunkstore::RowId::new().as_u128()
        ));
        let (file, mut out) = chunkstore::output::UnfinishedOutput::create(&path, |path| {
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

    fn path(&self) -> &Path {
        self.file.path()
    }
}

impl Drop for StdinCopy {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(self.file.path());
    }
}
