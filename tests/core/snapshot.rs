//! Snapshots and the shared store (SEMANTICS.md section 10).
//!
//! The stress test runs one writer and several readers on a [`SharedStore`]. The writer
//! makes random writes (temporal and static inserts, batches, flat and recursive Clears,
//! compaction on insert and on demand, garbage collection, entity and range drops); after
//! each, while it still holds the store alone, it records a digest of the store's answers
//! under the version it is about to publish. That record is the model of each version:
//! `tests/model.rs` checks the single-threaded store's answers against a naive model, and
//! this test checks that every snapshot, on any thread, answers exactly as the store did at
//! its version — every answer of one digest from that one version (no torn answer),
//! versions never going backwards for a reader, old snapshots still answering as they did
//! long after the writer moved on, and every thread finishing (no deadlock).
//!
//! It runs twice: with tiny compaction thresholds (compaction constantly, small indices)
//! and with compaction off, where the indices grow past the small form into persistent
//! sequences and large indices (the copy-on-write paths of `index/`).
//!
//! Size: a few seconds by default; `CHUNKSTORE_STRESS_SECS=600 cargo test --release --test
//! snapshot -- --nocapture` runs each configuration for that long (so twenty minutes in
//! all) and prints what it checked.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::cast_precision_loss,
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    reason = "tests fail loudly; test values are small non-negative integers"
)]

use crate::common;

use std::collections::HashMap;
use std::hash::{DefaultHasher, Hash, Hasher};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use chunkstore::{
    ChunkStore, DataframeQuery, GcOptions, LatestAtQuery, RangeQuery, SharedStore, Snapshot,
    StoreConfig, StoreView, TimeInt, TimeRange,
};
use common::{clear, path, scalars, static_scalar, t};

const ENTITIES: [&str; 6] = ["a", "a/b", "a/b/c", "d", "d/e", "f"];
const MAX_FRAME: u64 = 64;

/// A small deterministic generator (xorshift64*), seeded per thread.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }

    fn entity(&mut self) -> &'static str {
        ENTITIES[self.below(ENTITIES.len() as u64) as usize]
    }

    fn frame(&mut self) -> i64 {
        self.below(MAX_FRAME).cast_signed()
    }
}

/// A digest of every answer the test compares: latest-at of every entity at several
/// times, a range of every entity, the figures, the entity list and a dataframe.
fn digest(view: &StoreView) -> u64 {
    let mut hasher = DefaultHasher::new();
    for entity in ENTITIES {
        let entity = path(entity);
        for at in [0, 7, 20, 33, 50, 63, i64::MAX] {
            let query = LatestAtQuery::new("frame", t(at));
            view.latest_at(&query, &entity, "x")
                .map(|cell| (cell.row_id(), cell.time()))
                .hash(&mut hasher);
        }
        let range = RangeQuery::new("frame", TimeRange::new(t(10), t(40)));
        let rows: Vec<_> = view
            .range(&range, &entity, "x")
            .iter()
            .map(|row| (row.row_id(), row.time()))
            .collect();
        rows.hash(&mut hasher);
    }
    let stats = view.stats();
    (stats.num_rows(), stats.num_chunks()).hash(&mut hasher);
    view.entity_paths().hash(&mut hasher);
    if let Ok(stream) = view.dataframe(&DataframeQuery::new("frame")) {
        stream.schema().fields().len().hash(&mut hasher);
        for batch in stream {
            let batch = batch.unwrap();
            batch.num_rows().hash(&mut hasher);
            for column in batch.columns() {
                column.to_data().hash_slow(&mut hasher);
            }
        }
    }
    hasher.finish()
}

/// Hashing Arrow data by its logical contents (the trait arrow does not provide).
trait HashSlow {
    fn hash_slow(&self, hasher: &mut DefaultHasher);
}

