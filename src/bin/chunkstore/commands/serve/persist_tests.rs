//! The write-ahead log's tests: reading back, rewriting, locking, and fault injection in
//! the style of redb's crash tests: a scripted session of interleaved write streams run
//! on a disk that fails one write (then has room again), fails one sync, or stops (the
//! process killed), at every byte offset; after each, a restart from what the disk holds
//! (as a killed process leaves it, or a power cut) keeps every acknowledged message and
//! never more than was written, and what the server served after the failure is exactly
//! what the log kept.

use std::collections::BTreeMap;
use std::io;
use std::path::Path;
use std::sync::Arc;

use chunkstore::StoreConfig;
use chunkstore::hub::StoreHub;
use chunkstore::rrd::{LogMsg, StoreId, StoreInfo};
use parking_lot::Mutex;

use super::super::{ReadMode, ServerState, StateOptions};
use super::*;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("chunkstore-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn chunk_msg(recording: &str, frame: i64, values: usize) -> LogMsg {
    let values: Vec<f64> = (0..u32::try_from(values).unwrap()).map(f64::from).collect();
    let chunk = chunkstore::ChunkBuilder::new(
        chunkstore::ChunkId::new(),
        chunkstore::EntityPath::parse("/x").unwrap(),
    )
    .with_row(
        chunkstore::RowId::new(),
        [(chunkstore::Timeline::sequence("frame"), frame)],
        [(
            "x",
            Arc::new(arrow_array::Float64Array::from(values)) as arrow_array::ArrayRef,
        )],
    )
    .build()
    .unwrap();
    LogMsg::from_chunk(&StoreId::recording("app", recording), &chunk, false).unwrap()
}

/// Rows per recording.
fn rows(hub: &StoreHub) -> BTreeMap<String, u64> {
    hub.recordings()
        .iter()
        .map(|r| {
            (
                r.info.store_id.recording_id.to_string(),
                r.snapshot.stats().num_rows(),
            )
        })
        .collect()
}

