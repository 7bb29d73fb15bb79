//! One door to a recording (feature `rrd`): open any source (an `.rrd` file, a directory of
//! Arrow IPC chunk files, one such file), lazily where its footer allows, and answer every
//! read the same way whether it was loaded or is read lazily. The CLI, the Python package
//! and SQL's front ends open sources here; a new read operation is written once, in
//! [`RecordingReader`].
//!
//! ```no_run
//! use chunkstore::recording::{OpenOptions, Recording};
//! use chunkstore::{EntityPath, LatestAtQuery, TimeInt};
//!
//! let mut recording = Recording::open("robot.rrd".as_ref(), &OpenOptions::default(), &mut ())?;
//! let mut reader = recording.reader();
//! let time_type = reader.time_type("frame_id")?; // an unknown name is an error naming the known ones
//! let robot = EntityPath::parse("/world/robot")?;
//! let at = LatestAtQuery::new("frame_id", TimeInt::new(30).unwrap());
//! let cell = reader.latest_at(&at, &robot, "Transform3D:translation")?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod error;
mod load;
mod reader;
mod source;

use std::path::{Path, PathBuf};

pub use error::{LoadFault, OpenError};
pub use load::LoadedRecording;
pub use reader::RecordingReader;
pub use source::SourceKind;

use crate::rrd::{LazyRecording, StoreInfo, StreamHeader};
use crate::storage::{Input, StorageOptions};
use crate::{ChunkId, ChunkStore, RowId, StoreConfig};

/// How to open a source.
///
/// Built from [`OpenOptions::default`] with the `with_*` methods (the struct may gain
/// fields):
/// ```
/// use chunkstore::recording::OpenOptions;
/// let options = OpenOptions::default().with_skip_bad(true).with_recording("run-7");
/// assert!(options.skip_bad && options.lazy);
/// ```
#[derive(Debug, Clone)]
#[non_exhaustive]
#[allow(
    clippy::struct_excessive_bools,
    reason = "independent switches, each a command-line flag"
)]
pub struct OpenOptions {
    /// The store's configuration when loaded (a lazy recording keeps the file's chunks).
    pub config: StoreConfig,
    /// Compact once everything is loaded.
    pub compact: bool,
    /// Skip a file, message or chunk that cannot be loaded (telling
    /// [`LoadObserver::skipped`]) and load the rest; without it the first is the error.
    /// A lazy opening cannot see every message, so it loads instead.
    pub skip_bad: bool,
    /// The recording to read, by its recording id, where the source holds several.
    pub recording: Option<String>,
    /// Open an `.rrd` with a footer lazily: discovery reads the footer, queries decode the
    /// chunks they need ([`Recording::open`]; ignored by [`LoadedRecording::load`]).
    pub lazy: bool,
    /// Keep the chunks in source order ([`LoadedRecording::in_source_order`]).
    pub keep_source_order: bool,
    /// Remember the chunk each row was loaded from ([`Recording::row_source`]): a map
    /// entry per row.
    pub track_row_sources: bool,
    /// Options of the object store a URL source names ([`crate::storage`]).
    pub storage: StorageOptions,
}

impl Default for OpenOptions {
    /// Default store configuration, lazy where possible, nothing skipped or tracked.
    fn default() -> Self {
        Self {
            config: StoreConfig::DEFAULT,
            compact: false,
            skip_bad: false,
            recording: None,
            lazy: true,
            keep_source_order: false,
            track_row_sources: false,
            storage: StorageOptions::default(),
        }
    }
}

impl OpenOptions {
    /// With the store's configuration.
    #[must_use]
    pub fn with_config(mut self, config: StoreConfig) -> Self {
        self.config = config;
        self
    }

    /// Compacting once everything is loaded, or not.
    #[must_use]
    pub fn with_compact(mut self, compact: bool) -> Self {
        self.compact = compact;
        self
    }

    /// Skipping what cannot be loaded, or not ([`OpenOptions::skip_bad`]).
    #[must_use]
    pub fn with_skip_bad(mut self, skip_bad: bool) -> Self {
        self.skip_bad = skip_bad;
        self
    }