impl HashSlow for arrow_data::ArrayData {
    fn hash_slow(&self, hasher: &mut DefaultHasher) {
        format!("{:?}", arrow_array::make_array(self.clone())).hash(hasher);
    }
}

/// One random write (or a batch of them) made by the writer. Collections and drops happen
/// in one of `shrink_one_in` of the writes that would otherwise make them (a larger value
/// lets the indices grow).
fn random_write(rng: &mut Rng, store: &mut ChunkStore, next_row_id: &mut u128, shrink_one_in: u64) {
    let mut row_id = || {
        *next_row_id += 1;
        *next_row_id
    };
    let mut roll = rng.below(100);
    if ((71..78).contains(&roll) || (83..88).contains(&roll)) && rng.below(shrink_one_in) != 0 {
        roll = 0; // an insert instead
    }
    match roll {
        0..55 => {
            let rows: Vec<_> = (0..=rng.below(5))
                .map(|_| {
                    let value = (rng.below(2) == 0).then(|| vec![rng.below(1000) as f64]);
                    (rng.frame(), row_id(), value)
                })
                .collect();
            store.insert(scalars(rng.entity(), "x", &rows)).unwrap();
        }
        55..62 => {
            let chunk = static_scalar(rng.entity(), "x", row_id(), rng.below(1000) as f64);
            store.insert(chunk).unwrap();
        }
        62..69 => {
            let chunk = clear(rng.entity(), Some(rng.frame()), row_id(), rng.below(2) == 0);
            store.insert(chunk).unwrap();
        }
        69..71 => {
            let chunk = clear(rng.entity(), None, row_id(), rng.below(2) == 0);
            store.insert(chunk).unwrap();
        }
        71..78 => {
            let fraction = 0.1 + rng.below(5) as f64 / 10.0;
            let options = GcOptions::drop_at_least_fraction(fraction)
                .unwrap()
                .with_protect_latest(rng.below(3) as usize);
            store.gc(&options);
        }
        78..83 => {
            store.compact();
        }
        83..85 => {
            store.drop_entity(&path(rng.entity()), rng.below(2) == 0);
        }
        85..88 => {
            let (a, b) = (rng.frame(), rng.frame());
            store.drop_time_range("frame", TimeRange::new(t(a.min(b)), t(a.max(b))));
        }
        _ => {
            // A batch: many inserts, one publication.
            for _ in 0..rng.below(20) {
                let rows = [(rng.frame(), row_id(), Some(vec![1.0]))];
                store.insert(scalars(rng.entity(), "x", &rows)).unwrap();
            }
        }
    }
}

/// What the readers found, summed over all of them.
#[derive(Default)]
struct Checked {
    snapshots: AtomicU64,
    held_rechecks: AtomicU64,
}

/// What a stress run did: writes published, snapshots checked, re-checks of held
/// snapshots, and the most temporal chunks one entity held at once.
struct Stressed {
    writes: u64,
    snapshots: u64,
    rechecks: u64,
    max_entity_chunks: u64,
}