#[test]
fn a_log_reads_back_cuts_a_torn_tail_and_refuses_garbage_and_damage() {
    let dir = temp_dir("persist");
    let path = dir.join("log.rrd");
    let msg = LogMsg::from_store_info(&StoreInfo::new(StoreId::recording("a", "r")));
    {
        let log = PersistLog::create_or_append(&path).unwrap();
        log.append(1, &msg).unwrap();
        log.append(2, &msg).unwrap();
        log.sync().unwrap();
    }
    // Tear the last message.
    let len = std::fs::metadata(&path).unwrap().len();
    let file = OpenOptions::new().write(true).open(&path).unwrap();
    file.set_len(len - 3).unwrap();
    drop(file);
    let log = PersistLog::create_or_append(&path).unwrap();
    let hub = StoreHub::new(StoreConfig::DEFAULT).unwrap();
    let report = log.replay_into(&hub);
    assert_eq!((report.messages, report.skipped), (1, 0));
    assert_eq!(hub.recordings().len(), 1);
    for seq in 3..6 {
        log.append(seq, &msg).unwrap();
    }
    log.sync().unwrap();
    drop(log);
    let again = PersistLog::create_or_append(&path).unwrap();
    assert_eq!(again.file.lock().backlog.as_ref().map(Vec::len), Some(4));
    drop(again);

    // One damaged byte in the middle (the high byte of the second message's length) is
    // no torn tail: the server refuses to start, and the file is left as it is.
    let whole = std::fs::read(&path).unwrap();
    let frame = 16 + msg.body().len();
    let mut damaged = whole.clone();
    damaged[12 + frame + 15] = 0x40;
    std::fs::write(&path, &damaged).unwrap();
    let err = PersistLog::create_or_append(&path).err().unwrap();
    assert!(
        err.contains(&format!("damaged after byte {}", 12 + frame)),
        "{err}"
    );
    assert!(!err.contains('\n'), "{err}");
    assert_eq!(std::fs::read(&path).unwrap(), damaged);

    std::fs::write(&path, b"this is not a log").unwrap();
    let err = PersistLog::create_or_append(&path).err().unwrap();
    assert!(err.contains("not an .rrd log"), "{err}");
    assert_eq!(std::fs::read(&path).unwrap(), b"this is not a log");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_second_server_on_the_same_log_is_refused_naming_the_holder() {
    let dir = temp_dir("lock");
    let path = dir.join("log.rrd");
    let first = PersistLog::create_or_append(&path).unwrap();
    let err = PersistLog::create_or_append(&path).err().unwrap();
    assert!(err.contains("in use by another server"), "{err}");
    assert!(
        err.contains(&format!("pid {}", std::process::id())),
        "{err}"
    );
    drop(first);
    PersistLog::create_or_append(&path).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_rewrite_keeps_what_the_stores_hold_and_what_came_after_and_stays_locked() {
    let dir = temp_dir("rewrite");
    let path = dir.join("log.rrd");
    let log = Arc::new(PersistLog::create_or_append(&path).unwrap());
    let listener_log = Arc::clone(&log);
    let hub = StoreHub::with_listener(
        StoreConfig::DEFAULT,
        Box::new(move |seq, msg: &LogMsg| listener_log.append(seq, msg).map_err(|e| e.to_string())),
    )
    .unwrap();
    let id = StoreId::recording("app", "r");
    hub.ingest(&LogMsg::from_store_info(&StoreInfo::new(id.clone())))
        .unwrap();
    for frame in 0..100 {
        hub.ingest(&chunk_msg("r", frame, 500)).unwrap();
    }
    hub.collect_garbage(hub.heap_bytes() / 5);
    let (before, after) = log.rewrite(&hub).unwrap();
    assert!(after < before / 2, "{before} -> {after}");
    // The new file is locked too.
    let err = PersistLog::create_or_append(&path).err().unwrap();
    assert!(err.contains("in use by another server"), "{err}");
    // Appends go to the new log.
    hub.ingest(&chunk_msg("r", 1000, 500)).unwrap();
    log.sync().unwrap();
    assert!(!dir.join("log.rrd.rewrite").exists());
    let rows = hub.recordings()[0].snapshot.stats().num_rows();
    drop(hub);
    drop(log);

    let again = PersistLog::create_or_append(&path).unwrap();
    let copy = StoreHub::new(StoreConfig::DEFAULT).unwrap();
    let report = again.replay_into(&copy);
    assert_eq!(report.skipped, 0);
    assert_eq!(copy.recordings()[0].snapshot.stats().num_rows(), rows);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A disk in memory that misbehaves once, as told.
#[derive(Default)]
struct Disk {
    /// What the operating system holds: what a killed process leaves.
    bytes: Vec<u8>,
    /// What the last successful sync made durable: what a power cut leaves.
    durable: Vec<u8>,
    /// Bytes appended so far, over the whole session.
    appended: u64,
    /// The append that would pass this many bytes writes up to it and fails (a full
    /// disk); later appends succeed (room was made).
    fail_write_at: Option<u64>,
    /// The sync of this number (counting from 1) fails.
    fail_sync: Option<u32>,
    syncs: u32,
    /// The process is killed once this many bytes were appended: nothing more reaches
    /// the disk.
    stop_at: Option<u64>,
    stopped: bool,
}

struct FaultyDevice(Arc<Mutex<Disk>>);

impl LogDevice for FaultyDevice {
    fn append(&mut self, bytes: &[u8]) -> io::Result<()> {
        let mut disk = self.0.lock();
        if disk.stopped {
            return Err(io::Error::other("killed"));
        }
        let room = [disk.fail_write_at, disk.stop_at]
            .into_iter()
            .flatten()
            .map(|at| at.saturating_sub(disk.appended))
            .min()
            .unwrap_or(u64::MAX);
        let n = usize::try_from(room).unwrap_or(usize::MAX).min(bytes.len());
        disk.bytes.extend_from_slice(&bytes[..n]);
        disk.appended += n as u64;
        if n == bytes.len() {
            return Ok(());
        }
        if disk.stop_at == Some(disk.appended) {
            disk.stopped = true;
            return Err(io::Error::other("killed"));
        }
        disk.fail_write_at = None;
        Err(io::Error::new(io::ErrorKind::StorageFull, "no space left"))
    }

    fn truncate(&mut self, len: u64) -> io::Result<()> {
        let mut disk = self.0.lock();
        if disk.stopped {
            return Err(io::Error::other("killed"));
        }
        let len = usize::try_from(len).unwrap();
        disk.bytes.truncate(len);
        Ok(())
    }

    fn syncer(&self) -> Arc<dyn Fn() -> io::Result<()> + Send + Sync> {
        let disk = Arc::clone(&self.0);
        Arc::new(move || {
            let mut disk = disk.lock();
            disk.syncs += 1;
            if disk.stopped || disk.fail_sync == Some(disk.syncs) {
                return Err(io::Error::other("I/O error"));
            }
            disk.durable = disk.bytes.clone();
            Ok(())
        })
    }

    fn read_prefix(&mut self, len: u64) -> io::Result<Vec<u8>> {
        let disk = self.0.lock();
        let len = usize::try_from(len).unwrap_or(usize::MAX);
        Ok(disk.bytes[..len.min(disk.bytes.len())].to_vec())
    }
}

/// One step of the scripted session.
enum Step {
    /// Stream `n` sends a message (its recording is `s{n}`).
    Send(usize, LogMsg),
    /// Stream `n` ends and asks to be acknowledged.
    Finish(usize),
    /// The once-a-second timer syncs.
    Tick,
}

/// Four streams, interleaved, with small and (past the buffer) large messages and timer
/// syncs between.
fn script() -> (Vec<Step>, BTreeMap<String, u64>) {
    use Step::{Finish, Send, Tick};
    let info = |n: usize| {
        LogMsg::from_store_info(&StoreInfo::new(StoreId::recording("app", format!("s{n}"))))
    };
    let chunk = |n: usize, frame: i64, values: usize| chunk_msg(&format!("s{n}"), frame, values);
    let steps = vec![
        Send(0, info(0)),
        Send(0, chunk(0, 0, 1)),
        Send(1, info(1)),
        Send(0, chunk(0, 1, 2)),
        Send(1, chunk(1, 0, 40)),
        Finish(1),
        Send(0, chunk(0, 2, 1)),
        Tick,
        Send(2, chunk(2, 0, 3)),
        Finish(0),
        Send(2, chunk(2, 1, 1)),
        Send(3, info(3)),
        Tick,
        Send(2, chunk(2, 2, 60)),
        Send(3, chunk(3, 0, 1)),
        Finish(3),
        Finish(2),
    ];
    let written = BTreeMap::from([
        ("s0".to_owned(), 3),
        ("s1".to_owned(), 1),
        ("s2".to_owned(), 3),
        ("s3".to_owned(), 1),
    ]);
    (steps, written)
}

/// What a session did: the streams acknowledged, what the server held at its end, and
/// whether the process was killed.
struct Session {
    acknowledged: Vec<String>,
    served: BTreeMap<String, u64>,
}

fn options() -> StateOptions {
    StateOptions {
        memory_limit: None,
        read_mode: ReadMode::Snapshot,
        max_write_streams: 8,
        max_message_bytes: 1 << 20,
        storage: chunkstore::storage::StorageOptions::default(),
        retention: Vec::new(),
    }
}

/// Runs the script on `disk` (empty) as the server's write path does.
fn run_session(disk: &Arc<Mutex<Disk>>, steps: &[Step]) -> Session {
    let path = Path::new("faulty.rrd");
    // A disk that fails at once: the server does not start (and the restart finds a torn
    // stream header).
    let Ok(log) = PersistLog::open_on(path, Box::new(FaultyDevice(Arc::clone(disk))), 256) else {
        return Session {
            acknowledged: Vec::new(),
            served: BTreeMap::new(),
        };
    };
    let state = ServerState::start(Some(Arc::new(log)), Vec::new(), &options()).unwrap();
    let mut streams: BTreeMap<usize, Option<super::super::write::WriteStream>> = BTreeMap::new();
    let mut acknowledged = Vec::new();
    for step in steps {
        if disk.lock().stopped {
            break;
        }
        match step {
            Step::Send(n, msg) => {
                let stream = streams
                    .entry(*n)
                    .or_insert_with(|| state.begin_stream().ok());
                if let Some(writer) = stream
                    && state.write(writer, msg, msg.decoded_len()).is_err()
                {
                    *stream = None;
                    if state.log_failed() {
                        state.recover_log();
                    }
                }
            }
            Step::Finish(n) => {
                if let Some(Some(writer)) = streams.remove(n)
                    && state.finish(&writer).is_ok()
                {
                    acknowledged.push(format!("s{n}"));
                }
            }
            Step::Tick => {
                if let Some(log) = &state.persist
                    && log.sync_if_dirty().is_err()
                {
                    state.recover_log();
                }
            }
        }
    }
    Session {
        acknowledged,
        served: rows(&state.hub),
    }
}

/// What a server restarted on `image` holds; a log it refuses fails the test.
fn restart(image: Vec<u8>, what: &str) -> BTreeMap<String, u64> {
    let disk = Arc::new(Mutex::new(Disk {
        bytes: image,
        ..Disk::default()
    }));
    let log = PersistLog::open_on(
        Path::new("restarted.rrd"),
        Box::new(FaultyDevice(disk)),
        256,
    )
    .unwrap_or_else(|e| panic!("{what}: the restart refused the log: {e}"));
    let hub = StoreHub::new(StoreConfig::DEFAULT).unwrap();
    let report = log.replay_into(&hub);
    assert_eq!(report.skipped, 0, "{what}: a message did not read back");
    rows(&hub)
}

/// Every acknowledged recording whole, none more than written.
fn check_restart(
    restored: &BTreeMap<String, u64>,
    session: &Session,
    written: &BTreeMap<String, u64>,
    what: &str,
) {
    for recording in &session.acknowledged {
        assert_eq!(
            restored.get(recording),
            written.get(recording),
            "{what}: acknowledged {recording} lost rows ({restored:?})"
        );
    }
    for (recording, n) in restored {
        assert!(
            n <= &written[recording],
            "{what}: {recording} has more rows than written"
        );
    }
}

/// The session once undisturbed: how many bytes and syncs it takes.
fn undisturbed() -> (u64, u32) {
    let (steps, written) = script();
    let disk = Arc::new(Mutex::new(Disk::default()));
    let session = run_session(&disk, &steps);
    assert_eq!(session.acknowledged.len(), 4);
    assert_eq!(session.served, written);
    let disk = disk.lock();
    (disk.appended, disk.syncs)
}

#[test]
fn a_disk_that_fails_one_write_at_any_byte_loses_nothing_acknowledged() {
    let (steps, written) = script();
    let (total, _) = undisturbed();
    assert!(total > 1_000, "a session of {total} bytes");
    for at in 0..=total {
        let disk = Arc::new(Mutex::new(Disk {
            fail_write_at: Some(at),
            ..Disk::default()
        }));
        let session = run_session(&disk, &steps);
        check_failed_disk(
            &disk,
            &session,
            &written,
            &format!("a write failing at byte {at}"),
        );
    }
}

/// After a session on a disk that failed and recovered: what the server served is what
/// its log kept (nothing it dropped), and restarts from what a kill and what a power cut
/// leave keep every acknowledged message, never more than written.
fn check_failed_disk(
    disk: &Arc<Mutex<Disk>>,
    session: &Session,
    written: &BTreeMap<String, u64>,
    what: &str,
) {
    let (bytes, durable) = {
        let disk = disk.lock();
        (disk.bytes.clone(), disk.durable.clone())
    };
    let killed = restart(bytes, what);
    assert_eq!(session.served, killed, "{what}: served what the log lost");
    check_restart(&killed, session, written, what);
    check_restart(&restart(durable, what), session, written, what);
}

#[test]
fn a_disk_that_fails_one_sync_loses_nothing_acknowledged() {
    let (steps, written) = script();
    let (_, syncs) = undisturbed();
    for fail in 1..=syncs {
        let disk = Arc::new(Mutex::new(Disk {
            fail_sync: Some(fail),
            ..Disk::default()
        }));
        let what = format!("sync {fail} failing");
        let session = run_session(&disk, &steps);
        assert!(
            session.acknowledged.len() < 4,
            "{what}: every stream acknowledged"
        );
        check_failed_disk(&disk, &session, &written, &what);
    }
}

#[test]
fn a_process_killed_at_any_byte_keeps_every_acknowledged_message() {
    let (steps, written) = script();
    let (total, _) = undisturbed();
    for at in 0..=total {
        let disk = Arc::new(Mutex::new(Disk {
            stop_at: Some(at),
            ..Disk::default()
        }));
        let session = run_session(&disk, &steps);
        let what = format!("killed at byte {at}");
        let (bytes, durable) = {
            let disk = disk.lock();
            (disk.bytes.clone(), disk.durable.clone())
        };
        check_restart(&restart(bytes.clone(), &what), &session, &written, &what);
        check_restart(&restart(durable.clone(), &what), &session, &written, &what);
        // A power cut that kept part of what was not synced: a torn tail.
        if bytes.starts_with(&durable) && bytes.len() > durable.len() {
            let half = durable.len() + (bytes.len() - durable.len()) / 2;
            check_restart(
                &restart(bytes[..half].to_vec(), &what),
                &session,
                &written,
                &what,
            );
        }
    }
}
