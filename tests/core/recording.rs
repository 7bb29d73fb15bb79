//! The one door to a recording (`chunkstore::recording`, SEMANTICS.md section 11): every
//! kind of source opens through it, a lazy and a loaded recording answer every read alike,
//! and each bad source is its own typed error.

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a test fails loudly"
)]

use chunkstore::recording::{
    LoadFault, LoadObserver, LoadedRecording, OpenError, OpenOptions, ProgressUnit, Recording,
    RecordingReader, SourceKind,
};
use chunkstore::rrd::StreamHeader;
use chunkstore::{LatestAtQuery, RangeQuery, TimeInt, TimeRange};

use crate::common::{self, ScratchDir, path};

fn robot_rrd() -> std::path::PathBuf {
    common::robot_recording().join("a_robot.rrd")
}

fn robot_dir() -> std::path::PathBuf {
    common::robot_recording().join("chunks")
}

fn eager() -> OpenOptions {
    OpenOptions::default().with_lazy(false)
}

#[test]
fn sources_are_told_apart_by_their_contents() {
    let scratch = ScratchDir::new("recording-kinds");
    assert_eq!(SourceKind::detect(&robot_rrd()).unwrap(), SourceKind::Rrd);
    assert_eq!(
        SourceKind::detect(&robot_dir()).unwrap(),
        SourceKind::ChunkDirectory
    );
    // A chunk file under a name that says nothing of its kind.
    let renamed = scratch.join("data.bin");
    std::fs::copy(&common::robot_chunk_files()[0], &renamed).unwrap();
    assert_eq!(SourceKind::detect(&renamed).unwrap(), SourceKind::IpcFile);

    let text = scratch.join("notes.rrd");
    std::fs::write(&text, "hello").unwrap();
    let error = SourceKind::detect(&text).unwrap_err();
    assert!(
        matches!(&error, OpenError::UnknownFormat { head, .. } if head == b"hello"),
        "{error:?}"
    );
    assert!(
        error
            .to_string()
            .contains("neither an .rrd file nor Arrow IPC")
    );

    let missing = scratch.join("missing.rrd");
    let error = SourceKind::detect(&missing).unwrap_err();
    assert!(matches!(error, OpenError::Io { ref path, .. } if *path == missing));
}

/// Every read, from the robot recording opened lazily, loaded from the same `.rrd`, and
/// loaded from its chunk files: the same answers (SEMANTICS.md section 11).
#[test]
fn lazy_and_loaded_recordings_answer_alike() {
    let mut lazy = Recording::open(&robot_rrd(), &OpenOptions::default(), &mut ()).unwrap();
    let mut loaded = Recording::open(&robot_rrd(), &eager(), &mut ()).unwrap();
    let mut directory = Recording::open(&robot_dir(), &OpenOptions::default(), &mut ()).unwrap();
    assert!(lazy.is_lazy() && !loaded.is_lazy() && !directory.is_lazy());
    assert_eq!(lazy.kind(), SourceKind::Rrd);
    assert_eq!(directory.kind(), SourceKind::ChunkDirectory);
    assert_eq!(
        lazy.store_info().map(|i| i.store_id.recording_id.clone()),
        loaded.store_info().map(|i| i.store_id.recording_id.clone())
    );

    let entities = loaded.reader().entity_paths();
    assert!(entities.len() > 3, "{entities:?}");
    assert_eq!(lazy.reader().entity_paths(), entities);
    assert_eq!(directory.reader().entity_paths(), entities);
    let timelines = loaded.reader().timelines();
    assert_eq!(lazy.reader().timelines(), timelines);
    for timeline in &timelines {
        let span = loaded.reader().time_range(timeline.name());
        assert!(span.is_some());
        assert_eq!(lazy.reader().time_range(timeline.name()), span);
        assert_eq!(
            lazy.reader().time_type(timeline.name()).unwrap(),
            timeline.time_type()
        );
    }

    let mut answers = 0;
    for entity in &entities {
        let components = loaded.reader().component_names(entity);
        assert_eq!(lazy.reader().component_names(entity), components);
        for component in &components {
            for at in [0, 7, 30, 59, i64::MAX] {
                let query = LatestAtQuery::new("frame_id", TimeInt::new(at).unwrap());
                let mut reads = [&mut lazy, &mut loaded, &mut directory].map(|recording| {
                    let cell = recording
                        .reader()
                        .latest_at(&query, entity, component.as_str());
                    cell.unwrap().map(|c| (c.time(), c.row_id(), c.cell()))
                });
                answers += usize::from(reads[0].is_some());
                let first = reads[0].take();
                assert!(
                    reads[1..].iter().all(|r| *r == first),
                    "{entity} {component} @ {at}"
                );
            }
            let range = RangeQuery::new("frame_id", TimeRange::EVERYTHING);
            let rows = [&mut lazy, &mut loaded].map(|recording| {
                let result = recording.reader().range(&range, entity, component.as_str());
                let result = result.unwrap();
                result
                    .iter()
                    .map(|r| (r.time(), r.row_id()))
                    .collect::<Vec<_>>()
            });
            assert_eq!(rows[0], rows[1], "{entity} {component}");
        }
    }
    assert!(answers > 20, "the sweep found answers ({answers})");
    // The lazy one decoded chunks to answer; loading the rest gives the whole store.
    let (rows, chunks) = lazy.reader().num_rows_and_chunks();
    let store = lazy.into_store().unwrap();
    assert_eq!(store.stats().num_rows(), rows);
    assert!(chunks >= store.stats().num_chunks());
}