#[allow(
    clippy::too_many_lines,
    reason = "one writer, the readers and the watchdog read best together"
)]
fn stress(
    config: StoreConfig,
    shrink_one_in: u64,
    duration: Duration,
    num_readers: usize,
) -> Stressed {
    let shared = SharedStore::new(ChunkStore::with_config(config).unwrap());
    let history: Arc<Mutex<HashMap<u64, u64>>> = Arc::default();
    history
        .lock()
        .unwrap()
        .insert(shared.snapshot().version(), digest(&shared.snapshot()));
    let stop = Arc::new(AtomicBool::new(false));
    let checked = Arc::new(Checked::default());
    let (done_tx, done_rx) = std::sync::mpsc::channel::<Result<(), String>>();

    let writer = {
        let (shared, history, stop, done) = (
            shared.clone(),
            Arc::clone(&history),
            Arc::clone(&stop),
            done_tx.clone(),
        );
        std::thread::spawn(move || {
            let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
            let mut next_row_id = 0;
            let mut writes = 0u64;
            let mut max_entity_chunks = 0;
            let deadline = Instant::now() + duration;
            let result = (|| {
                while Instant::now() < deadline {
                    shared.write(|store| {
                        random_write(&mut rng, store, &mut next_row_id, shrink_one_in);
                        store.sanity_check().map_err(|e| e.to_string())?;
                        for entity in ENTITIES {
                            if let Some(stats) = store.entity_stats(&path(entity)) {
                                max_entity_chunks =
                                    max_entity_chunks.max(stats.num_temporal_chunks);
                            }
                        }
                        let version = store.snapshot().version();
                        let answers = digest(store);
                        let mut history = history.lock().unwrap();
                        match history.insert(version, answers) {
                            Some(earlier) if earlier != answers => {
                                Err(format!("version {version} changed what the store answers"))
                            }
                            _ => Ok(()),
                        }
                    })?;
                    writes += 1;
                }
                Ok::<_, String>(())
            })();
            stop.store(true, Ordering::Release);
            done.send(result).unwrap();
            (writes, max_entity_chunks)
        })
    };

    let readers: Vec<_> = (0..num_readers)
        .map(|reader| {
            let (shared, history, stop, checked, done) = (
                shared.clone(),
                Arc::clone(&history),
                Arc::clone(&stop),
                Arc::clone(&checked),
                done_tx.clone(),
            );
            std::thread::spawn(move || {
                let mut rng = Rng(reader as u64 + 1);
                let mut held: Vec<(Snapshot, u64)> = Vec::new();
                let result = (|| {
                    let mut last_version = 0;
                    while !stop.load(Ordering::Acquire) {
                        let snapshot = shared.snapshot();
                        let version = snapshot.version();
                        if version < last_version {
                            return Err(format!("version went back: {last_version} -> {version}"));
                        }
                        last_version = version;
                        let answers = digest(&snapshot);
                        let expected = history.lock().unwrap().get(&version).copied();
                        if expected != Some(answers) {
                            return Err(format!(
                                "reader {reader}: snapshot of version {version} answers \
                                 {answers:x}, the store answered {expected:x?}"
                            ));
                        }
                        checked.snapshots.fetch_add(1, Ordering::Relaxed);
                        // Hold a few snapshots for a while: they must keep answering as
                        // they did, however far the writer has gone since.
                        if rng.below(8) == 0 {
                            if held.len() == 4 {
                                held.swap_remove(rng.below(4) as usize);
                            }
                            held.push((snapshot, answers));
                        }
                        for (old, answers) in &held {
                            if digest(old) != *answers {
                                return Err(format!(
                                    "reader {reader}: a held snapshot of version {} changed",
                                    old.version()
                                ));
                            }
                            checked.held_rechecks.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                    Ok(())
                })();
                done.send(result).unwrap();
            })
        })
        .collect();
    drop(done_tx);

    // Every thread reports once; a thread that never does is stuck.
    let limit = Instant::now() + duration + Duration::from_mins(2);
    for _ in 0..=num_readers {
        let left = limit.saturating_duration_since(Instant::now());
        match done_rx.recv_timeout(left) {
            Ok(Ok(())) => {}
            Ok(Err(error)) => {
                stop.store(true, Ordering::Release);
                panic!("{error}");
            }
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                panic!("a thread did not finish: deadlock or livelock")
            }
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => {
                panic!("a thread ended without reporting")
            }
        }
    }
    let (num_writes, max_entity_chunks) = writer.join().unwrap();
    for reader in readers {
        reader.join().unwrap();
    }
    Stressed {
        writes: num_writes,
        snapshots: checked.snapshots.load(Ordering::Relaxed),
        rechecks: checked.held_rechecks.load(Ordering::Relaxed),
        max_entity_chunks,
    }
}

#[test]
fn readers_see_exactly_one_version_while_the_writer_runs() {
    let seconds: u64 = std::env::var("CHUNKSTORE_STRESS_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3);
    let tiny = StoreConfig::DEFAULT
        .with_max_rows(8)
        .with_max_rows_unsorted(4)
        .with_max_bytes(4096);
    let configs = [
        ("tiny thresholds", tiny, 1),
        ("compaction off", StoreConfig::COMPACTION_OFF, 12),
    ];
    for (name, config, shrink_one_in) in configs {
        let run = stress(config, shrink_one_in, Duration::from_secs(seconds), 3);
        println!(
            "stress, {name}: {seconds} s, {} writes published, {} snapshots checked, {} \
             re-checks of held snapshots, up to {} temporal chunks at one entity, zero \
             divergences",
            run.writes, run.snapshots, run.rechecks, run.max_entity_chunks
        );
        assert!(
            run.writes > 0 && run.snapshots > 0,
            "the test exercised nothing"
        );
    }
}

#[test]
fn a_snapshot_is_frozen_and_cannot_be_changed() {
    let mut store = ChunkStore::new();
    store
        .insert(scalars("a", "x", &[(1, 1, Some(vec![1.0]))]))
        .unwrap();
    let snapshot = store.snapshot();
    let version = snapshot.version();
    store
        .insert(scalars("a", "x", &[(2, 2, Some(vec![2.0]))]))
        .unwrap();
    store.insert(clear("a", Some(3), 3, false)).unwrap();
    let query = LatestAtQuery::new("frame", TimeInt::MAX);
    assert!(store.latest_at(&query, &path("a"), "x").is_none());
    let cell = snapshot.latest_at(&query, &path("a"), "x").unwrap();
    assert_eq!(cell.time(), Some(t(1)));
    assert_eq!(snapshot.stats().num_rows(), 1);
    assert_eq!(snapshot.version(), version);
    assert!(store.snapshot().version() > version);
    // Clones share the frozen view.
    let clone = snapshot.clone();
    assert_eq!(clone.version(), version);
    assert_eq!(clone.chunks().len(), 1);
}

#[test]
fn a_snapshot_survives_drops_and_gc_of_everything_it_sees() {
    let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).unwrap();
    for frame in 0..20 {
        let rows = [(frame, frame as u128 + 1, Some(vec![frame as f64]))];
        store.insert(scalars("robot/arm", "x", &rows)).unwrap();
    }
    store.insert(static_scalar("robot", "x", 100, 7.0)).unwrap();
    let before = store.snapshot();
    let answers = digest(&before);
    store.gc(&GcOptions::everything());
    store.drop_entity(&path("robot"), true);
    assert_eq!(store.stats().num_chunks(), 0);
    assert_eq!(digest(&before), answers);
    assert_eq!(before.chunks().len(), 21);
    let range = RangeQuery::new("frame", TimeRange::new(t(0), t(100)));
    assert_eq!(before.range(&range, &path("robot/arm"), "x").num_rows(), 20);
    before.sanity_check().unwrap();
}

#[test]
fn the_shared_store_publishes_every_write_and_batches_at_once() {
    let shared = SharedStore::new(ChunkStore::new());
    let first = shared.snapshot();
    shared
        .insert(scalars("a", "x", &[(1, 1, Some(vec![1.0]))]))
        .unwrap();
    let second = shared.snapshot();
    assert!(second.version() > first.version());
    assert_eq!(first.stats().num_rows(), 0);
    assert_eq!(second.stats().num_rows(), 1);

    let chunks = (2..12).map(|frame| scalars("a", "x", &[(frame, frame as u128, Some(vec![1.0]))]));
    shared.insert_batch(chunks).unwrap();
    let third = shared.snapshot();
    assert_eq!(third.stats().num_rows(), 11);
    assert_eq!(
        third.version(),
        second.version() + 10,
        "one version per insert"
    );

    // Events still reach subscribers, in order, from the writer.
    let seen = Arc::new(Mutex::new(Vec::new()));
    let sink = Arc::clone(&seen);
    shared.write(|store| {
        store.subscribe(move |events| sink.lock().unwrap().push(events.len()));
    });
    shared.write(|store| store.drop_entity(&path("a"), false));
    assert!(!seen.lock().unwrap().is_empty());
    assert_eq!(shared.snapshot().stats().num_chunks(), 0);
    assert_eq!(third.stats().num_rows(), 11);

    // A refused insert changes nothing, and the error comes back.
    shared
        .insert(scalars("b", "x", &[(1, 50, Some(vec![1.0]))]))
        .unwrap();
    let before = shared.snapshot();
    let refused = shared.insert(clear("b", Some(2), 51, false)).and_then(|_| {
        // A Clear is fine; a boolean `x` at `b`, whose `x` holds floats, is not.
        shared.insert(
            chunkstore::Chunk::try_new(
                chunkstore::ChunkId::new(),
                path("b"),
                vec![common::rid(52)],
                vec![],
                vec![("x".into(), common::bool_list(&[Some(true)]))],
            )
            .unwrap(),
        )
    });
    assert!(refused.is_err());
    assert_eq!(
        shared.snapshot().stats().num_rows(),
        before.stats().num_rows() + 1
    );
    let store = shared.try_into_store().unwrap();
    store.sanity_check().unwrap();
}

#[test]
fn a_version_a_reader_drops_last_is_freed_by_the_writer() {
    let shared = SharedStore::new(ChunkStore::with_config(StoreConfig::COMPACTION_OFF).unwrap());
    for frame in 0..10 {
        let rows = [(frame, frame as u128 + 1, Some(vec![1.0]))];
        shared.insert(scalars("a", "x", &rows)).unwrap();
    }
    let collected = |shared: &SharedStore| {
        let snapshot = shared.snapshot();
        let weak: Vec<_> = snapshot.chunks().iter().map(Arc::downgrade).collect();
        shared.write(|store| store.gc(&GcOptions::everything()));
        assert_eq!(shared.snapshot().stats().num_chunks(), 0);
        assert_eq!(
            snapshot.stats().num_chunks(),
            weak.len() as u64,
            "the snapshot still answers"
        );
        (snapshot, weak)
    };
    let alive = |weak: &[std::sync::Weak<chunkstore::Chunk>]| {
        weak.iter().filter(|w| w.upgrade().is_some()).count()
    };

    // The reader drops the last snapshot of the collected version: the writer frees it,
    // not the reader, at its next write...
    let (snapshot, weak) = collected(&shared);
    drop(snapshot);
    assert_eq!(
        alive(&weak),
        10,
        "handed back to the writer, not freed by the reader"
    );
    shared
        .insert(scalars("b", "x", &[(1, 100, Some(vec![1.0]))]))
        .unwrap();
    assert_eq!(alive(&weak), 0, "freed by the next write");

    // ...or when asked to.
    shared
        .insert(scalars("a", "x", &[(1, 200, Some(vec![1.0]))]))
        .unwrap();
    let (snapshot, weak) = collected(&shared);
    drop(snapshot);
    assert_eq!(alive(&weak), 2);
    shared.reclaim();
    assert_eq!(alive(&weak), 0, "freed by reclaim");

    // A snapshot that outlives its store frees what it holds where it is dropped.
    shared
        .insert(scalars("a", "x", &[(2, 300, Some(vec![1.0]))]))
        .unwrap();
    let snapshot = shared.snapshot();
    let weak: Vec<_> = snapshot.chunks().iter().map(Arc::downgrade).collect();
    drop(shared);
    assert_eq!(alive(&weak), 1);
    drop(snapshot);
    assert_eq!(
        alive(&weak),
        0,
        "freed with the last holder once the store is gone"
    );
}