    /// Reading the recording with this recording id.
    #[must_use]
    pub fn with_recording(mut self, recording: impl Into<String>) -> Self {
        self.recording = Some(recording.into());
        self
    }

    /// Opening an `.rrd` with a footer lazily, or not ([`OpenOptions::lazy`]).
    #[must_use]
    pub fn with_lazy(mut self, lazy: bool) -> Self {
        self.lazy = lazy;
        self
    }

    /// Keeping the chunks in source order, or not.
    #[must_use]
    pub fn with_keep_source_order(mut self, keep: bool) -> Self {
        self.keep_source_order = keep;
        self
    }

    /// Remembering the chunk each row was loaded from, or not.
    #[must_use]
    pub fn with_track_row_sources(mut self, track: bool) -> Self {
        self.track_row_sources = track;
        self
    }

    /// With the options of the object store a URL source names.
    #[must_use]
    pub fn with_storage(mut self, storage: StorageOptions) -> Self {
        self.storage = storage;
        self
    }
}

/// What a load counts its progress in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgressUnit {
    /// Bytes of an `.rrd` file.
    Bytes,
    /// Files of a directory.
    Files,
}

/// Told what a load does, for a progress bar and warnings. Every method does nothing by
/// default; `()` observes nothing.
pub trait LoadObserver {
    /// An `.rrd`'s stream header was read (which Rerun version wrote it).
    fn header(&mut self, _header: StreamHeader) {}
    /// Loading started: `total` units to go.
    fn started(&mut self, _total: u64, _unit: ProgressUnit) {}
    /// `done` units of the total are loaded.
    fn progressed(&mut self, _done: u64) {}
    /// Loading ended (successfully or not); skipped faults may still be told.
    fn finished(&mut self) {}
    /// A fault was skipped ([`OpenOptions::skip_bad`]).
    fn skipped(&mut self, _fault: &LoadFault) {}
}

impl LoadObserver for () {}

/// A recording opened from a source: loaded into a store, or an `.rrd` read lazily through
/// its footer. [`Recording::reader`] answers every read either way.
#[derive(Debug)]
pub struct Recording {
    source: PathBuf,
    kind: SourceKind,
    contents: Contents,
}

#[derive(Debug)]
enum Contents {
    Loaded(Box<LoadedRecording>),
    Lazy(Box<LazyRecording<Input>>),
}

impl Recording {
    /// Opens `path`: lazily if it is an `.rrd` with a footer and `options.lazy` (and not
    /// `skip_bad`), else loaded whole.
    ///
    /// # Errors
    /// As [`LoadedRecording::load`]; a corrupt footer is [`OpenError::Footer`] (reading
    /// without it, `lazy: false`, may work).
    pub fn open(
        path: &Path,
        options: &OpenOptions,
        observer: &mut dyn LoadObserver,
    ) -> Result<Self, OpenError> {
        let kind = SourceKind::detect(path)?;
        if kind == SourceKind::Rrd && options.lazy && !options.skip_bad {
            let input = crate::storage::open_input(path, &options.storage).map_err(|source| {
                OpenError::Io {
                    path: path.to_owned(),
                    source,
                }
            })?;
            match LazyRecording::from_reader_recording(input, options.recording.as_deref()) {
                Ok(Some(lazy)) => {
                    if let Some(header) = lazy.header() {
                        observer.header(header);
                    }
                    return Ok(Self {
                        source: path.to_owned(),
                        kind,
                        contents: Contents::Lazy(Box::new(lazy)),
                    });
                }
                Ok(None) => {}
                Err(error) if error.is_recording_choice() => {
                    return Err(OpenError::rrd(path, error));
                }
                Err(error) => {
                    return Err(OpenError::Footer {
                        path: path.to_owned(),
                        error,
                    });
                }
            }
        }
        let loaded = LoadedRecording::load_kind(path, kind, options, observer)?;
        Ok(Self {
            source: path.to_owned(),
            kind,
            contents: Contents::Loaded(Box::new(loaded)),
        })
    }

    /// The path it was opened from.
    pub fn source(&self) -> &Path {
        &self.source
    }

