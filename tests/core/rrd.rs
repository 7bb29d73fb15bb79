//! `.rrd` files: the robot recording Rerun 0.41 wrote decodes to exactly the chunks of its
//! chunk files; what we write reads back identically; bad input is a typed error naming
//! the byte offset, never a panic.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests fail loudly on unexpected values"
)]

use std::sync::Arc;

use arrow_buffer::Buffer;
use chunkstore::Chunk;
use chunkstore::rrd::{self, RrdErrorKind, RrdItem, RrdReader, RrdWriter, StoreId, StoreKind};

use crate::common;

use common::robot_recording as recording;

fn rrd_bytes() -> Vec<u8> {
    std::fs::read(recording().join("a_robot.rrd")).unwrap()
}

fn chunk_files() -> Vec<Chunk> {
    common::robot_chunks()
}

fn same_chunks(a: &[Chunk], b: &[Chunk]) {
    assert_eq!(a.len(), b.len());
    for (a, b) in a.iter().zip(b) {
        assert_eq!(a.id(), b.id());
        assert_eq!(
            a.to_record_batch().unwrap(),
            b.to_record_batch().unwrap(),
            "chunk {}",
            a.id()
        );
    }
}

#[test]
fn the_robot_recording_decodes_to_its_chunk_files() {
    let contents = rrd::read_rrd(Buffer::from_vec(rrd_bytes()), false).unwrap();
    let chunks: Vec<Chunk> = contents.chunks.into_iter().map(|(_, c)| c).collect();
    same_chunks(&chunks, &chunk_files());
    let info = &contents.store_infos[0];
    assert_eq!(info.store_id.kind, StoreKind::Recording);
    assert_eq!(&*info.store_id.application_id, "rerun_example_robot_scene");
    assert_eq!(
        &*info.store_id.recording_id,
        "a0000000-0000-4000-8000-00000000000a"
    );
    assert_eq!(contents.skipped_blueprint_messages, 0);

    // The footer's manifest describes every chunk, in file order.
    let manifests = contents.manifests.expect("Rerun 0.41 writes a footer");
    assert_eq!(manifests.len(), 1);
    let entries = &manifests[0].entries;
    assert_eq!(entries.len(), chunks.len());
    for (entry, chunk) in entries.iter().zip(&chunks) {
        assert_eq!(entry.chunk_id, chunk.id());
        assert_eq!(&entry.entity_path, chunk.entity_path());
        assert_eq!(entry.is_static, chunk.is_static());
        assert_eq!(entry.num_rows, chunk.num_rows() as u64);
        for time in chunk.time_columns() {
            let range = entry
                .ranges
                .iter()
                .find(|r| r.timeline.name() == time.timeline().name())
                .unwrap();
            assert_eq!(
                chunkstore::TimeRange::new(range.min, range.max),
                time.time_range()
            );
            assert_eq!(range.timeline, *time.timeline());
        }
        let mut names: Vec<&str> = chunk
            .components()
            .iter()
            .map(|c| c.name().as_str())
            .collect();
        names.sort_unstable();
        let listed: Vec<&str> = entry.components.iter().map(|c| c.name.as_str()).collect();
        assert_eq!(listed, names);
    }
}

#[test]
fn a_stream_reader_gives_the_same_as_a_buffer_reader() {
    let bytes = rrd_bytes();
    let from_stream = rrd::read_rrd_from(bytes.as_slice(), false).unwrap();
    let from_buffer = rrd::read_rrd(Buffer::from_vec(bytes), false).unwrap();
    let a: Vec<Chunk> = from_stream.chunks.into_iter().map(|(_, c)| c).collect();
    let b: Vec<Chunk> = from_buffer.chunks.into_iter().map(|(_, c)| c).collect();
    same_chunks(&a, &b);
    assert_eq!(from_stream.manifests, from_buffer.manifests);
}

fn write(chunks: &[Arc<Chunk>], compress: bool) -> Vec<u8> {
    let info = rrd::StoreInfo::new(StoreId::recording("app", "rec"));
    let mut writer = RrdWriter::with_store_info(Vec::new(), &info, compress).unwrap();
    for chunk in chunks {
        writer.write_chunk(chunk).unwrap();
    }
    writer.finish().unwrap()
}

