//! Loading a source: an `.rrd` file (eagerly, or lazily through its footer), a directory of
//! Arrow IPC chunk files, or one such file; told apart by content. Long loads show a
//! progress bar on stderr when it is a terminal.

use std::io::{IsTerminal as _, Read as _};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use chunkstore::rrd::{
    LazyRecording, RecordingSelector, RrdErrorKind, RrdItem, RrdReader, StoreInfo,
};
use chunkstore::{
    ChunkId, ChunkStore, ComponentName, EntityPath, LatestAtQuery, QueryCell, RangeQuery,
    RangeResult, RowId, StoreConfig, TimeType,
};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use crate::one_line;

/// How to load.
pub struct Options {
    pub config: StoreConfig,
    pub compact: bool,
    pub skip_bad: bool,
    /// `--recording ID`: the recording to read where the source holds several.
    pub recording: Option<String>,
}

/// What a source is, by its contents.
pub enum SourceKind {
    Rrd,
    IpcDirectory,
    IpcFile,
}

pub fn source_kind(source: &Path) -> Result<SourceKind, String> {
    let metadata = std::fs::metadata(source).map_err(|e| format!("{}: {e}", source.display()))?;
    if metadata.is_dir() {
        return Ok(SourceKind::IpcDirectory);
    }
    let mut head = [0u8; 8];
    let mut file = std::fs::File::open(source).map_err(|e| format!("{}: {e}", source.display()))?;
    let mut got = 0;
    while got < head.len() {
        match file.read(&mut head[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) => return Err(format!("{}: {e}", source.display())),
        }
    }
    let head = &head[..got];
    if chunkstore::rrd::looks_like_rrd(head) {
        Ok(SourceKind::Rrd)
    } else if head.starts_with(b"ARROW1") || head.starts_with(&[0xff, 0xff, 0xff, 0xff]) {
        Ok(SourceKind::IpcFile)
    } else {
        Err(format!(
            "{}: neither an .rrd file nor Arrow IPC (it starts with {:?})",
            source.display(),
            String::from_utf8_lossy(head)
        ))
    }
}

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
pub fn warn_if_newer(header: chunkstore::rrd::StreamHeader, source: &Path) {
    if header.is_newer_than_known() {
        eprintln!(
            "warning: {} was written by Rerun {}, newer than the 0.41 encoding this tool \
             knows: what it does not know is skipped",
            source.display(),
            header.version_text()
        );
    }
}

/// The store, and the chunk each row was loaded from (compaction may have moved it).
pub struct Loaded {
    pub store: ChunkStore,
    /// Kept only for the commands that print chunk ids (a map entry per row).
    pub source_chunk: ahash::HashMap<RowId, ChunkId>,
    track_sources: bool,
    /// The loaded recording's store info (of an `.rrd` source, or a directory written by
    /// `convert`).
    pub store_info: Option<StoreInfo>,
    /// Blueprint messages the source held, which were not loaded.
    pub skipped_blueprint_messages: usize,
    /// The chunks in source order, when asked for (for `convert`), each id once: a chunk
    /// the source holds twice (which the store takes once) is written once.
    pub in_order: Vec<Arc<chunkstore::Chunk>>,
    in_order_ids: ahash::HashSet<ChunkId>,
}

impl Loaded {
    /// The id of the chunk `row_id` was loaded from; `stored` if unknown.
    pub fn source_chunk(&self, row_id: RowId, stored: ChunkId) -> ChunkId {
        self.source_chunk.get(&row_id).copied().unwrap_or(stored)
    }

    fn new(config: StoreConfig, track_sources: bool) -> Result<Self, String> {
        Ok(Self {
            store: ChunkStore::with_config(config).map_err(|e| e.to_string())?,
            source_chunk: ahash::HashMap::default(),
            track_sources,
            store_info: None,
            skipped_blueprint_messages: 0,
            in_order: Vec::new(),
            in_order_ids: ahash::HashSet::default(),
        })
    }

