//! Reading a segment for a query: from the cache of loaded segments, whole from its file,
//! or (through its footer or its index) only the chunks the query needs, as `prune.rs`
//! picks them; and counting what each read cost.

use std::collections::HashSet;
use std::sync::atomic::{AtomicU64, Ordering};

#[cfg(feature = "datafusion")]
use super::threads::in_parallel;
use super::{Dataset, DatasetError, ReadStats, Warnings, prune};
use crate::recording::{LoadedRecording, OpenError, OpenOptions};
use crate::rrd::LazyRecording;
use crate::storage::Input;
use crate::{ChunkId, Snapshot};

/// What a query read of one segment.
pub(crate) struct SegmentRead {
    /// The store of what was read: the whole segment, or the chunks the query needs.
    pub snapshot: Snapshot,
    /// Is it kept for the rows' pass (see [`Dataset::segment_for`])?
    pub keep: bool,
    /// What was read from the file for it (nothing when the cache had it).
    pub read: ReadStats,
}

impl Dataset {
    /// Counts a read of one segment in the dataset's stats; returns it alone.
    fn count_read(&self, this: ReadStats) -> ReadStats {
        self.inner.read.lock().add(this);
        this
    }

    /// Segment number `number` loaded whole, from the cache or from its file.
    pub(crate) fn loaded_segment(
        &self,
        number: usize,
    ) -> Result<(Snapshot, ReadStats), DatasetError> {
        if let Some(snapshot) = self.inner.cache.lock().get(number) {
            return Ok((snapshot, ReadStats::default()));
        }
        let segment = &self.inner.segments[number];
        let options = OpenOptions {
            lazy: false,
            ..self.open_options(&segment.id)
        };
        let mut observer = Warnings(&self.inner.warnings);
        let loaded = LoadedRecording::load(&segment.path, &options, &mut observer)?;
        // An object is read whole in one streamed GET.
        let streamed = crate::storage::url_scheme(&segment.path).is_some();
        let read = self.count_read(ReadStats {
            segment_reads: 1,
            chunks_decoded: segment.num_chunks,
            bytes_read: segment.file_bytes,
            requests: u64::from(streamed),
            bytes_fetched: if streamed { segment.file_bytes } else { 0 },
        });
        let snapshot = loaded.store.snapshot();
        self.inner.cache.lock().insert(number, snapshot.clone());
        Ok((snapshot, read))
    }

    /// Can segment number `number` be read in part, through its footer's manifest? Not
    /// without a footer, nor with `skip_bad` (a bad chunk is skipped, which only a whole
    /// load does).
    pub(super) fn reads_in_part(&self, number: usize) -> bool {
        let segment = &self.inner.segments[number];
        (segment.from_footer || segment.index_file.is_some()) && !self.inner.options.skip_bad
    }

    /// Segment number `number`'s file opened through its footer; `None` when it has none.
    pub(super) fn footer(
        &self,
        number: usize,
    ) -> Result<Option<LazyRecording<Input>>, DatasetError> {
        let segment = &self.inner.segments[number];
        #[cfg(feature = "object-store")]
        if let Some(object) = &self.inner.objects[number] {
            // Its footer (or its index) was read when the dataset opened: no request.
            let input = Input::Object(object.clone());
            return match &segment.index_file {
                Some(index) => std::fs::File::open(index)
                    .map_err(|e| crate::rrd::RrdError::new(0, crate::rrd::RrdErrorKind::Io(e)))
                    .and_then(|index| LazyRecording::with_index(input, index, Some(&segment.id))),
                None => LazyRecording::from_reader_footer(input, Some(&segment.id)),
            }
            .map_err(|error| OpenError::rrd(&segment.path, error).into());
        }
        match &segment.index_file {
            Some(index) => LazyRecording::open_indexed(&segment.path, index, Some(&segment.id)),
            None => LazyRecording::open_recording(&segment.path, Some(&segment.id)),
        }
        .map(|lazy| lazy.map(|lazy| lazy.map_input(Input::File)))
        .map_err(|error| OpenError::rrd(&segment.path, error).into())
    }

    /// The chunks of segment number `number` that `pick` picks from its manifest, read
    /// through its footer; `None` when the file has no footer to read them by.
    fn read_part(
        &self,
        number: usize,
        pick: impl FnOnce(&crate::rrd::Manifest) -> PickedChunks,
    ) -> Result<Option<(Snapshot, ReadStats, PickedChunks)>, DatasetError> {
        let Some(mut lazy) = self.footer(number)? else {
            return Ok(None);
        };
        let segment = &self.inner.segments[number];
        // The reader may carry the requests of the dataset's open (its footer's GET).
        let opened = lazy.stats();
        let picked = pick(lazy.manifest());
        let store = lazy
            .load_where(|entry| picked.chunks.contains(&entry.chunk_id))
            .map_err(|error| OpenError::rrd(&segment.path, error))?;
        let snapshot = store.snapshot();
        let stats = lazy.stats();
        let read = self.count_read(ReadStats {
            segment_reads: 1,
            chunks_decoded: stats.chunks_decoded as u64,
            bytes_read: stats.bytes_read,
            requests: stats.requests - opened.requests,
            bytes_fetched: stats.bytes_fetched - opened.bytes_fetched,
        });
        Ok(Some((snapshot, read, picked)))
    }