/// Issue 32, item 2: two rows logged at frames 2 then 1 compact into one chunk in time
/// order, so its row ids are out of order; Rerun refuses such a chunk. Every writer sorts
/// rows by row id on the way out, keeping the chunk's id and its answers.
#[test]
fn compacted_out_of_order_rows_are_written_in_row_id_order() {
    use chunkstore::{ChunkStore, LatestAtQuery, RangeQuery, StoreConfig, TimeRange};
    let mut store = ChunkStore::with_config(StoreConfig::DEFAULT).unwrap();
    store.insert(common::scalar("/e", "x", 2, 10, 2.0)).unwrap();
    store.insert(common::scalar("/e", "x", 1, 20, 1.0)).unwrap();
    store.compact();
    let chunks = store.export_chunks();
    assert!(
        chunks.iter().any(|c| !c.is_sorted_by_row_id()),
        "the store must hold a chunk out of row-id order for this test to mean anything"
    );
    for compress in [true, false] {
        let back = common::rrd_chunks_rerun_loads(write(&chunks, compress));
        let back_ids: Vec<_> = back.iter().map(Chunk::id).collect();
        let ids: Vec<_> = chunks.iter().map(|c| c.id()).collect();
        assert_eq!(back_ids, ids, "same chunks, same ids");
        let mut reread = ChunkStore::new();
        for chunk in back {
            reread.insert(chunk).unwrap();
        }
        let e = common::path("/e");
        for at in 0..=3 {
            let query = LatestAtQuery::new("frame", common::t(at));
            assert_eq!(
                reread.latest_at(&query, &e, "x").map(|c| c.row_id()),
                store.latest_at(&query, &e, "x").map(|c| c.row_id()),
                "latest-at {at}"
            );
        }
        let all = RangeQuery::new("frame", TimeRange::new(common::t(0), common::t(9)));
        let rows = |s: &ChunkStore| {
            s.range(&all, &e, "x")
                .iter()
                .map(|r| (r.time(), r.row_id()))
                .collect::<Vec<_>>()
        };
        assert_eq!(rows(&reread), rows(&store));
    }
    // Chunk files too.
    let mut file = Vec::new();
    let unsorted = chunks.iter().find(|c| !c.is_sorted_by_row_id()).unwrap();
    chunkstore::ipc::write_chunk_ipc_file(unsorted, &mut file).unwrap();
    let back = chunkstore::ipc::read_chunks_from_bytes(&file).unwrap();
    back.iter().for_each(common::assert_rerun_loads);
    assert_eq!(back[0].id(), unsorted.id());
}

#[test]
fn a_second_chunk_under_one_id_is_refused_and_the_stream_stays_readable() {
    let original: Vec<Arc<Chunk>> = chunk_files().into_iter().map(Arc::new).collect();
    let info = rrd::StoreInfo::new(StoreId::recording("app", "rec"));
    let mut writer = RrdWriter::with_store_info(Vec::new(), &info, true).unwrap();
    writer.write_chunk(&original[0]).unwrap();
    let before = writer.position();
    let error = writer.write_chunk(&original[0]).unwrap_err();
    assert!(
        matches!(error.kind, RrdErrorKind::DuplicateChunkId { chunk_id } if chunk_id == original[0].id()),
        "{error}"
    );
    assert!(
        error.to_string().contains(&original[0].id().to_string()),
        "{error}"
    );
    assert_eq!(writer.position(), before, "nothing written");
    writer.write_chunk(&original[1]).unwrap();
    let bytes = writer.finish().unwrap();
    let back = rrd::read_rrd(Buffer::from_vec(bytes), false).unwrap();
    let ids: Vec<_> = back.chunks.iter().map(|(_, c)| c.id()).collect();
    assert_eq!(ids, vec![original[0].id(), original[1].id()]);
}

#[test]
fn read_write_read_is_lossless_compressed_or_not() {
    let original: Vec<Arc<Chunk>> = chunk_files().into_iter().map(Arc::new).collect();
    for compress in [true, false] {
        let bytes = write(&original, compress);
        let back = rrd::read_rrd(Buffer::from_vec(bytes), false).unwrap();
        let back: Vec<Chunk> = back.chunks.into_iter().map(|(_, c)| c).collect();
        let original: Vec<Chunk> = chunk_files();
        same_chunks(&back, &original);
    }
}

#[test]
fn our_manifest_reads_back_as_rerun_s_does() {
    let original: Vec<Arc<Chunk>> = chunk_files().into_iter().map(Arc::new).collect();
    let ours = rrd::read_rrd(Buffer::from_vec(write(&original, true)), false).unwrap();
    let theirs = rrd::read_rrd(Buffer::from_vec(rrd_bytes()), false).unwrap();
    let ours = &ours.manifests.unwrap()[0].entries;
    let theirs = &theirs.manifests.unwrap()[0].entries;
    assert_eq!(ours.len(), theirs.len());
    for (a, b) in ours.iter().zip(theirs) {
        // Offsets and sizes differ (our store info, our IPC writer and compressor); the
        // rest must not.
        assert_eq!(
            (&a.chunk_id, &a.entity_path, a.is_static, a.num_rows),
            (&b.chunk_id, &b.entity_path, b.is_static, b.num_rows)
        );
        assert_eq!(a.ranges, b.ranges);
        assert_eq!(a.components, b.components);
    }
}