    /// What kind of source it was opened from.
    pub fn kind(&self) -> SourceKind {
        self.kind
    }

    /// Is it read lazily (not every chunk decoded yet)?
    pub fn is_lazy(&self) -> bool {
        matches!(self.contents, Contents::Lazy(_))
    }

    /// The recording's store info, if the source has one.
    pub fn store_info(&self) -> Option<&StoreInfo> {
        match &self.contents {
            Contents::Loaded(loaded) => loaded.store_info.as_ref(),
            Contents::Lazy(lazy) => lazy.store_info(),
        }
    }

    /// The lazy recording, while it is read lazily.
    pub fn lazy(&self) -> Option<&LazyRecording<Input>> {
        match &self.contents {
            Contents::Lazy(lazy) => Some(lazy),
            Contents::Loaded(_) => None,
        }
    }

    /// What loading learnt, once loaded.
    pub fn loaded(&self) -> Option<&LoadedRecording> {
        match &self.contents {
            Contents::Loaded(loaded) => Some(loaded),
            Contents::Lazy(_) => None,
        }
    }

    /// The reads, answered from the store or lazily.
    pub fn reader(&mut self) -> RecordingReader<'_> {
        match &mut self.contents {
            Contents::Loaded(loaded) => RecordingReader::view(&loaded.store),
            Contents::Lazy(lazy) => RecordingReader::lazy(lazy),
        }
    }

    /// The id of the chunk `row_id` was loaded from ([`OpenOptions::track_row_sources`]:
    /// compaction may have moved it); `stored` otherwise (a lazy recording keeps the
    /// file's chunks).
    pub fn row_source(&self, row_id: RowId, stored: ChunkId) -> ChunkId {
        match &self.contents {
            Contents::Loaded(loaded) => loaded.row_source(row_id, stored),
            Contents::Lazy(_) => stored,
        }
    }

    /// Decodes whatever a lazy recording has not decoded yet, in place: a chunk that fails
    /// leaves the recording lazy and usable.
    ///
    /// # Errors
    /// If a chunk cannot be read or decoded.
    pub fn load_all(&mut self) -> Result<&ChunkStore, OpenError> {
        match &mut self.contents {
            Contents::Loaded(loaded) => Ok(&loaded.store),
            Contents::Lazy(lazy) => lazy
                .load_all()
                .map_err(|error| OpenError::rrd(&self.source, error)),
        }
    }

    /// The whole recording's store (a lazy one decoded first).
    ///
    /// # Errors
    /// As [`Recording::load_all`]; the recording is gone either way.
    pub fn into_store(self) -> Result<ChunkStore, OpenError> {
        match self.contents {
            Contents::Loaded(loaded) => Ok(loaded.store),
            Contents::Lazy(lazy) => lazy
                .into_store()
                .map_err(|error| OpenError::rrd(&self.source, error)),
        }
    }
}

/// The recording a directory of chunk files names (`convert` writes it), checked against
/// the one asked for.
fn directory_store_info(dir: &Path, options: &OpenOptions) -> Result<Option<StoreInfo>, OpenError> {
    let chosen = if crate::storage::url_scheme(dir).is_some() {
        // A prefix: its store info is the object of that name under it, if there is one.
        let url = format!("{}{}", dir.display(), crate::rrd::STORE_INFO_FILE);
        match crate::storage::read_whole(Path::new(&url), &options.storage) {
            Ok(bytes) => crate::rrd::decode_directory_store_info(&bytes).map(Some),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(source) => {
                return Err(OpenError::Io {
                    path: PathBuf::from(url),
                    source,
                });
            }
        }
        .and_then(|info| {
            crate::rrd::choose_directory_recording(info.as_ref(), options.recording.as_deref())
        })
    } else {
        crate::rrd::read_directory_recording(dir, options.recording.as_deref())
    };
    chosen.map_err(|error| {
        if error.is_recording_choice() {
            OpenError::Recording {
                path: dir.to_owned(),
                error,
            }
        } else {
            OpenError::StoreInfo {
                path: dir.join(crate::rrd::STORE_INFO_FILE),
                error,
            }
        }
    })
}
