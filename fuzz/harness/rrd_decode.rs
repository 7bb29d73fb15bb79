//! The body of the `rrd_decode` fuzz target: arbitrary bytes as an `.rrd` stream, read
//! four ways (from memory, streamed from a reader, opened lazily through a footer, and
//! scanned into a detached index).
//! Nothing may panic; the two eager readers (from memory, runs of small chunks decode a
//! phase at a time) must agree item for item (chunk ids, error offsets and kinds); a lazy recording, where the bytes open as one, must answer a latest-at as a
//! store holding every chunk its manifest lists does; the chunks then go through
//! everything a store does ([`super::lifecycle::exercise`]).

use arrow_buffer::Buffer;
use chunkstore::rrd::{self, LazyRecording, Manifest, ManifestTimeRange, RrdContents};
use chunkstore::{Chunk, ChunkId, ChunkStore, LatestAtQuery, StoreConfig, TimeInt};

/// What the manifest should say of a chunk's component: its cells' range per timeline.
fn component_ranges(chunk: &Chunk, name: &str) -> Vec<ManifestTimeRange> {
    let Some(column) = chunk.component(name) else {
        return Vec::new();
    };
    let mut ranges: Vec<ManifestTimeRange> = chunk
        .time_columns()
        .iter()
        .filter_map(|time| {
            let valid = (0..chunk.num_rows()).filter(|&row| column.is_valid(row));
            let times: Vec<i64> = valid.map(|row| time.times()[row]).collect();
            Some(ManifestTimeRange {
                timeline: time.timeline().clone(),
                min: TimeInt::new(*times.iter().min()?)?,
                max: TimeInt::new(*times.iter().max()?)?,
            })
        })
        .collect();
    ranges.sort_by(|a, b| a.timeline.name().cmp(b.timeline.name()));
    ranges
}

/// A store of every chunk, if the stream decoded without an error and its manifest lists
/// exactly its chunks, each with its true entity, static flag and component ranges.
fn truthful_store(contents: &RrdContents, manifest: &Manifest) -> Option<ChunkStore> {
    if !contents.errors.is_empty() || manifest.entries.len() != contents.chunks.len() {
        return None;
    }
    for (entry, (_, chunk)) in manifest.entries.iter().zip(&contents.chunks) {
        let mut names: Vec<&str> = chunk
            .components()
            .iter()
            .map(|c| c.name().as_str())
            .collect();
        names.sort_unstable();
        let listed: Vec<&str> = entry.components.iter().map(|c| c.name.as_str()).collect();
        let truthful = entry.chunk_id == chunk.id()
            && &entry.entity_path == chunk.entity_path()
            && entry.is_static == chunk.is_static()
            && listed == names
            && entry.components.iter().all(|c| {
                let mut claimed = c.ranges.clone();
                claimed.sort_by(|a, b| a.timeline.name().cmp(b.timeline.name()));
                chunk.is_static() || claimed == component_ranges(chunk, c.name.as_str())
            });
        if !truthful {
            return None;
        }
    }
    let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).ok()?;
    for (_, chunk) in &contents.chunks {
        // A copy (chunks are not `Clone`); the originals go on to the lifecycle.
        let copy = Chunk::from_record_batch(&chunk.to_record_batch().ok()?).ok()?;
        store.insert(copy).ok()?;
    }
    Some(store)
}

fn summary(contents: &RrdContents) -> (Vec<ChunkId>, Vec<u64>, usize, bool) {
    (
        contents.chunks.iter().map(|(_, c)| c.id()).collect(),
        contents.errors.iter().map(|e| e.offset).collect(),
        contents.store_infos.len(),
        contents.manifests.is_some(),
    )
}

/// What kind of error it is (its message can print a hash map, in no set order).
fn kind_of(error: &rrd::RrdError) -> std::mem::Discriminant<rrd::RrdErrorKind> {
    std::mem::discriminant(&error.kind)
}

/// Scanned as a file without a footer is, in one pass (an object's body as it arrives):
/// the index lists the scanned chunks in order, each placed within the stream, each chunk
/// read back through it.
fn scanned_into_an_index(bytes: &[u8]) {
    if let Ok((scanned, index)) = rrd::index::scan_stream_and_index(bytes, Vec::new())
        && scanned.store_info.is_some()
    {
        let mut through = LazyRecording::with_index(
            std::io::Cursor::new(bytes),
            std::io::Cursor::new(index),
            None,
        )
        .expect("the index it wrote reads")
        .expect("an index has a footer");
        let entries = &through.manifest().entries;
        let ids: Vec<ChunkId> = entries.iter().map(|e| e.chunk_id).collect();
        let scanned_ids: Vec<ChunkId> = scanned.chunks.iter().map(|c| c.id()).collect();
        assert_eq!(ids, scanned_ids);
        for entry in entries {
            assert!(entry.byte_size > 0, "{entry:?}");
            assert!(
                entry.byte_offset + entry.byte_size <= bytes.len() as u64,
                "{entry:?}"
            );
        }
        assert_eq!(through.stats().file_bytes, bytes.len() as u64);
        // The stream decoded cleanly, so each chunk decodes again where the index places
        // it; only the store may refuse one (a component of two types, say).
        if let Err(error) = through.load_all() {
            assert!(
                matches!(error.kind, rrd::RrdErrorKind::Footer { .. })
                    && !error.to_string().contains("the manifest says"),
                "{error}"
            );
        }
    }
}