/// Every prefix of the file: a typed error (or a clean end at a message boundary), the
/// chunks before the cut still decoded, never a panic.
#[test]
fn every_truncation_is_an_error_and_keeps_what_came_before() {
    let bytes = rrd_bytes();
    let total = rrd::read_rrd(Buffer::from_vec(bytes.clone()), false)
        .unwrap()
        .chunks
        .len();
    let mut boundaries = 0;
    for cut in (0..bytes.len())
        .step_by(97)
        .chain([12, 140, 268, 284, bytes.len() - 1])
    {
        let prefix = Buffer::from_vec(bytes[..cut].to_vec());
        match rrd::read_rrd(prefix, true) {
            Err(e) => assert!(cut < 12, "cut {cut}: {e}"),
            Ok(contents) => {
                assert!(contents.chunks.len() <= total);
                if contents.errors.is_empty() {
                    boundaries += 1;
                } else {
                    let error = contents.errors.last().unwrap();
                    assert!(error.offset <= cut as u64, "cut {cut}: {error}");
                }
            }
        }
    }
    assert!(boundaries < 10, "a cut is almost never on a boundary");
}

#[test]
fn bad_headers_are_named() {
    let mut bytes = rrd_bytes();
    bytes[..4].copy_from_slice(b"RRF1");
    let err = RrdReader::new(bytes.as_slice()).err().unwrap();
    assert!(matches!(err.kind, RrdErrorKind::OldFraming { .. }), "{err}");
    bytes[..4].copy_from_slice(b"PK\x03\x04");
    let err = RrdReader::new(bytes.as_slice()).err().unwrap();
    assert!(matches!(err.kind, RrdErrorKind::NotAnRrd { .. }), "{err}");
    assert!(err.to_string().contains("not an .rrd"), "{err}");
    // Shorter than a header: a wrong magic is named as such, a right one as truncated.
    let err = RrdReader::new(&b"PK\x03\x04ab"[..]).err().unwrap();
    assert!(matches!(err.kind, RrdErrorKind::NotAnRrd { .. }), "{err}");
    for short in [&b"RRF2\x00)"[..], b"RR", b""] {
        let err = RrdReader::new(short).err().unwrap();
        assert!(matches!(err.kind, RrdErrorKind::Truncated { .. }), "{err}");
    }
    bytes[..4].copy_from_slice(b"RRF2");
    bytes[5] = 2; // Rerun 0.2
    let err = RrdReader::new(bytes.as_slice()).err().unwrap();
    assert!(
        matches!(err.kind, RrdErrorKind::UnsupportedVersion { .. }),
        "{err}"
    );
}

#[test]
fn a_huge_length_field_is_refused_without_allocating_it() {
    let mut bytes = rrd_bytes();
    // The first message's length: 2^63.
    bytes[20..28].copy_from_slice(&(1u64 << 63).to_le_bytes());
    for contents in [
        rrd::read_rrd(Buffer::from_vec(bytes.clone()), true).unwrap(),
        rrd::read_rrd_from(bytes.as_slice(), true).unwrap(),
    ] {
        let error = &contents.errors[0];
        assert_eq!(error.offset, 28, "{error}");
        assert!(
            matches!(error.kind, RrdErrorKind::Truncated { .. }),
            "{error}"
        );
        assert!(contents.chunks.is_empty());
    }
}

#[test]
fn a_corrupt_payload_spoils_only_its_own_chunk() {
    let mut bytes = rrd_bytes();
    // Inside the first ArrowMsg's LZ4 payload (its body starts at 284).
    for b in &mut bytes[400..440] {
        *b ^= 0x5a;
    }
    let contents = rrd::read_rrd(Buffer::from_vec(bytes.clone()), true).unwrap();
    assert_eq!(contents.errors.len(), 1, "{:?}", contents.errors);
    assert!(!contents.errors[0].is_fatal());
    assert_eq!(contents.chunks.len(), 36);
    assert!(rrd::read_rrd(Buffer::from_vec(bytes), false).is_err());
}

#[test]
fn a_footer_that_disagrees_with_the_body_is_an_error() {
    let mut bytes = rrd_bytes();
    let n = bytes.len();
    bytes[n - 14] ^= 1; // the stream footer's checksum
    let contents = rrd::read_rrd(Buffer::from_vec(bytes), true).unwrap();
    assert_eq!(contents.chunks.len(), 37);
    assert!(
        matches!(contents.errors[0].kind, RrdErrorKind::Footer { .. }),
        "{}",
        contents.errors[0]
    );
}