#[test]
fn an_unknown_timeline_names_the_known_ones() {
    let mut recording = Recording::open(&robot_rrd(), &OpenOptions::default(), &mut ()).unwrap();
    let error = recording.reader().time_type("frame").unwrap_err();
    assert_eq!(error.name, "frame");
    assert_eq!(error.known, ["frame_id", "log_time", "sim_time"]);
    // The same error from a store's view.
    let store = common::robot();
    let view_error = RecordingReader::view(&store)
        .time_type("frame")
        .unwrap_err();
    assert_eq!(view_error, error);
    assert_eq!(
        error.to_string(),
        "unknown timeline \"frame\" (the store has: frame_id, log_time, sim_time)"
    );
}

/// What a load tells its observer, in order.
#[derive(Default)]
struct Told {
    headers: usize,
    started: Vec<(u64, ProgressUnit)>,
    progressed: u64,
    finished: usize,
    skipped: Vec<String>,
}

impl LoadObserver for Told {
    fn header(&mut self, _header: StreamHeader) {
        self.headers += 1;
    }
    fn started(&mut self, total: u64, unit: ProgressUnit) {
        self.started.push((total, unit));
    }
    fn progressed(&mut self, done: u64) {
        assert!(done >= self.progressed, "progress never goes back");
        self.progressed = done;
    }
    fn finished(&mut self) {
        self.finished += 1;
    }
    fn skipped(&mut self, fault: &LoadFault) {
        self.skipped.push(fault.to_string());
    }
}

#[test]
fn a_load_reports_progress_and_keeps_what_was_asked() {
    let mut told = Told::default();
    let size = std::fs::metadata(robot_rrd()).unwrap().len();
    let options = eager()
        .with_keep_source_order(true)
        .with_track_row_sources(true)
        .with_compact(true);
    let loaded = LoadedRecording::load(&robot_rrd(), &options, &mut told).unwrap();
    assert_eq!(told.headers, 1);
    assert_eq!(told.started, [(size, ProgressUnit::Bytes)]);
    assert_eq!(told.progressed, size);
    assert_eq!(told.finished, 1);
    assert!(told.skipped.is_empty());
    assert!(loaded.header.is_some() && loaded.store_info.is_some());
    // Compaction merged chunks (the recording's 37 into 8); each row still names the
    // chunk of the file it came from.
    assert!(loaded.in_source_order.len() as u64 > loaded.store.stats().num_chunks());
    let sources: std::collections::HashSet<_> =
        loaded.in_source_order.iter().map(|c| c.id()).collect();
    for chunk in loaded.store.chunks() {
        for &row_id in chunk.row_ids() {
            assert!(sources.contains(&loaded.row_source(row_id, chunk.id())));
        }
    }

    let mut told = Told::default();
    let files = common::robot_chunk_files().len() as u64;
    LoadedRecording::load(&robot_dir(), &OpenOptions::default(), &mut told).unwrap();
    assert_eq!(told.started, [(files, ProgressUnit::Files)]);
    assert_eq!(told.progressed, files);
}