    /// Inserts one chunk; `Err` names why the store refused it.
    fn insert(&mut self, chunk: chunkstore::Chunk, keep_order: bool) -> Result<(), String> {
        let chunk = Arc::new(chunk);
        let id = chunk.id();
        self.store
            .insert(Arc::clone(&chunk))
            .map_err(|e| e.to_string())?;
        if self.track_sources {
            for &row_id in chunk.row_ids() {
                self.source_chunk.entry(row_id).or_insert(id);
            }
        }
        if keep_order && self.in_order_ids.insert(id) {
            self.in_order.push(chunk);
        }
        Ok(())
    }
}

/// Loads the whole source into a store.
pub fn load(source: &Path, options: &Options) -> Result<Loaded, String> {
    load_with(source, options, false, false)
}

/// Loads the whole source, also keeping its chunks in source order.
pub fn load_in_order(source: &Path, options: &Options) -> Result<Loaded, String> {
    load_with(source, options, true, false)
}

fn load_with(
    source: &Path,
    options: &Options,
    keep_order: bool,
    track_sources: bool,
) -> Result<Loaded, String> {
    let mut loaded = Loaded::new(options.config, track_sources)?;
    match source_kind(source)? {
        SourceKind::Rrd => load_rrd(source, options, keep_order, &mut loaded)?,
        SourceKind::IpcDirectory => {
            loaded.store_info = directory_store_info(source, options.recording.as_deref())?;
            load_directory(source, options, keep_order, &mut loaded)?;
        }
        SourceKind::IpcFile => {
            let chunks = chunkstore::io::read_chunks_from_path(source)
                .map_err(|e| format!("{}: {e}", source.display()))?;
            for chunk in chunks {
                let id = chunk.id();
                if let Err(error) = loaded.insert(chunk, keep_order) {
                    if !options.skip_bad {
                        return Err(format!(
                            "{}: {error} (--skip-bad loads the rest)",
                            source.display()
                        ));
                    }
                    eprintln!(
                        "warning: skipped {id} of {}: {}",
                        source.display(),
                        one_line(&error)
                    );
                }
            }
        }
    }
    if options.compact {
        loaded.store.compact();
    }
    Ok(loaded)
}

fn load_rrd(
    source: &Path,
    options: &Options,
    keep_order: bool,
    loaded: &mut Loaded,
) -> Result<(), String> {
    let name = source.display();
    let file = std::fs::File::open(source).map_err(|e| format!("{name}: {e}"))?;
    let size = file.metadata().map_or(0, |m| m.len());
    let reader = RrdReader::new(std::io::BufReader::with_capacity(1 << 20, file))
        .map_err(|e| format!("{name}: {e}"))?;
    warn_if_newer(reader.header(), source);
    let bar = progress(size, "loading", true);
    // Decoding (read, LZ4, IPC, chunk validation) runs on its own thread while this one
    // inserts: two cores, about twice as fast. A bounded channel keeps a few chunks ahead.
    let (items, received) = std::sync::mpsc::sync_channel(16);
    let decoder = std::thread::spawn(move || {
        let mut reader = reader;
        while let Some(item) = reader.next() {
            if items.send((item, reader.position())).is_err() {
                break; // the loader stopped early
            }
        }
    });
    let result = insert_items(
        received,
        options,
        keep_order,
        loaded,
        &bar,
        &name.to_string(),
    );
    bar.finish_and_clear();
    if let Err(panic) = decoder.join() {
        // A bug in the decoder: reported as one, not as a short load.
        std::panic::resume_unwind(panic);
    }
    result
}

