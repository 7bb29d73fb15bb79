//! Opening a source through the library's one door (`chunkstore::recording`), with a
//! progress bar on stderr when it is a terminal, one warning line per fault skipped, and
//! each error with the option that would get past it.

use std::io::IsTerminal as _;
use std::path::Path;

use chunkstore::TimeType;
use chunkstore::recording::{
    LoadFault, LoadObserver, LoadedRecording, OpenError, OpenOptions, ProgressUnit, Recording,
    RecordingReader,
};
use chunkstore::rrd::StreamHeader;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// How to load: the library's options, filled in from the global arguments.
pub type Options = OpenOptions;

/// A progress bar on stderr if it is a terminal, hidden otherwise.
pub fn progress(len: u64, what: &str, bytes: bool) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
    let template = if bytes {
        "{msg} [{bar:40}] {bytes}/{total_bytes} ({bytes_per_sec}, {eta})"
    } else {
        "{msg} [{bar:40}] {pos}/{len} ({eta})"
    };
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_message(what.to_owned());
    bar
}

/// One warning line for an `.rrd` written by a Rerun newer than the encoding this tool
/// knows: it is read (unknown fields are skipped), but data may be missed.
pub fn warn_if_newer(header: StreamHeader, source: &Path) {
    if header.is_newer_than_known() {
        eprintln!(
            "warning: {} was written by Rerun {}, newer than the 0.41 encoding this tool \
             knows: what it does not know is skipped",
            source.display(),
            header.version_text()
        );
    }
}

/// What the terminal is told while a source loads.
struct Terminal<'a> {
    source: &'a Path,
    bar: ProgressBar,
}

impl<'a> Terminal<'a> {
    fn new(source: &'a Path) -> Self {
        Self {
            source,
            bar: ProgressBar::hidden(),
        }
    }
}

impl LoadObserver for Terminal<'_> {
    fn header(&mut self, header: StreamHeader) {
        warn_if_newer(header, self.source);
    }

    fn started(&mut self, total: u64, unit: ProgressUnit) {
        self.bar = progress(total, "loading", unit == ProgressUnit::Bytes);
    }

    fn progressed(&mut self, done: u64) {
        self.bar.set_position(done);
    }

    fn finished(&mut self) {
        self.bar.finish_and_clear();
    }

    fn skipped(&mut self, fault: &LoadFault) {
        self.bar.suspend(|| eprintln!("warning: {fault}"));
    }
}

/// The error as one message, with the option that gets past it.
fn message(error: &OpenError) -> String {
    if error.is_recording_choice() {
        format!("{error} (--recording ID chooses)")
    } else if error.is_skippable() {
        format!("{error} (--skip-bad loads the rest)")
    } else if matches!(error, OpenError::Footer { .. }) {
        format!("{error} (--eager reads it without the footer)")
    } else {
        error.to_string()
    }
}

/// Loads the whole source into a store.
pub fn load(source: &Path, options: &Options) -> Result<LoadedRecording, String> {
    LoadedRecording::load(source, options, &mut Terminal::new(source)).map_err(|e| message(&e))
}

/// Loads the whole source, also keeping its chunks in source order.
pub fn load_in_order(source: &Path, options: &Options) -> Result<LoadedRecording, String> {
    load(source, &options.clone().with_keep_source_order(true))
}

/// Opens the source for latest-at and range queries: lazily where it is an `.rrd` with a
/// footer (unless `eager` or `--skip-bad`, which needs to see every message), else loaded,
/// remembering each row's chunk of the source.
pub fn open_for_queries(
    source: &Path,
    options: &Options,
    eager: bool,
) -> Result<Recording, String> {
    let options = options
        .clone()
        .with_lazy(!eager)
        .with_track_row_sources(true);
    Recording::open(source, &options, &mut Terminal::new(source)).map_err(|e| message(&e))
}

/// The type of `timeline`, or an error naming the timelines the source has: the rule of
/// `dataframe`, SQL and Python too (a misspelt name must not pass for an answer of static
/// data only). A source without temporal data answers on any timeline (`None`: a time
/// of any form).
pub fn timeline_type(
    reader: &RecordingReader<'_>,
    timeline: &str,
    source: &Path,
) -> Result<Option<TimeType>, String> {
    match reader.time_type(timeline) {
        Ok(time_type) => Ok(Some(time_type)),
        Err(error) if error.known.is_empty() => Ok(None),
        Err(error) => Err(format!("{}: {error}", source.display())),
    }
}