#[test]
fn bad_sources_are_typed_errors_and_skip_bad_loads_the_rest() {
    let scratch = ScratchDir::new("recording-bad");
    let empty = scratch.join("empty");
    std::fs::create_dir(&empty).unwrap();
    let error = Recording::open(&empty, &OpenOptions::default(), &mut ()).unwrap_err();
    assert!(matches!(error, OpenError::NoChunkFiles { .. }), "{error:?}");

    // A directory with one broken chunk file among good ones.
    let dir = scratch.join("dir");
    std::fs::create_dir(&dir).unwrap();
    for file in common::robot_chunk_files() {
        std::fs::copy(&file, dir.join(file.file_name().unwrap())).unwrap();
    }
    let first = common::robot_chunk_files()[0]
        .file_name()
        .unwrap()
        .to_owned();
    std::fs::write(dir.join(&first), b"ARROW1 and then nothing").unwrap();
    let error = Recording::open(&dir, &OpenOptions::default(), &mut ()).unwrap_err();
    assert!(error.is_skippable(), "{error:?}");
    assert!(matches!(&error, OpenError::Fault(fault) if matches!(**fault, LoadFault::File { .. })));
    let mut told = Told::default();
    let skip_bad = OpenOptions::default().with_skip_bad(true);
    let recording = Recording::open(&dir, &skip_bad, &mut told).unwrap();
    assert_eq!(told.skipped.len(), 1, "{:?}", told.skipped);
    assert!(
        told.skipped[0].starts_with("skipped "),
        "{:?}",
        told.skipped
    );
    assert!(recording.loaded().unwrap().store.stats().num_rows() > 0);

    // Every file broken: nothing to load, even skipping.
    let broken = scratch.join("broken");
    std::fs::create_dir(&broken).unwrap();
    std::fs::write(broken.join("x.arrow"), b"garbage").unwrap();
    let error = Recording::open(&broken, &skip_bad, &mut ()).unwrap_err();
    assert!(
        matches!(error, OpenError::NoReadableFile { .. }),
        "{error:?}"
    );

    // A truncated `.rrd`: the message it ends in is the fault; skipping, the rest loads.
    let bytes = std::fs::read(robot_rrd()).unwrap();
    let truncated = scratch.join("truncated.rrd");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let error = Recording::open(&truncated, &OpenOptions::default(), &mut ()).unwrap_err();
    assert!(
        matches!(&error, OpenError::Fault(fault) if matches!(**fault, LoadFault::Message { .. })),
        "{error:?}"
    );
    let mut told = Told::default();
    let recording = Recording::open(&truncated, &skip_bad, &mut told).unwrap();
    assert!(!recording.is_lazy());
    assert_eq!(told.skipped.len(), 1);
    assert!(
        told.skipped[0].starts_with("stopped reading"),
        "{:?}",
        told.skipped
    );
}

#[test]
fn a_recording_is_chosen_by_its_id() {
    let scratch = ScratchDir::new("recording-choice");
    let identity =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("testdata/rerun-0.41/identity");
    let both = scratch.join("both.rrd");
    let mut bytes = std::fs::read(identity.join("out_of_order.rrd")).unwrap();
    bytes.extend(std::fs::read(robot_rrd()).unwrap());
    std::fs::write(&both, bytes).unwrap();
    for lazy in [true, false] {
        let options = OpenOptions::default().with_lazy(lazy);
        let error = Recording::open(&both, &options, &mut ()).unwrap_err();
        assert!(error.is_recording_choice(), "{error:?}");
        let chosen = options
            .clone()
            .with_recording("out-of-order-rec".to_owned());
        let mut recording = Recording::open(&both, &chosen, &mut ()).unwrap();
        assert_eq!(recording.is_lazy(), lazy);
        let entities = recording.reader().entity_paths();
        assert!(entities.contains(&path("/plot/a")), "{entities:?}");
        assert!(!entities.iter().any(|e| e.to_string().starts_with("/world")));
        let wrong = options.with_recording("nope".to_owned());
        let error = Recording::open(&both, &wrong, &mut ()).unwrap_err();
        assert!(error.is_recording_choice(), "{error:?}");
        assert!(error.to_string().contains("nope"), "{error}");
    }
}