/// Inserts what the decoding thread sends, in stream order.
fn insert_items(
    received: std::sync::mpsc::Receiver<(Result<RrdItem, chunkstore::rrd::RrdError>, u64)>,
    options: &Options,
    keep_order: bool,
    loaded: &mut Loaded,
    bar: &ProgressBar,
    name: &str,
) -> Result<(), String> {
    let mut num_chunks = 0usize;
    let mut selector = RecordingSelector::new(options.recording.as_deref());
    for (item, position) in received {
        bar.set_position(position);
        match item {
            Ok(RrdItem::StoreInfo(info)) => selector.observe(&info),
            Ok(RrdItem::SkippedBlueprint { .. }) => loaded.skipped_blueprint_messages += 1,
            Ok(RrdItem::Chunk {
                chunk,
                offset,
                store_id,
            }) => {
                // Another recording's chunk is not data of this one (nor bad data).
                if !selector
                    .wants(&store_id)
                    .map_err(|kind| recording_error(name, kind))?
                {
                    continue;
                }
                let id = chunk.id();
                if let Err(error) = loaded.insert(chunk, keep_order) {
                    if !options.skip_bad {
                        return Err(format!(
                            "{name}: chunk {id} at byte {offset}: {error} (--skip-bad loads the rest)"
                        ));
                    }
                    bar.suspend(|| {
                        eprintln!(
                            "warning: skipped chunk {id} of {name} at byte {offset}: {}",
                            one_line(&error)
                        );
                    });
                }
                num_chunks += 1;
            }
            Ok(_) => {}
            Err(error) => {
                if !options.skip_bad {
                    return Err(format!("{name}: {error} (--skip-bad loads the rest)"));
                }
                let what = if error.is_fatal() {
                    "stopped reading"
                } else {
                    "skipped a message of"
                };
                bar.suspend(|| {
                    eprintln!("warning: {what} {name}: {}", one_line(&error.to_string()));
                });
            }
        }
    }
    loaded.store_info = selector
        .finish()
        .map_err(|kind| recording_error(name, kind))?;
    if num_chunks == 0 && loaded.store.num_chunks() == 0 && options.skip_bad {
        eprintln!("warning: {name} holds no chunk that could be loaded");
    }
    Ok(())
}

/// A source holding several recordings, or not the one asked for: named, with the option
/// that chooses.
fn recording_error(name: &str, kind: RrdErrorKind) -> String {
    let error = chunkstore::rrd::RrdError { offset: 0, kind };
    format!("{name}: {error} (--recording ID chooses)")
}

/// The recording a directory of chunk files names (`convert` writes it), checked against
/// `--recording`.
fn directory_store_info(dir: &Path, wanted: Option<&str>) -> Result<Option<StoreInfo>, String> {
    chunkstore::rrd::read_directory_recording(dir, wanted).map_err(|error| {
        if error.is_recording_choice() {
            recording_error(&dir.display().to_string(), error.kind)
        } else {
            format!(
                "{}: {error}",
                dir.join(chunkstore::rrd::STORE_INFO_FILE).display()
            )
        }
    })
}

fn chunk_files(dir: &Path) -> Result<Vec<PathBuf>, String> {
    let files = chunkstore::io::chunk_files(dir).map_err(|e| e.to_string())?;
    if files.is_empty() {
        return Err(format!(
            "{}: no Arrow IPC files (.{})",
            dir.display(),
            chunkstore::io::IPC_EXTENSIONS.join(", .")
        ));
    }
    Ok(files)
}

fn load_directory(
    dir: &Path,
    options: &Options,
    keep_order: bool,
    loaded: &mut Loaded,
) -> Result<(), String> {
    // With `--skip-bad`, what was skipped: printed once something loaded, else the error
    // names the first (one line either way).
    let mut skipped: Vec<String> = Vec::new();
    let mut num_loaded = 0;
    let files = chunk_files(dir)?;
    let bar = progress(files.len() as u64, "loading", false);
    for file in &files {
        bar.inc(1);
        let name = file.display();
        let chunks = match chunkstore::io::read_chunks_from_path(file) {
            Ok(chunks) => chunks,
            Err(error) if options.skip_bad => {
                skipped.push(format!("{name}: {}", one_line(&error.to_string())));
                continue;
            }
            Err(error) => return Err(format!("{name}: {error} (--skip-bad loads the rest)")),
        };
        for chunk in chunks {
            let id = chunk.id();
            match loaded.insert(chunk, keep_order) {
                Ok(()) => {}
                Err(error) if options.skip_bad => {
                    skipped.push(format!("{id} of {name}: {}", one_line(&error)));
                }
                Err(error) => return Err(format!("{name}: {error} (--skip-bad loads the rest)")),
            }
        }
        num_loaded += 1;
    }
    bar.finish_and_clear();
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
    Ok(())
}

