//! [`LazyRecording`]: an `.rrd` file opened through its footer's chunk manifest, which
//! decodes only the chunks a query needs.
//!
//! Opening reads the stream header, the store info and the footer (350 KB for a 1 GB file
//! of 5,200 chunks of two components) and nothing else. A query picks candidate chunks from the manifest (entity,
//! component, per-timeline time range of the component's cells), reads and decodes just
//! those, inserts them into a private [`ChunkStore`] (compaction off, so ids stay those of
//! the file), and answers from it: the answer is the one the whole recording gives,
//! because every chunk that could change it was loaded.
//!
//! Which chunks a latest-at at `t` needs: every candidate chunk has a cell at its
//! component's least time `min ≤ t`, so the answer's time is at least `S`, the greatest
//! such `min`; only chunks whose component range reaches `S` (`max ≥ S`) can hold it.
//! Static chunks of the component are loaded too (static data wins), and the chunks of the
//! entity and its ancestors that log Clears statically, or at or before `t` and at or
//! after `S` (they may hide the answer).
//!
//! The file is read by seeking to each message and reading it, not memory-mapped: a memory map needs `unsafe`
//! (this crate forbids it) and is undefined behaviour if another process truncates the
//! file; and since payloads are LZ4-compressed, a decoded chunk is a copy either way.

use std::io::SeekFrom;
use std::ops::Range;
use std::path::Path;
use std::sync::Arc;

use arrow_buffer::Buffer;

use super::error::{RrdError, RrdErrorKind};
use super::footers::{LazyStats, find_store_info, read_footers, read_into, read_stream_header};
use super::frames::StreamHeader;
use super::input::RrdInput;
use super::manifest::{Manifest, ManifestEntry};
use super::messages::{ArrowMsg, Compression, StoreInfo};
use super::payload;
use crate::query::{LatestAtQuery, QueryCell, RangeQuery, RangeResult};
use crate::{
    ChunkId, ChunkStore, ComponentName, EntityPath, StoreConfig, TimeInt, TimeRange, Timeline,
};

/// Chunk bytes a query's load asks its input to fetch at once ([`RrdInput::prefetch`]).
const PREFETCH_BATCH_BYTES: u64 = 64 << 20;

/// An `.rrd` recording opened lazily: see the module documentation.
///
/// ```no_run
/// use chunkstore::{EntityPath, LatestAtQuery, TimeInt};
/// use chunkstore::rrd::LazyRecording;
/// let mut recording = LazyRecording::open("big.rrd".as_ref())?.expect("the file has a footer");
/// let robot = EntityPath::parse("/world/robot")?;
/// let at = LatestAtQuery::new("frame_id", TimeInt::new(30).unwrap());
/// let cell = recording.latest_at(&at, &robot, "Transform3D:translation")?;
/// println!("{} of {} chunks decoded", recording.stats().chunks_decoded, recording.stats().chunks_in_file);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct LazyRecording<R = std::fs::File> {
    input: R,
    /// `None` when opened from the footer alone ([`LazyRecording::from_reader_footer`]).
    header: Option<StreamHeader>,
    store_info: Option<StoreInfo>,
    manifest: Manifest,
    /// Per entity, its entries (indices into the manifest), in file order.
    by_entity: ahash::HashMap<EntityPath, Vec<usize>>,
    loaded: ahash::HashSet<ChunkId>,
    store: ChunkStore,
    stats: LazyStats,
    footers_start: u64,
}

impl<R> std::fmt::Debug for LazyRecording<R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LazyRecording")
            .field("store_info", &self.store_info)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl LazyRecording<std::fs::File> {
    /// Opens a file lazily; `Ok(None)` if it has no footer (read it with
    /// [`super::read_rrd`] instead).
    ///
    /// # Errors
    /// If the file cannot be read, is not an `.rrd`, its footer is corrupt, or it holds
    /// more than one recording ([`RrdErrorKind::SeveralRecordings`]: choose one with
    /// [`LazyRecording::open_recording`]).
    pub fn open(path: &Path) -> Result<Option<Self>, RrdError> {
        Self::open_recording(path, None)
    }

    /// Opens the recording `recording_id` of a file lazily (or, given `None`, the only
    /// one); `Ok(None)` if the file has no footer.
    ///
    /// # Errors
    /// As [`LazyRecording::open`], and [`RrdErrorKind::NoSuchRecording`] if the file does
    /// not hold that recording.
    pub fn open_recording(
        path: &Path,
        recording_id: Option<&str>,
    ) -> Result<Option<Self>, RrdError> {
        let file = std::fs::File::open(path).map_err(|e| RrdError::new(0, RrdErrorKind::Io(e)))?;
        Self::from_reader_recording(file, recording_id)
    }
}