pub fn rrd_decode(bytes: &[u8]) {
    let from_memory = rrd::read_rrd(Buffer::from(bytes.to_vec()), true);
    let streamed = rrd::read_rrd_from(bytes, true);
    let (from_memory, streamed) = match (from_memory, streamed) {
        (Ok(a), Ok(b)) => (a, b),
        (Err(a), Err(b)) => {
            assert_eq!(a.offset, b.offset, "{a} / {b}");
            assert_eq!(kind_of(&a), kind_of(&b), "{a} / {b}");
            return;
        }
        (a, b) => panic!("the readers disagree: {:?} / {:?}", a.err(), b.err()),
    };
    // From memory, runs of messages decode a phase at a time; streamed, one at a time.
    assert_eq!(summary(&from_memory), summary(&streamed));
    let kinds =
        |contents: &RrdContents| -> Vec<_> { contents.errors.iter().map(kind_of).collect() };
    assert_eq!(kinds(&from_memory), kinds(&streamed));
    for error in &from_memory.errors {
        assert!(error.offset <= bytes.len() as u64, "{error}");
        let _ = error.to_string();
    }

    // A file of several recordings: each opens when chosen, and a selector fed the
    // stream's items in order never panics.
    if let Err(error) = LazyRecording::from_reader(std::io::Cursor::new(bytes))
        && let rrd::RrdErrorKind::SeveralRecordings { recording_ids } = &error.kind
    {
        assert!(recording_ids.len() >= 2, "{error}");
        for id in recording_ids.iter().take(4) {
            let chosen =
                LazyRecording::from_reader_recording(std::io::Cursor::new(bytes), Some(id));
            if let Ok(Some(chosen)) = chosen {
                assert_eq!(*chosen.manifest().store_id.recording_id, **id);
            }
        }
    }
    let mut selector = rrd::RecordingSelector::new(None);
    for info in &from_memory.store_infos {
        selector.observe(info);
    }
    for (store, _) in &from_memory.chunks {
        let _ = selector.wants(store);
    }
    let _ = selector.finish();

    // Opened from its footers alone (as an object in a bucket is): where the whole opening
    // reads the footers, so does this one, to the same manifest, without a header or a
    // store info; and a load through it never panics.
    if let Ok(Some(whole)) = LazyRecording::from_reader(std::io::Cursor::new(bytes)) {
        let mut footer = LazyRecording::from_reader_footer(std::io::Cursor::new(bytes), None)
            .expect("the footers the whole opening read")
            .expect("a footer");
        assert_eq!(footer.manifest(), whole.manifest());
        assert_eq!(footer.footers_start(), whole.footers_start());
        assert!(footer.header().is_none() && footer.store_info().is_none());
        let _ = footer.load_all();
    }

    scanned_into_an_index(bytes);

    if let Ok(Some(mut lazy)) = LazyRecording::from_reader(std::io::Cursor::new(bytes)) {
        // Where the whole stream decoded cleanly and its manifest tells the truth about
        // every chunk, lazy answers must be the eager store's.
        let eager = truthful_store(&from_memory, lazy.manifest());
        let entities = lazy.entity_paths();
        for entity in entities.iter().take(4) {
            for component in lazy.component_names(entity).iter().take(4) {
                for timeline in ["frame", "frame_id", "log_time", "sim_time", "t"] {
                    for t in [i64::MIN + 1, 0, 1, 30, i64::MAX] {
                        let query = LatestAtQuery::new(timeline, TimeInt::new(t).expect("valid"));
                        let lazily = lazy.latest_at(&query, entity, component.as_str());
                        if let (Some(store), Ok(lazily)) = (&eager, lazily) {
                            let eagerly = store.latest_at(&query, entity, component.as_str());
                            assert_eq!(
                                lazily.map(|c| (c.row_id(), c.time())),
                                eagerly.map(|c| (c.row_id(), c.time())),
                                "{timeline} {t} {entity} {component}"
                            );
                        }
                    }
                }
            }
        }
        let stats = lazy.stats();
        assert_eq!(stats.file_bytes, bytes.len() as u64);
        assert!(stats.chunks_decoded <= stats.chunks_in_file);
    }

    let chunks = from_memory.chunks.into_iter().map(|(_, c)| c).collect();
    super::lifecycle::exercise(chunks);
}