#[test]
fn blueprint_chunks_are_skipped() {
    let chunks: Vec<Arc<Chunk>> = chunk_files().into_iter().take(3).map(Arc::new).collect();
    let mut blueprint = StoreId::recording("app", "layout");
    blueprint.kind = StoreKind::Blueprint;
    let mut writer = RrdWriter::new(Vec::new(), blueprint).unwrap();
    writer.write_chunk(&chunks[0]).unwrap();
    let blueprint_bytes = writer.finish().unwrap();
    let mut all = write(&chunks, true);
    all.extend_from_slice(&blueprint_bytes); // concatenated streams
    let contents = rrd::read_rrd(Buffer::from_vec(all), false).unwrap();
    assert_eq!(contents.chunks.len(), 3);
    assert_eq!(contents.skipped_blueprint_messages, 1);
    assert_eq!(contents.store_infos.len(), 2);
    let items: Vec<_> = RrdReader::new(blueprint_bytes.as_slice())
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap();
    assert!(
        items
            .iter()
            .any(|i| matches!(i, RrdItem::SkippedBlueprint { .. }))
    );
}

#[test]
fn files_are_written_atomically() {
    let dir = common::ScratchDir::new("rrd");
    let path = dir.join("out.rrd");
    std::fs::write(&path, b"old contents").unwrap();
    let chunks: Vec<Arc<Chunk>> = chunk_files().into_iter().map(Arc::new).collect();
    let info = rrd::StoreInfo::new(StoreId::recording("app", "rec"));
    let size = rrd::write_rrd_file(&path, &info, chunks.iter().cloned(), |_| {}).unwrap();
    // The size returned is the whole file's, footer included.
    assert_eq!(std::fs::metadata(&path).unwrap().len(), size);
    let back = rrd::read_rrd(Buffer::from_vec(std::fs::read(&path).unwrap()), false).unwrap();
    assert_eq!(back.chunks.len(), 37);
    // A write into a directory that does not exist fails and leaves nothing behind.
    let missing = dir.join("no/such/dir/out.rrd");
    let info = rrd::StoreInfo::new(StoreId::recording("app", "rec"));
    assert!(rrd::write_rrd_file(&missing, &info, chunks.iter().cloned(), |_| {}).is_err());
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(leftovers, vec![std::ffi::OsString::from("out.rrd")]);
}

fn eager_store() -> chunkstore::ChunkStore {
    let mut store = chunkstore::ChunkStore::new();
    for chunk in chunk_files() {
        store.insert(chunk).unwrap();
    }
    store
}

#[test]
fn lazy_answers_equal_eager_answers_and_decode_a_fraction() {
    use chunkstore::{LatestAtQuery, RangeQuery, TimeInt, TimeRange};
    let store = eager_store();
    let path = recording().join("a_robot.rrd");
    // One query alone decodes few chunks.
    let mut lazy = rrd::LazyRecording::open(&path).unwrap().unwrap();
    assert_eq!(lazy.stats().chunks_decoded, 0);
    assert_eq!(lazy.entity_paths(), store.entity_paths());
    let robot = chunkstore::EntityPath::parse("/world/robot").unwrap();
    let at = LatestAtQuery::new("frame_id", TimeInt::new(30).unwrap());
    let cell = lazy
        .latest_at(&at, &robot, "Transform3D:translation")
        .unwrap()
        .unwrap();
    let expected = store
        .latest_at(&at, &robot, "Transform3D:translation")
        .unwrap();
    assert_eq!(cell.row_id(), expected.row_id());
    let stats = lazy.stats();
    assert!(stats.chunks_decoded <= 2, "{stats:?}");
    assert!(stats.bytes_read < stats.file_bytes / 4, "{stats:?}");
    // Handed over after one query: the whole recording, as the eager reader loads it.
    let handed_over = lazy.into_store().unwrap();
    assert_eq!(handed_over.stats().num_rows(), store.stats().num_rows());
    assert_eq!(handed_over.entity_paths(), store.entity_paths());

    // Every entity, component and time on every timeline: the same answers.
    for (timeline, times) in [
        ("frame_id", (-1..=62).collect::<Vec<i64>>()),
        ("sim_time", (0..=62).map(|f| f * 50_000_000 - 1).collect()),
    ] {
        let mut lazy = rrd::LazyRecording::open(&path).unwrap().unwrap();
        for &t in &times {
            let query = LatestAtQuery::new(timeline, TimeInt::new(t).unwrap());
            for entity in store.entity_paths() {
                for component in store.component_names(&entity) {
                    let a = lazy.latest_at(&query, &entity, component.as_str()).unwrap();
                    let b = store.latest_at(&query, &entity, component.as_str());
                    assert_eq!(
                        a.map(|c| (c.row_id(), c.time())),
                        b.map(|c| (c.row_id(), c.time())),
                        "{timeline} {t} {entity} {component}"
                    );
                }
            }
        }
        for (lo, hi) in [(0, 10), (25, 35), (i64::MIN + 1, i64::MAX)] {
            let query = RangeQuery::new(
                timeline,
                TimeRange::new(TimeInt::new(lo).unwrap(), TimeInt::new(hi).unwrap()),
            );
            for entity in store.entity_paths() {
                for component in store.component_names(&entity) {
                    let a: Vec<_> = lazy
                        .range(&query, &entity, component.as_str())
                        .unwrap()
                        .iter()
                        .map(|r| (r.row_id(), r.time()))
                        .collect();
                    let b: Vec<_> = store
                        .range(&query, &entity, component.as_str())
                        .iter()
                        .map(|r| (r.row_id(), r.time()))
                        .collect();
                    assert_eq!(a, b, "{timeline} [{lo}, {hi}] {entity} {component}");
                }
            }
        }
    }
}