impl LazyRecording<std::fs::File> {
    /// Opens the data file `path` lazily through its detached index `index` (written by
    /// [`super::index::scan_and_index`] when the file had no footer): the index gives the
    /// store info and the manifest, and chunks are read from `path`. `Ok(None)` if the
    /// index is not one (it has no footer).
    ///
    /// # Errors
    /// As [`LazyRecording::open_recording`], for either file. A data file that changed
    /// since it was indexed is found out when a chunk is read: one that is not where the
    /// index puts it is an error naming its offset.
    pub fn open_indexed(
        path: &Path,
        index: &Path,
        recording_id: Option<&str>,
    ) -> Result<Option<Self>, RrdError> {
        let io = |e| RrdError::new(0, RrdErrorKind::Io(e));
        let index = std::fs::File::open(index).map_err(io)?;
        let data = std::fs::File::open(path).map_err(io)?;
        LazyRecording::with_index(data, index, recording_id)
    }
}

impl<R: RrdInput> LazyRecording<R> {
    /// Opens the data `input` lazily through its detached index `index` (the index's
    /// bytes), as [`LazyRecording::open_indexed`] opens a file (the input may be an object
    /// in a bucket: only the chunks a query needs are read from it).
    ///
    /// # Errors
    /// As [`LazyRecording::open_indexed`].
    pub fn with_index<I: RrdInput>(
        mut input: R,
        index: I,
        recording_id: Option<&str>,
    ) -> Result<Option<Self>, RrdError> {
        let Some(lazy) = LazyRecording::from_reader_recording(index, recording_id)? else {
            return Ok(None);
        };
        let file_bytes = input
            .seek(SeekFrom::End(0))
            .map_err(|e| RrdError::new(0, RrdErrorKind::Io(e)))?;
        let mut lazy = lazy.map_input(|_| input);
        lazy.stats.file_bytes = file_bytes;
        Ok(Some(lazy))
    }

    /// Opens a seekable input lazily; `Ok(None)` if it has no footer.
    ///
    /// # Errors
    /// As [`LazyRecording::open`].
    pub fn from_reader(input: R) -> Result<Option<Self>, RrdError> {
        Self::from_reader_recording(input, None)
    }

    /// Opens the recording `recording_id` (or the only one) of a seekable input lazily;
    /// `Ok(None)` if it has no footer.
    ///
    /// The input may be several streams one after the other (`cat a.rrd b.rrd`): each
    /// stream's footer is found from the end backwards (its stream footer says where its
    /// `End` message is, counted from the stream's start), and the manifests of one
    /// recording in several streams are merged, their offsets counted from the start of
    /// the input. If any stream has no footer, `Ok(None)`: only a full read sees it all.
    ///
    /// # Errors
    /// As [`LazyRecording::open_recording`].
    pub fn from_reader_recording(
        input: R,
        recording_id: Option<&str>,
    ) -> Result<Option<Self>, RrdError> {
        Self::open_with(input, recording_id, true)
    }

    /// Opens the recording `recording_id` (or the only one) of a seekable input from its
    /// footers alone, without reading the start of any stream: no stream header is
    /// checked ([`LazyRecording::header`] is `None`) and no store info is looked for
    /// ([`LazyRecording::store_info`] is `None`; the manifest's store id names the
    /// recording). Over a network this is one read at the end of the input, where
    /// [`LazyRecording::from_reader_recording`] also reads its start. `Ok(None)` if it has
    /// no footer.
    ///
    /// # Errors
    /// As [`LazyRecording::open_recording`].
    pub fn from_reader_footer(
        input: R,
        recording_id: Option<&str>,
    ) -> Result<Option<Self>, RrdError> {
        Self::open_with(input, recording_id, false)
    }

