//! Loading a whole source into a store: an `.rrd` decoded on a second thread while this one
//! inserts, a directory file by file, a single chunk file. Faults are skipped or returned as
//! [`OpenOptions::skip_bad`] says; progress and skipped faults go to a [`LoadObserver`].

use std::path::Path;
use std::sync::Arc;

use super::error::{LoadFault, OpenError};
use super::{LoadObserver, OpenOptions, ProgressUnit, SourceKind};
use crate::rrd::{RecordingSelector, RrdError, RrdItem, RrdReader, StoreInfo, StreamHeader};
use crate::{Chunk, ChunkId, ChunkStore, RowId};

/// A source loaded whole into a store, with what the loading learnt about it.
#[derive(Debug)]
pub struct LoadedRecording {
    /// The store holding every chunk (compacted if asked).
    pub store: ChunkStore,
    /// The recording's store info (of an `.rrd`, or a directory written by `convert`).
    pub store_info: Option<StoreInfo>,
    /// The `.rrd`'s stream header, for an `.rrd`.
    pub header: Option<StreamHeader>,
    /// Blueprint messages the source held, which were not loaded.
    pub skipped_blueprint_messages: usize,
    /// With [`OpenOptions::keep_source_order`]: the chunks in source order, each id once (a
    /// chunk the source holds twice, which the store takes once, is listed once).
    pub in_source_order: Vec<Arc<Chunk>>,
    /// With [`OpenOptions::track_row_sources`]: the chunk each row was loaded from.
    row_sources: ahash::HashMap<RowId, ChunkId>,
    in_source_order_ids: ahash::HashSet<ChunkId>,
    options: OpenOptions,
}

impl LoadedRecording {
    /// Loads the whole source at `path` (of any [`SourceKind`]).
    ///
    /// # Errors
    /// The first fault (without `skip_bad`), a source that cannot be read at all, or one
    /// holding several recordings where none was chosen.
    pub fn load(
        path: &Path,
        options: &OpenOptions,
        observer: &mut dyn LoadObserver,
    ) -> Result<Self, OpenError> {
        Self::load_kind(path, SourceKind::detect(path)?, options, observer)
    }

    pub(super) fn load_kind(
        path: &Path,
        kind: SourceKind,
        options: &OpenOptions,
        observer: &mut dyn LoadObserver,
    ) -> Result<Self, OpenError> {
        let mut loaded = Self {
            store: ChunkStore::with_config(options.config).map_err(OpenError::Config)?,
            store_info: None,
            header: None,
            skipped_blueprint_messages: 0,
            in_source_order: Vec::new(),
            row_sources: ahash::HashMap::default(),
            in_source_order_ids: ahash::HashSet::default(),
            options: options.clone(),
        };
        match kind {
            SourceKind::Rrd => loaded.load_rrd(path, observer)?,
            SourceKind::ChunkDirectory => {
                loaded.store_info = super::directory_store_info(path, options)?;
                loaded.load_directory(path, observer)?;
            }
            SourceKind::IpcFile => {
                let bytes =
                    crate::storage::read_whole(path, &options.storage).map_err(|source| {
                        OpenError::Io {
                            path: path.to_owned(),
                            source,
                        }
                    })?;
                let chunks =
                    crate::ipc::read_chunks_from_bytes(&bytes).map_err(|error| OpenError::Ipc {
                        path: path.to_owned(),
                        error,
                    })?;
                for chunk in chunks {
                    if let Some(fault) = loaded.insert_or_skip(chunk, path, None)? {
                        observer.skipped(&fault);
                    }
                }
            }
        }
        if options.compact {
            // Group by group, dropping each group's events: `compact()` would hold every
            // replaced chunk in its events until the end, the old and new copies of the
            // whole store at once.
            loaded.store.compact_group_by_group(drop);
        }
        Ok(loaded)
    }

    /// The id of the chunk `row_id` was loaded from, where rows were tracked
    /// ([`OpenOptions::track_row_sources`]: compaction may have moved it); `stored`
    /// otherwise.
    pub fn row_source(&self, row_id: RowId, stored: ChunkId) -> ChunkId {
        self.row_sources.get(&row_id).copied().unwrap_or(stored)
    }

    /// Inserts `chunk`; a refusal is the error, or with `skip_bad` the fault skipped.
    fn insert_or_skip(
        &mut self,
        chunk: Chunk,
        path: &Path,
        offset: Option<u64>,
    ) -> Result<Option<LoadFault>, OpenError> {
        let chunk = Arc::new(chunk);
        let id = chunk.id();
        if let Err(error) = self.store.insert(Arc::clone(&chunk)) {
            let fault = LoadFault::Chunk {
                path: path.to_owned(),
                id,
                offset,
                error,
            };
            return self.skip(fault).map(Some);
        }
        if self.options.track_row_sources {
            for &row_id in chunk.row_ids() {
                self.row_sources.entry(row_id).or_insert(id);
            }
        }
        if self.options.keep_source_order && self.in_source_order_ids.insert(id) {
            self.in_source_order.push(chunk);
        }
        Ok(None)
    }

    /// `fault` as the error, or with `skip_bad` back to be told.
    fn skip(&self, fault: LoadFault) -> Result<LoadFault, OpenError> {
        if self.options.skip_bad {
            Ok(fault)
        } else {
            Err(OpenError::Fault(Box::new(fault)))
        }
    }