#[test]
fn lazy_open_needs_a_footer_and_checks_it() {
    let dir = common::ScratchDir::new("lazy");
    let chunks: Vec<Arc<Chunk>> = chunk_files().into_iter().map(Arc::new).collect();
    // No footer: `None`.
    let mut writer = RrdWriter::new(Vec::new(), StoreId::recording("a", "r")).unwrap();
    writer.write_chunk(&chunks[0]).unwrap();
    let no_footer = dir.join("no_footer.rrd");
    std::fs::write(&no_footer, writer.position().to_le_bytes()).unwrap();
    assert!(
        rrd::LazyRecording::open(&no_footer).is_err(),
        "not an rrd at all"
    );
    let unfinished = write(&chunks[..1], true);
    let unfinished = &unfinished[..unfinished.len() - 40];
    std::fs::write(&no_footer, unfinished).unwrap();
    assert!(rrd::LazyRecording::open(&no_footer).unwrap().is_none());
    // A footer whose checksum is wrong: an error naming it.
    let mut bytes = rrd_bytes();
    let n = bytes.len();
    bytes[n - 14] ^= 1;
    let bad = dir.join("bad_crc.rrd");
    std::fs::write(&bad, &bytes).unwrap();
    let err = rrd::LazyRecording::open(&bad).err().unwrap();
    assert!(matches!(err.kind, RrdErrorKind::Footer { .. }), "{err}");
}

/// A footer whose manifest says the chunks are elsewhere than they are: named, at the End
/// message.
#[test]
fn a_manifest_that_disagrees_with_the_body_is_an_error() {
    let chunks: Vec<Arc<Chunk>> = chunk_files().into_iter().take(4).map(Arc::new).collect();
    let in_order = write(&chunks, true);
    let swapped: Vec<Arc<Chunk>> = [1, 0, 2, 3]
        .iter()
        .map(|&i| Arc::clone(&chunks[i]))
        .collect();
    let other = write(&swapped, true);
    // The same messages in another order: the End message sits at the same offset, so the
    // body of one and the footer of the other make a well-framed file.
    let contents = rrd::read_rrd(Buffer::from_vec(other.clone()), false).unwrap();
    let end = contents.manifests.unwrap()[0]
        .entries
        .iter()
        .map(|e| e.byte_offset + e.byte_size)
        .max()
        .unwrap();
    let end = usize::try_from(end).unwrap();
    let mut spliced = other[..end].to_vec();
    spliced.extend_from_slice(&in_order[end..]);
    let contents = rrd::read_rrd(Buffer::from_vec(spliced), true).unwrap();
    assert_eq!(contents.chunks.len(), 4);
    assert_eq!(contents.errors.len(), 1, "{:?}", contents.errors);
    let error = &contents.errors[0];
    assert!(matches!(error.kind, RrdErrorKind::Footer { .. }), "{error}");
    assert!(
        error.to_string().contains("the manifest puts chunk"),
        "{error}"
    );
}

#[test]
fn a_newer_framing_is_named() {
    let mut bytes = rrd_bytes();
    bytes[3] = b'3';
    let err = RrdReader::new(bytes.as_slice()).err().unwrap();
    assert!(
        matches!(err.kind, RrdErrorKind::NewerFraming { .. }),
        "{err}"
    );
}