    fn open_with(
        mut input: R,
        recording_id: Option<&str>,
        read_starts: bool,
    ) -> Result<Option<Self>, RrdError> {
        let io = |at: u64| move |e: std::io::Error| RrdError::new(at, RrdErrorKind::Io(e));
        let file_bytes = input.seek(SeekFrom::End(0)).map_err(io(0))?;
        let mut stats = LazyStats {
            file_bytes,
            ..LazyStats::default()
        };
        let header = if read_starts {
            Some(read_stream_header(&mut input, 0, &mut stats)?)
        } else {
            None
        };
        let Some(streams) = read_footers(&mut input, &mut stats, read_starts)? else {
            return Ok(None);
        };
        let footers_start = streams.iter().map(|s| s.end_at).min().unwrap_or(file_bytes);
        // Each recording's manifest, merged across streams, in file order.
        let mut manifests: Vec<Manifest> = Vec::new();
        for stream in &streams {
            for manifest in &stream.manifests {
                match manifests
                    .iter_mut()
                    .find(|m| m.store_id == manifest.store_id)
                {
                    Some(merged) => merged.entries.extend(manifest.entries.iter().cloned()),
                    None => manifests.push(manifest.clone()),
                }
            }
        }
        let chosen = super::recordings::pick(manifests.iter().map(|m| &m.store_id), recording_id)
            .map_err(|kind| RrdError::new(0, kind))?
            .cloned();
        let Some(chosen) = chosen else {
            return Ok(None);
        };
        let Some(manifest) = manifests.into_iter().find(|m| m.store_id == chosen) else {
            return Ok(None);
        };
        let store_info = if read_starts {
            find_store_info(&mut input, &streams, &chosen, &mut stats)
        } else {
            None
        };
        let mut by_entity: ahash::HashMap<EntityPath, Vec<usize>> = ahash::HashMap::default();
        for (i, entry) in manifest.entries.iter().enumerate() {
            by_entity
                .entry(entry.entity_path.clone())
                .or_default()
                .push(i);
        }
        stats.chunks_in_file = manifest.entries.len();
        let store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).map_err(|e| {
            RrdError::new(
                0,
                RrdErrorKind::Footer {
                    reason: e.to_string(),
                },
            )
        })?;
        Ok(Some(Self {
            input,
            header,
            store_info,
            manifest,
            by_entity,
            loaded: ahash::HashSet::default(),
            store,
            stats,
            footers_start,
        }))
    }

    /// The same recording read from `f(input)` (the input, wrapped).
    pub(crate) fn map_input<S>(self, f: impl FnOnce(R) -> S) -> LazyRecording<S> {
        LazyRecording {
            input: f(self.input),
            header: self.header,
            store_info: self.store_info,
            manifest: self.manifest,
            by_entity: self.by_entity,
            loaded: self.loaded,
            store: self.store,
            stats: self.stats,
            footers_start: self.footers_start,
        }
    }

    /// Where the first of the input's footers starts: what opening it again reads is at
    /// or after this byte (the stream footers and footers), with its start if
    /// [`LazyRecording::from_reader_recording`] read it.
    pub fn footers_start(&self) -> u64 {
        self.footers_start
    }

    /// The stream header: which Rerun version wrote the file; `None` when opened from the
    /// footer alone ([`LazyRecording::from_reader_footer`]).
    pub fn header(&self) -> Option<StreamHeader> {
        self.header
    }

    /// The recording's store info (the first `SetStoreInfo` of its store in the file), if
    /// the file has one.
    pub fn store_info(&self) -> Option<&StoreInfo> {
        self.store_info.as_ref()
    }

    /// The footer's manifest of the recording (merged across the file's streams), its
    /// offsets counted from the start of the file.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// What has been read so far.
    pub fn stats(&self) -> LazyStats {
        let fetched = self.input.fetched();
        LazyStats {
            requests: fetched.requests,
            bytes_fetched: fetched.bytes,
            ..self.stats
        }
    }

    /// The chunks decoded so far, in a store.
    pub fn loaded_store(&self) -> &ChunkStore {
        &self.store
    }

    /// Every entity with data, sorted.
    pub fn entity_paths(&self) -> Vec<EntityPath> {
        let mut paths: Vec<EntityPath> = self.by_entity.keys().cloned().collect();
        paths.sort();
        paths
    }

    /// The components `entity` has data for, sorted.
    pub fn component_names(&self, entity: &EntityPath) -> Vec<ComponentName> {
        let mut names: Vec<ComponentName> = self
            .entries_of(entity)
            .flat_map(|e| e.components.iter().map(|c| c.name.clone()))
            .collect();
        names.sort();
        names.dedup();
        names
    }

    /// Every timeline of the recording's data, sorted by name.
    pub fn timelines(&self) -> Vec<Timeline> {
        let mut timelines: Vec<Timeline> = self
            .manifest
            .entries
            .iter()
            .flat_map(|e| &e.ranges)
            .map(|range| range.timeline.clone())
            .collect();
        timelines.sort();
        timelines.dedup();
        timelines
    }

    /// The least and greatest time of the data on `timeline`, as the manifest lists it, or
    /// `None` if the recording has none there.
    pub fn time_range(&self, timeline: &str) -> Option<TimeRange> {
        self.manifest
            .entries
            .iter()
            .flat_map(|e| &e.ranges)
            .filter(|range| range.timeline.name() == timeline)
            .map(|range| TimeRange::new(range.min, range.max))
            .reduce(TimeRange::union)
    }

    fn entries_of<'a>(
        &'a self,
        entity: &EntityPath,
    ) -> impl Iterator<Item = &'a ManifestEntry> + 'a {
        self.by_entity
            .get(entity)
            .into_iter()
            .flatten()
            .map(|&i| &self.manifest.entries[i])
    }

    /// The latest-at answer, as the whole recording gives it, decoding only the chunks
    /// that could hold or hide it.
    ///
    /// # Errors
    /// If a chunk the query needs cannot be read or decoded, or disagrees with the manifest.
    pub fn latest_at(
        &mut self,
        query: &LatestAtQuery,
        entity: &EntityPath,
        component: &str,
    ) -> Result<Option<QueryCell>, RrdError> {
        let t = query.at();
        let timeline = query.timeline();
        let component_range = |entry: &ManifestEntry, name: &str| {
            entry
                .components
                .iter()
                .find(|c| c.name.as_str() == name)
                .map(|c| {
                    c.ranges
                        .iter()
                        .find(|r| r.timeline.name() == timeline)
                        .map(|r| (r.min, r.max))
                })
        };
        let mut needed: Vec<usize> = Vec::new();
        let mut candidates: Vec<(usize, TimeInt, TimeInt)> = Vec::new();
        for &i in self.by_entity.get(entity).into_iter().flatten() {
            let entry = &self.manifest.entries[i];
            match component_range(entry, component) {
                Some(_) if entry.is_static => needed.push(i),
                Some(Some((min, max))) if min <= t => candidates.push((i, min, max)),
                _ => {}
            }
        }
        let floor = candidates.iter().map(|c| c.1).max();
        if let Some(floor) = floor {
            needed.extend(candidates.iter().filter(|c| c.2 >= floor).map(|c| c.0));
        }
        // Clears of the entity and its ancestors that may hide the answer: static ones
        // always (they hide static data too), temporal ones between the floor and `t`.
        let clear = ComponentName::CLEAR_IS_RECURSIVE;
        for path in std::iter::once(entity.clone()).chain(entity.ancestors()) {
            for &i in self.by_entity.get(&path).into_iter().flatten() {
                let entry = &self.manifest.entries[i];
                match (component_range(entry, clear), floor) {
                    (Some(_), _) if entry.is_static => needed.push(i),
                    (Some(Some((min, max))), Some(floor)) if min <= t && max >= floor => {
                        needed.push(i);
                    }
                    _ => {}
                }
            }
        }
        self.load(&needed)?;
        Ok(self.store.latest_at(query, entity, component))
    }

    /// The range answer, as the whole recording gives it, decoding only the chunks whose
    /// cells of `component` overlap the range (and static ones).
    ///
    /// # Errors
    /// As [`LazyRecording::latest_at`].
    pub fn range(
        &mut self,
        query: &RangeQuery,
        entity: &EntityPath,
        component: &str,
    ) -> Result<RangeResult, RrdError> {
        let range = query.range();
        let needed: Vec<usize> = self
            .by_entity
            .get(entity)
            .into_iter()
            .flatten()
            .copied()
            .filter(|&i| {
                let entry = &self.manifest.entries[i];
                entry
                    .components
                    .iter()
                    .find(|c| c.name.as_str() == component)
                    .is_some_and(|c| {
                        entry.is_static
                            || c.ranges.iter().any(|r| {
                                r.timeline.name() == query.timeline()
                                    && TimeRange::new(r.min, r.max).intersects(range)
                            })
                    })
            })
            .collect();
        self.load(&needed)?;
        Ok(self.store.range(query, entity, component))
    }

    /// Decodes the chunks whose manifest entries `keep` picks (those not decoded yet), and
    /// returns the store of every chunk decoded so far: for a caller that knows from the
    /// manifest which chunks its reads need (a dataset's dataframe over a range).
    ///
    /// # Errors
    /// As [`LazyRecording::latest_at`].
    pub fn load_where(
        &mut self,
        mut keep: impl FnMut(&ManifestEntry) -> bool,
    ) -> Result<&ChunkStore, RrdError> {
        let picked: Vec<usize> = (0..self.manifest.entries.len())
            .filter(|&i| keep(&self.manifest.entries[i]))
            .collect();
        self.load(&picked)?;
        Ok(&self.store)
    }

    /// Decodes every chunk not decoded yet: the whole recording, in its store.
    ///
    /// # Errors
    /// As [`LazyRecording::latest_at`].
    pub fn load_all(&mut self) -> Result<&ChunkStore, RrdError> {
        let all: Vec<usize> = (0..self.manifest.entries.len()).collect();
        self.load(&all)?;
        Ok(&self.store)
    }

    /// Decodes every chunk not decoded yet and hands over the whole recording's store
    /// (closing the input): for a caller that started lazily and now needs everything,
    /// to write to, collect or share.
    ///
    /// # Errors
    /// As [`LazyRecording::latest_at`]; the recording is gone either way.
    pub fn into_store(mut self) -> Result<ChunkStore, RrdError> {
        self.load_all()?;
        Ok(self.store)
    }

    fn load(&mut self, entries: &[usize]) -> Result<(), RrdError> {
        let mut wanted: Vec<usize> = entries
            .iter()
            .copied()
            .filter(|&i| !self.loaded.contains(&self.manifest.entries[i].chunk_id))
            .collect();
        wanted.sort_unstable();
        wanted.dedup();
        // The input is told each batch's ranges before they are read (an object in a
        // bucket fetches them together); a batch is bounded so that what it fetched, held
        // until read, stays small beside the chunks it decodes to.
        let mut start = 0;
        while start < wanted.len() {
            let mut end = start;
            let mut bytes = 0u64;
            while end < wanted.len() && (end == start || bytes < PREFETCH_BATCH_BYTES) {
                bytes = bytes.saturating_add(self.manifest.entries[wanted[end]].byte_size);
                end += 1;
            }
            let batch = &wanted[start..end];
            let mut ranges: Vec<Range<u64>> = batch
                .iter()
                .map(|&i| {
                    let entry = &self.manifest.entries[i];
                    entry.byte_offset..entry.byte_offset.saturating_add(entry.byte_size)
                })
                .collect();
            ranges.sort_unstable_by_key(|r| (r.start, r.end));
            let first = ranges.first().map_or(0, |r| r.start);
            self.input
                .prefetch(&ranges)
                .map_err(|e| RrdError::new(first, RrdErrorKind::Io(e)))?;
            self.load_batch(batch)?;
            start = end;
        }
        Ok(())
    }

    fn load_batch(&mut self, entries: &[usize]) -> Result<(), RrdError> {
        let mut body = Vec::new();
        for &i in entries {
            let entry = &self.manifest.entries[i];
            if self.loaded.contains(&entry.chunk_id) {
                continue;
            }
            let (id, at, len) = (entry.chunk_id, entry.byte_offset, entry.byte_size);
            read_into(
                &mut self.input,
                at,
                len,
                self.stats.file_bytes,
                &mut self.stats,
                &mut body,
            )?;
            let within =
                |(offset, kind): (usize, RrdErrorKind)| RrdError::new(at + offset as u64, kind);
            let msg = ArrowMsg::decode(&body).map_err(within)?;
            let payload = if msg.compression == Compression::None {
                // Decoded in place: the chunk keeps the body.
                let shared = Buffer::from_vec(std::mem::take(&mut body));
                payload::PayloadBytes::Shared(
                    shared.slice_with_length(msg.payload.start, msg.payload.len()),
                )
            } else {
                payload::PayloadBytes::Borrowed(&body[msg.payload.clone()])
            };
            let chunk = payload::decode_message_chunk(&msg, payload, at)?;
            if chunk.id() != id {
                return Err(RrdError::new(
                    at,
                    RrdErrorKind::Footer {
                        reason: format!(
                            "the manifest says chunk {id} is here, the file has chunk {}",
                            chunk.id()
                        ),
                    },
                ));
            }
            self.store.insert(Arc::new(chunk)).map_err(|e| {
                RrdError::new(
                    at,
                    RrdErrorKind::Footer {
                        reason: e.to_string(),
                    },
                )
            })?;
            self.loaded.insert(id);
            self.stats.chunks_decoded += 1;
        }
        Ok(())
    }
}