    fn load_rrd(&mut self, path: &Path, observer: &mut dyn LoadObserver) -> Result<(), OpenError> {
        let io = |source| OpenError::Io {
            path: path.to_owned(),
            source,
        };
        let (file, size) = crate::storage::open_stream(path, &self.options.storage).map_err(io)?;
        let reader = RrdReader::new(std::io::BufReader::with_capacity(1 << 20, file))
            .map_err(|error| OpenError::rrd(path, error))?;
        self.header = Some(reader.header());
        observer.header(reader.header());
        observer.started(size, ProgressUnit::Bytes);
        // Decoding (read, LZ4, IPC, chunk validation) runs on its own thread while this
        // one inserts: two cores, about twice as fast. A bounded channel keeps a few chunks
        // ahead.
        let (items, received) = std::sync::mpsc::sync_channel(16);
        let decoder = std::thread::spawn(move || {
            let mut reader = reader;
            while let Some(item) = reader.next() {
                if items.send((item, reader.position())).is_err() {
                    break; // the loader stopped early
                }
            }
        });
        let result = self.insert_items(&received, path, observer);
        drop(received);
        if result.is_ok() {
            observer.progressed(size); // the footer, after the last item
        }
        observer.finished();
        if let Err(panic) = decoder.join() {
            // A bug in the decoder: reported as one, not as a short load.
            std::panic::resume_unwind(panic);
        }
        result
    }

    /// Inserts what the decoding thread sends, in stream order.
    fn insert_items(
        &mut self,
        received: &std::sync::mpsc::Receiver<(Result<RrdItem, RrdError>, u64)>,
        path: &Path,
        observer: &mut dyn LoadObserver,
    ) -> Result<(), OpenError> {
        let recording_error = |kind| OpenError::Recording {
            path: path.to_owned(),
            error: RrdError::new(0, kind),
        };
        let mut num_chunks = 0usize;
        let mut selector = RecordingSelector::new(self.options.recording.as_deref());
        for (item, position) in received {
            observer.progressed(position);
            match item {
                Ok(RrdItem::StoreInfo(info)) => selector.observe(&info),
                Ok(RrdItem::SkippedBlueprint { .. }) => self.skipped_blueprint_messages += 1,
                Ok(RrdItem::Chunk {
                    chunk,
                    offset,
                    store_id,
                }) => {
                    // Another recording's chunk is not data of this one (nor bad data).
                    if !selector.wants(&store_id).map_err(recording_error)? {
                        continue;
                    }
                    if let Some(fault) = self.insert_or_skip(chunk, path, Some(offset))? {
                        observer.skipped(&fault);
                    }
                    num_chunks += 1;
                }
                Ok(_) => {}
                Err(error) => {
                    let fault = LoadFault::Message {
                        path: path.to_owned(),
                        error,
                    };
                    observer.skipped(&self.skip(fault)?);
                }
            }
        }
        self.store_info = selector.finish().map_err(recording_error)?;
        if num_chunks == 0 && self.store.num_chunks() == 0 && self.options.skip_bad {
            observer.skipped(&LoadFault::NoChunk {
                path: path.to_owned(),
            });
        }
        Ok(())
    }

    fn load_directory(
        &mut self,
        dir: &Path,
        observer: &mut dyn LoadObserver,
    ) -> Result<(), OpenError> {
        let files = chunk_files(dir, &self.options.storage)?;
        if files.is_empty() {
            return Err(OpenError::NoChunkFiles {
                dir: dir.to_owned(),
            });
        }
        // With `skip_bad`, what was skipped is told once something loaded; else the error
        // names the first.
        let mut skipped = Vec::new();
        let mut num_loaded = 0;
        observer.started(files.len() as u64, ProgressUnit::Files);
        for (done, file) in files.iter().enumerate() {
            observer.progressed(done as u64 + 1);
            let read = crate::storage::read_whole(file, &self.options.storage)
                .map_err(|source| crate::ipc::IpcError::Io {
                    path: file.clone(),
                    source,
                })
                .and_then(|bytes| crate::ipc::read_chunks_from_bytes(&bytes));
            let chunks = match read {
                Ok(chunks) => chunks,
                Err(error) => {
                    let fault = LoadFault::File {
                        path: file.clone(),
                        error,
                    };
                    skipped.push(self.skip(fault)?);
                    continue;
                }
            };
            for chunk in chunks {
                skipped.extend(self.insert_or_skip(chunk, file, None)?);
            }
            num_loaded += 1;
        }
        observer.finished();
        if num_loaded == 0 {
            let first = skipped.into_iter().next().unwrap_or(LoadFault::NoChunk {
                path: dir.to_owned(),
            });
            return Err(OpenError::NoReadableFile {
                dir: dir.to_owned(),
                first: Box::new(first),
            });
        }
        for fault in &skipped {
            observer.skipped(fault);
        }
        Ok(())
    }
}

/// The chunk files of the directory `dir`, or of the prefix a URL ending in `/` names
/// (the Arrow IPC objects directly under it: one LIST), sorted by name.
fn chunk_files(
    dir: &Path,
    storage: &crate::storage::StorageOptions,
) -> Result<Vec<std::path::PathBuf>, OpenError> {
    if crate::storage::url_scheme(dir).is_none() {
        return crate::ipc::chunk_files(dir).map_err(|error| OpenError::Ipc {
            path: dir.to_owned(),
            error,
        });
    }
    #[cfg(feature = "object-store")]
    return crate::storage::object::list_rrd_objects(&dir.to_string_lossy(), storage)
        .map(|listed| {
            listed
                .chunk_files
                .into_iter()
                .map(std::path::PathBuf::from)
                .collect()
        })
        .map_err(|error| OpenError::Io {
            path: dir.to_owned(),
            source: error.into_io(),
        });
    #[cfg(not(feature = "object-store"))]
    {
        let _ = storage;
        Err(OpenError::Io {
            path: dir.to_owned(),
            source: crate::storage::StorageError::needs_feature(dir).into_io(),
        })
    }
}