/// What answers queries: a loaded store, or an `.rrd` opened lazily.
pub enum Answers {
    Eager(Box<Loaded>),
    Lazy(Box<LazyRecording>),
}

/// Opens the source for latest-at and range queries: lazily where it is an `.rrd` with a
/// footer (unless `eager` or `--skip-bad`, which needs to see every message), else loaded.
pub fn open_for_queries(source: &Path, options: &Options, eager: bool) -> Result<Answers, String> {
    if !eager && !options.skip_bad && matches!(source_kind(source)?, SourceKind::Rrd) {
        match LazyRecording::open_recording(source, options.recording.as_deref()) {
            Ok(Some(lazy)) => {
                warn_if_newer(lazy.header(), source);
                return Ok(Answers::Lazy(Box::new(lazy)));
            }
            Ok(None) => {}
            Err(error) => {
                if error.is_recording_choice() {
                    return Err(recording_error(&source.display().to_string(), error.kind));
                }
                return Err(format!(
                    "{}: {error} (--eager reads it without the footer)",
                    source.display()
                ));
            }
        }
    }
    load_with(source, options, false, true).map(|loaded| Answers::Eager(Box::new(loaded)))
}

impl Answers {
    pub fn entity_paths(&self) -> Vec<EntityPath> {
        match self {
            Self::Eager(loaded) => loaded.store.entity_paths(),
            Self::Lazy(lazy) => lazy.entity_paths(),
        }
    }

    pub fn component_names(&self, entity: &EntityPath) -> Vec<ComponentName> {
        match self {
            Self::Eager(loaded) => loaded.store.component_names(entity),
            Self::Lazy(lazy) => lazy.component_names(entity),
        }
    }

    pub fn latest_at(
        &mut self,
        query: &LatestAtQuery,
        entity: &EntityPath,
        component: &str,
    ) -> Result<Option<QueryCell>, String> {
        match self {
            Self::Eager(loaded) => Ok(loaded.store.latest_at(query, entity, component)),
            Self::Lazy(lazy) => lazy
                .latest_at(query, entity, component)
                .map_err(|e| e.to_string()),
        }
    }

    pub fn range(
        &mut self,
        query: &RangeQuery,
        entity: &EntityPath,
        component: &str,
    ) -> Result<RangeResult, String> {
        match self {
            Self::Eager(loaded) => Ok(loaded.store.range(query, entity, component)),
            Self::Lazy(lazy) => lazy
                .range(query, entity, component)
                .map_err(|e| e.to_string()),
        }
    }

    /// The id of the chunk `row_id` was loaded from (a lazy store keeps the file's chunks).
    pub fn source_chunk(&self, row_id: RowId, stored: ChunkId) -> ChunkId {
        match self {
            Self::Eager(loaded) => loaded.source_chunk(row_id, stored),
            Self::Lazy(_) => stored,
        }
    }

    /// The type of `timeline`, or an error if no data of the source is on it, naming the
    /// timelines it has: the rule of `dataframe`, SQL and Python too (a misspelt name must
    /// not pass for an answer of static data only).
    pub fn timeline_type(&self, timeline: &str, source: &Path) -> Result<TimeType, String> {
        let found = match self {
            Self::Eager(loaded) => loaded.store.time_type(timeline),
            Self::Lazy(lazy) => lazy
                .timelines()
                .iter()
                .find(|t| t.0.name() == timeline)
                .map(|t| t.0.time_type()),
        };
        if let Some(time_type) = found {
            return Ok(time_type);
        }
        let known: Vec<String> = match self {
            Self::Eager(loaded) => loaded
                .store
                .timelines()
                .iter()
                .map(|t| t.name().to_owned())
                .collect(),
            Self::Lazy(lazy) => lazy
                .timelines()
                .iter()
                .map(|t| t.0.name().to_owned())
                .collect(),
        };
        let error = chunkstore::DataframeError::UnknownIndex {
            timeline: timeline.to_owned(),
            known,
        };
        Err(format!("{}: {error}", source.display()))
    }
}