    /// The chunks of segment number `number` that `pick` picks from its manifest (the
    /// whole segment where it cannot be read in part, or is kept).
    pub(crate) fn segment_chunks(
        &self,
        number: usize,
        pick: impl FnOnce(&crate::rrd::Manifest) -> HashSet<ChunkId>,
    ) -> Result<(Snapshot, ReadStats), DatasetError> {
        if let Some(snapshot) = self.inner.cache.lock().get(number) {
            return Ok((snapshot, ReadStats::default()));
        }
        if self.reads_in_part(number) {
            let part = self.read_part(number, |manifest| PickedChunks {
                chunks: pick(manifest),
                kept: false,
            })?;
            if let Some((snapshot, read, _)) = part {
                return Ok((snapshot, read));
            }
        }
        self.loaded_segment(number)
    }

    #[cfg(feature = "datafusion")]
    /// How many chunks of these segments (by number) reads for `query`'s rows decode (see
    /// [`Dataset::chunks_counted`]).
    ///
    /// # Errors
    /// A footer that cannot be read (its file changed since the dataset opened).
    pub(crate) fn chunks_for_rows(
        &self,
        numbers: &[usize],
        query: &crate::DataframeQuery,
    ) -> Result<u64, DatasetError> {
        self.chunks_counted(numbers, prune::prunable(query), |manifest| {
            prune::needed(manifest, query, prune::Needs::Rows).len()
        })
    }

    #[cfg(feature = "datafusion")]
    /// How many chunks of these segments (by number) `keep` keeps of their manifests (see
    /// [`Dataset::chunks_counted`]).
    ///
    /// # Errors
    /// A footer that cannot be read (its file changed since the dataset opened).
    pub(crate) fn chunks_picked(
        &self,
        numbers: &[usize],
        keep: impl Fn(&crate::rrd::ManifestEntry) -> bool + Sync,
    ) -> Result<u64, DatasetError> {
        self.chunks_counted(numbers, true, |manifest| {
            manifest.entries.iter().filter(|e| keep(e)).count()
        })
    }

    #[cfg(feature = "datafusion")]
    /// The chunks `count` counts in these segments' manifests, read from their footers on
    /// the dataset's threads; a segment read whole (no footer, `skip_bad`, or `in_part`
    /// false) counts all its chunks.
    fn chunks_counted(
        &self,
        numbers: &[usize],
        in_part: bool,
        count: impl Fn(&crate::rrd::Manifest) -> usize + Sync,
    ) -> Result<u64, DatasetError> {
        let counts = in_parallel(numbers, self.read_threads(), |&number| {
            if in_part
                && self.reads_in_part(number)
                && let Some(lazy) = self.footer(number)?
            {
                return Ok(count(lazy.manifest()) as u64);
            }
            Ok::<_, DatasetError>(self.inner.segments[number].num_chunks)
        });
        counts.into_iter().sum()
    }

    /// What segment number `number` holds that `query` needs: the whole segment if it is
    /// kept, else, through its footer, only the chunks the query needs (`prune.rs`; not
    /// kept in the cache, they are the query's); the whole segment where that cannot be
    /// told.
    ///
    /// For planning (`plan_room`: the bytes the query may still keep until it reads its
    /// rows), the rows' chunks are read too if they fit in that room, which they then
    /// take; otherwise only the columns' chunks. Without a room, for the rows, only the
    /// rows' chunks: the store may lack columns (and the index) the segment has, which
    /// hold nothing in the rows. Says whether what was read is kept for the rows (never
    /// without a room).
    pub(crate) fn segment_for(
        &self,
        number: usize,
        query: &crate::DataframeQuery,
        plan_room: Option<&AtomicU64>,
    ) -> Result<SegmentRead, DatasetError> {
        let reserve = |bytes: u64| {
            plan_room.is_some_and(|room| {
                room.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |left| {
                    left.checked_sub(bytes)
                })
                .is_ok()
            })
        };
        let whole = |(snapshot, read): (Snapshot, ReadStats)| {
            let keep = reserve(snapshot.stats().heap_bytes);
            SegmentRead {
                snapshot,
                keep,
                read,
            }
        };
        if let Some(snapshot) = self.inner.cache.lock().get(number) {
            return Ok(whole((snapshot, ReadStats::default())));
        }
        if self.reads_in_part(number) && prune::prunable(query) {
            let part = self.read_part(number, |manifest| {
                if plan_room.is_none() {
                    return PickedChunks {
                        chunks: prune::needed(manifest, query, prune::Needs::Rows),
                        kept: false,
                    };
                }
                let both = prune::needed(manifest, query, prune::Needs::Both);
                let bytes = manifest
                    .entries
                    .iter()
                    .filter(|e| both.contains(&e.chunk_id))
                    .map(|e| e.uncompressed_size)
                    .sum();
                if reserve(bytes) {
                    PickedChunks {
                        chunks: both,
                        kept: true,
                    }
                } else {
                    PickedChunks {
                        chunks: prune::needed(manifest, query, prune::Needs::Columns),
                        kept: false,
                    }
                }
            })?;
            if let Some((snapshot, read, picked)) = part {
                // For the rows, a store without the index holds none. For planning, where
                // none of the chunks it needs is on the index, the segment's own view (its
                // columns, which other timelines give) needs the whole segment.
                if plan_room.is_none() || snapshot.time_type(query.index()).is_some() {
                    return Ok(SegmentRead {
                        snapshot,
                        keep: picked.kept,
                        read,
                    });
                }
            }
        }
        self.loaded_segment(number).map(whole)
    }
}

/// The chunks a read of part of a segment picked, and whether they are kept for the rows.
pub(crate) struct PickedChunks {
    chunks: HashSet<ChunkId>,
    kept: bool,
}
