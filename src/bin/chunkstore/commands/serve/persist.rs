//! `--persist FILE.rrd`: the server's write-ahead log. Every accepted message is appended
//! as an `.rrd` frame (its body as the client sent it) in the order the hub accepted it;
//! a write stream is acknowledged only after the log is flushed and `fdatasync`ed, and a
//! timer syncs once a second besides.
//!
//! What it promises, and how:
//! - **Nothing acknowledged is lost.** The log knows how many of its bytes are durable
//!   (`synced`: whole frames, the last successful sync's). A failed write or sync (a full
//!   disk) may leave part of a frame on disk, so the log stops taking appends until it is
//!   rolled back to `synced` ([`PersistLog::roll_back`]); every rollback starts a new
//!   *epoch*, and a stream is acknowledged only if the sync after its last message
//!   succeeded in the epoch of its first ([`PersistLog::sync`]). Syncs run one at a time,
//!   so a success is never one that follows an unreported failure.
//! - **Damage is never mistaken for a torn tail.** On start, a torn last frame (a write cut
//!   short) is cut off with a warning; any other fault ([`chunkstore::rrd::LogScan`] tells
//!   them apart) refuses to start, naming the offset, and leaves the file as it is.
//! - **One server per log.** The log is locked (`flock`) for as long as the server runs; a
//!   second one refuses to start, naming the holder's pid where `/proc/locks` tells it.
//!
//! When the log holds much more than the stores (after garbage collection), it is
//! rewritten from what the stores hold, beside the original, then renamed over it: a
//! crash at any moment leaves either the old log or the new one, both complete.
//!
//! The log writes through a [`LogDevice`]: the file ([`FileDevice`]), or in tests a disk
//! that fails at a chosen byte.

use std::fs::{File, OpenOptions};
use std::io::{self, Read as _, Seek as _, Write as _};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_buffer::Buffer;
use chunkstore::hub::StoreHub;
use chunkstore::rrd::{LogMsg, log_stream_header, scan_log};
use parking_lot::Mutex;

use super::metrics::Histogram;

/// Frames smaller than this are gathered in memory and written together.
const BUFFER_CAPACITY: usize = 1 << 20;

/// Where the log's bytes go: appended at the end, cut back, made durable.
pub trait LogDevice: Send {
    /// Appends `bytes`. On an error, any prefix of them may have been written.
    fn append(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Cuts the log to its first `len` bytes; later appends go after them.
    fn truncate(&mut self, len: u64) -> io::Result<()>;
    /// Makes what was appended durable; called outside the log's lock (appends go on).
    fn syncer(&self) -> Arc<dyn Fn() -> io::Result<()> + Send + Sync>;
    /// The log's first `len` bytes, as they are on the device.
    fn read_prefix(&mut self, len: u64) -> io::Result<Vec<u8>>;
}

/// The log file, locked for this process.
pub struct FileDevice {
    file: File,
    /// The same file, synced outside the log's lock.
    sync_handle: Arc<File>,
}

impl FileDevice {
    /// Opens (creating) and locks `path`. Another process holding the lock is an error
    /// naming it.
    fn open_locked(path: &Path) -> Result<Self, String> {
        let name = path.display();
        let file = OpenOptions::new()
            .create(true)
            .truncate(false)
            .read(true)
            .write(true)
            .open(path)
            .map_err(|e| format!("{name}: {e}"))?;
        Self::lock(file, path)
    }

    fn lock(file: File, path: &Path) -> Result<Self, String> {
        let name = path.display();
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let holder = lock_holder(&file)
                    .map(|pid| format!(" (pid {pid})"))
                    .unwrap_or_default();
                return Err(format!(
                    "{name} is in use by another server{holder}: two servers appending to \
                     one log would lose each other's messages"
                ));
            }
            Err(std::fs::TryLockError::Error(e)) => return Err(format!("{name}: locking: {e}")),
        }
        let sync_handle = Arc::new(file.try_clone().map_err(|e| format!("{name}: {e}"))?);
        Ok(Self { file, sync_handle })
    }
}

/// The pid holding a `flock` on `file`, from `/proc/locks` (Linux): its lines read
/// `1: FLOCK  ADVISORY  WRITE 1234 fd:01:5678 0 EOF`, the file named by device and inode.
fn lock_holder(file: &File) -> Option<u32> {
    use std::os::unix::fs::MetadataExt as _;
    let inode = file.metadata().ok()?.ino();
    let locks = std::fs::read_to_string("/proc/locks").ok()?;
    locks.lines().find_map(|line| {
        let fields: Vec<&str> = line.split_whitespace().collect();
        let (kind, pid, id) = (fields.get(1)?, fields.get(4)?, fields.get(5)?);
        let file_inode: u64 = id.rsplit(':').next()?.parse().ok()?;
        (*kind == "FLOCK" && file_inode == inode)
            .then(|| pid.parse().ok())
            .flatten()
    })
}

impl LogDevice for FileDevice {
    fn append(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.file.write_all(bytes)
    }

    fn truncate(&mut self, len: u64) -> io::Result<()> {
        self.file.set_len(len)?;
        self.file.seek(io::SeekFrom::Start(len))?;
        Ok(())
    }

    fn syncer(&self) -> Arc<dyn Fn() -> io::Result<()> + Send + Sync> {
        let file = Arc::clone(&self.sync_handle);
        Arc::new(move || file.sync_data())
    }

    fn read_prefix(&mut self, len: u64) -> io::Result<Vec<u8>> {
        let mut bytes = Vec::new();
        self.file.seek(io::SeekFrom::Start(0))?;
        (&mut self.file).take(len).read_to_end(&mut bytes)?;
        self.file.seek(io::SeekFrom::End(0))?;
        Ok(bytes)
    }
}

/// The open log.
pub struct PersistLog {
    path: PathBuf,
    file: Mutex<LogFile>,
    /// Held for the whole of a sync: one at a time, so that one's success never follows
    /// another's unreported failure on the same file.
    sync_lock: Mutex<()>,
    /// How long syncs take.
    sync_latency: Histogram,
}

struct LogFile {
    device: Box<dyn LogDevice>,
    /// Frames not yet handed to the device.
    buffer: Vec<u8>,
    /// Frames this large or larger go to the device directly.
    buffer_capacity: usize,
    /// Bytes handed to the device: whole frames (unless `failed`).
    written: u64,
    /// Bytes known durable: whole frames, as of the last successful sync.
    synced: u64,
    /// Why the log takes no appends: a write or a sync failed, and the device may hold
    /// part of a frame past `synced` until [`PersistLog::roll_back`] cuts it off.
    failed: Option<String>,
    /// How many rollbacks there were.
    epoch: u64,
    /// A rollback dropped what was past `synced` but could not cut the device back.
    cut_pending: bool,
    /// While a rewrite is under way: the messages appended meanwhile, with their
    /// sequence numbers, to append to the new log too.
    captured: Option<Vec<(u64, LogMsg)>>,
    /// What the log held when the server started, to read back into the hub.
    backlog: Option<Vec<LogMsg>>,
}

/// What reading the log back found.
pub struct ReplayReport {
    pub messages: usize,
    pub skipped: usize,
}

/// What [`PersistLog::roll_back`] did.
#[derive(Debug, PartialEq, Eq)]
pub enum RollBack {
    /// The log had not failed: nothing to do.
    Healthy,
    /// Messages past the durable bytes were dropped (a new epoch): what memory holds must
    /// be rebuilt from [`PersistLog::durable_messages`]. `Err` if the device could not be
    /// cut back: the log still takes no appends.
    Dropped(Result<(), String>),
    /// The log had already dropped them, but the device could not be cut back before;
    /// this is the retry.
    Retried(Result<(), String>),
}

impl LogFile {
    fn len(&self) -> u64 {
        self.written + self.buffer.len() as u64
    }

    /// Hands the buffered frames to the device.
    fn flush(&mut self) -> io::Result<()> {
        if self.buffer.is_empty() {
            return Ok(());
        }
        let result = self.device.append(&self.buffer);
        match &result {
            Ok(()) => self.written += self.buffer.len() as u64,
            Err(e) => self.failed = Some(format!("writing: {e}")),
        }
        // Written or not, they are no longer ours to write: after a failure the log is
        // rolled back past them.
        self.buffer.clear();
        result
    }

    fn refuse(&self) -> io::Result<()> {
        match &self.failed {
            Some(why) => Err(io::Error::other(format!(
                "the log takes no writes until it is rolled back ({why})"
            ))),
            None => Ok(()),
        }
    }
}

impl PersistLog {
    /// Opens `path` for appending, creating it if needed, locked for this process; an
    /// existing log is scanned (and kept for [`PersistLog::replay_into`]). A torn tail is
    /// cut off with a warning; any other fault is an error and the file is not touched.
    pub fn create_or_append(path: &Path) -> Result<Self, String> {
        let device = FileDevice::open_locked(path)?;
        Self::open_on(path, Box::new(device), BUFFER_CAPACITY)
    }

    /// [`PersistLog::create_or_append`] on any device (`path` names it in messages),
    /// gathering frames smaller than `buffer_capacity` in memory.
    pub fn open_on(
        path: &Path,
        mut device: Box<dyn LogDevice>,
        buffer_capacity: usize,
    ) -> Result<Self, String> {
        let name = path.display();
        let bytes = device
            .read_prefix(u64::MAX)
            .map_err(|e| format!("{name}: {e}"))?;
        let total = bytes.len() as u64;
        let scan = scan_log(&Buffer::from(bytes));
        if let Some(fault) = &scan.fault {
            if scan.valid_len == 0 && !scan.is_torn_tail() {
                return Err(format!(
                    "{name}: not an .rrd log this server can append to ({fault}); the file is \
                     left as it is"
                ));
            }
            if !scan.is_torn_tail() {
                return Err(format!(
                    "{name}: damaged after byte {} ({fault}): the {} bytes from there on are \
                     not a write cut short and may hold acknowledged messages, so the log is \
                     left as it is; keep a copy, then cut it to its first {} bytes \
                     (truncate -s) to start from what comes before the damage",
                    scan.valid_len,
                    total - scan.valid_len,
                    scan.valid_len
                ));
            }
            tracing::warn!(
                "{name}: dropped a torn last message ({} bytes from byte {}, a write \
                 cut short): {fault}",
                total - scan.valid_len,
                scan.valid_len
            );
        }
        let keep = scan.valid_len;
        if keep < total {
            device.truncate(keep).map_err(|e| format!("{name}: {e}"))?;
        }
        let mut log = LogFile {
            device,
            buffer: Vec::new(),
            buffer_capacity,
            written: keep,
            synced: keep,
            failed: None,
            epoch: 0,
            cut_pending: false,
            captured: None,
            backlog: Some(scan.messages),
        };
        if !scan.open_stream {
            log.buffer.extend_from_slice(&log_stream_header());
        }
        let persist = Self {
            path: path.to_owned(),
            file: Mutex::new(log),
            sync_lock: Mutex::new(()),
            sync_latency: Histogram::default(),
        };
        persist.sync().map_err(|e| format!("{name}: {e}"))?;
        Ok(persist)
    }

    /// The log's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Bytes in the log (written, if not yet synced).
    pub fn len(&self) -> u64 {
        self.file.lock().len()
    }

    /// The current epoch: a stream is acknowledged only if no rollback came between its
    /// first message and its sync.
    pub fn epoch(&self) -> u64 {
        self.file.lock().epoch
    }

    /// Why the log takes no appends, if it does not.
    pub fn failure(&self) -> Option<String> {
        self.file.lock().failed.clone()
    }

    /// Feeds what the log held at start into `hub` (without logging it again). A message
    /// that does not decode or is refused is skipped with a warning: the log is what was
    /// accepted, so that is damage on disk, and the rest is still worth having.
    pub fn replay_into(&self, hub: &StoreHub) -> ReplayReport {
        let backlog = self.file.lock().backlog.take().unwrap_or_default();
        self.restore(hub, backlog)
    }

    fn restore(&self, hub: &StoreHub, messages: Vec<LogMsg>) -> ReplayReport {
        let mut report = ReplayReport {
            messages: 0,
            skipped: 0,
        };
        for (i, msg) in messages.into_iter().enumerate() {
            match hub.restore(&msg) {
                Ok(_) => report.messages += 1,
                Err(e) => {
                    report.skipped += 1;
                    tracing::warn!("{}: message {i} skipped: {e}", self.path.display());
                }
            }
        }
        report
    }

    /// Appends one message (buffered: [`PersistLog::sync`] makes it durable). Refused
    /// while the log has failed.
    pub fn append(&self, seq: u64, msg: &LogMsg) -> io::Result<()> {
        let mut file = self.file.lock();
        file.refuse()?;
        let header = msg.frame_header();
        let body = msg.body().as_slice();
        let frame_len = header.len() + body.len();
        if file.buffer.len() + frame_len > file.buffer_capacity {
            file.flush()?;
        }
        if frame_len >= file.buffer_capacity {
            // An image: straight to the device, not copied through the buffer.
            let written = file.device.append(&header);
            if let Err(e) = written.and_then(|()| file.device.append(body)) {
                file.failed = Some(format!("writing: {e}"));
                return Err(e);
            }
            file.written += frame_len as u64;
        } else {
            file.buffer.extend_from_slice(&header);
            file.buffer.extend_from_slice(body);
        }
        if let Some(captured) = &mut file.captured {
            captured.push((seq, msg.clone()));
        }
        Ok(())
    }

    /// Writes and syncs everything appended so far; returns the epoch it is durable in.
    /// The sync runs outside the lock, so appends go on meanwhile. A failure leaves the
    /// log refusing appends until [`PersistLog::roll_back`].
    pub fn sync(&self) -> io::Result<u64> {
        let _one_at_a_time = self.sync_lock.lock();
        let (target, epoch, syncer) = {
            let mut file = self.file.lock();
            file.refuse()?;
            file.flush()?;
            (file.written, file.epoch, file.device.syncer())
        };
        let started = std::time::Instant::now();
        let outcome = syncer();
        self.sync_latency.observe(started.elapsed());
        let mut file = self.file.lock();
        if let Err(e) = outcome {
            if file.epoch == epoch && file.failed.is_none() {
                file.failed = Some(format!("syncing: {e}"));
            }
            return Err(e);
        }
        if file.epoch != epoch {
            return Err(io::Error::other(
                "the log was rolled back during this sync after a write failed",
            ));
        }
        file.refuse()?;
        file.synced = file.synced.max(target);
        Ok(epoch)
    }

    /// How long syncs took.
    pub fn sync_latency(&self) -> &Histogram {
        &self.sync_latency
    }

    /// [`PersistLog::sync`] if anything was appended since the last.
    pub fn sync_if_dirty(&self) -> io::Result<()> {
        let dirty = {
            let file = self.file.lock();
            file.failed.is_none() && file.len() > file.synced
        };
        if dirty { self.sync().map(drop) } else { Ok(()) }
    }

    /// After a failed write or sync: drops every message past the durable bytes (a new
    /// epoch) and cuts the device back to them, so the log takes appends again. The
    /// caller must then rebuild what memory holds from [`PersistLog::durable_messages`]
    /// (on [`RollBack::Dropped`]), with no appends meanwhile.
    pub fn roll_back(&self) -> RollBack {
        let _no_sync = self.sync_lock.lock();
        let mut file = self.file.lock();
        let Some(why) = file.failed.clone() else {
            return RollBack::Healthy;
        };
        // A retry after a cut that failed: the messages were dropped then.
        let dropped = !file.cut_pending;
        if dropped {
            file.epoch += 1;
        }
        file.buffer.clear();
        file.written = file.synced;
        let synced = file.synced;
        let cut = file
            .device
            .truncate(synced)
            .and_then(|()| (file.device.syncer())());
        let result = match cut {
            Ok(()) => {
                file.failed = None;
                file.cut_pending = false;
                Ok(())
            }
            Err(e) => {
                file.failed = Some(format!("cutting back to byte {synced} after {why}: {e}"));
                file.cut_pending = true;
                Err(e.to_string())
            }
        };
        if dropped {
            RollBack::Dropped(result)
        } else {
            RollBack::Retried(result)
        }
    }

    /// The messages in the durable part of the log: what memory should hold after a
    /// rollback.
    pub fn durable_messages(&self) -> io::Result<Vec<LogMsg>> {
        let mut file = self.file.lock();
        let synced = file.synced;
        let bytes = file.device.read_prefix(synced)?;
        if (bytes.len() as u64) < synced {
            return Err(io::Error::other("the log is shorter than what was synced"));
        }
        Ok(scan_log(&Buffer::from(bytes)).messages)
    }

    /// Rebuilds `hub` from the log's durable messages (after a rollback), without
    /// logging them again.
    pub fn restore_durable(&self, hub: &StoreHub) -> io::Result<ReplayReport> {
        let messages = self.durable_messages()?;
        Ok(self.restore(hub, messages))
    }

    /// Rewrites the log from what `hub` holds now (plus what arrives meanwhile) and renames
    /// it over the old one. Returns the sizes before and after.
    pub fn rewrite(&self, hub: &StoreHub) -> io::Result<(u64, u64)> {
        // Capture first, then take the history: a message accepted in between is in both
        // and is written once (by sequence number).
        let epoch = {
            let mut file = self.file.lock();
            file.refuse()?;
            if file.captured.is_some() {
                return Err(io::Error::other("a rewrite is already under way"));
            }
            file.captured = Some(Vec::new());
            file.epoch
        };
        let replay = hub.replay();
        let history_seq = replay.seq;
        let temporary = self.path.with_extension("rrd.rewrite");
        let written = (|| -> io::Result<(io::BufWriter<File>, u64)> {
            let file = File::create(&temporary)?;
            let mut out = io::BufWriter::with_capacity(BUFFER_CAPACITY, file);
            let header = log_stream_header();
            out.write_all(&header)?;
            let mut len = header.len() as u64;
            for msg in replay.into_messages() {
                len += write_frame(&mut out, &msg.map_err(io::Error::other)?)?;
            }
            Ok((out, len))
        })();
        let _no_sync = self.sync_lock.lock();
        let mut file = self.file.lock();
        let captured = file.captured.take().unwrap_or_default();
        let abandon = |e: io::Error| {
            let _ = std::fs::remove_file(&temporary);
            Err(e)
        };
        let (mut out, mut len) = match written {
            Ok(written) => written,
            Err(e) => return abandon(e),
        };
        // What memory held may include messages a failed write then dropped: a rewrite
        // from it would make them durable.
        if file.epoch != epoch || file.failed.is_some() {
            return abandon(io::Error::other("a write failed during the rewrite"));
        }
        let finished = (|| -> io::Result<FileDevice> {
            for (seq, msg) in &captured {
                if *seq > history_seq {
                    len += write_frame(&mut out, msg)?;
                }
            }
            // What was buffered for the old log is in the new one (captured).
            out.flush()?;
            let new = out.into_inner().map_err(io::IntoInnerError::into_error)?;
            new.sync_all()?;
            // Locked before it takes the log's name: a server starting meanwhile finds
            // either file locked.
            let device = FileDevice::lock(new, &self.path).map_err(io::Error::other)?;
            std::fs::rename(&temporary, &self.path)?;
            if let Some(dir) = self.path.parent().filter(|p| !p.as_os_str().is_empty()) {
                File::open(dir)?.sync_all()?;
            }
            Ok(device)
        })();
        let mut device = match finished {
            Ok(device) => device,
            Err(e) => return abandon(e),
        };
        device.file.seek(io::SeekFrom::End(0))?;
        let before = file.len();
        file.device = Box::new(device);
        file.buffer.clear();
        file.written = len;
        file.synced = len;
        Ok((before, len))
    }
}

/// Writes `msg` as an `.rrd` frame; returns the bytes written.
fn write_frame(out: &mut impl io::Write, msg: &LogMsg) -> io::Result<u64> {
    let header = msg.frame_header();
    out.write_all(&header)?;
    out.write_all(msg.body().as_slice())?;
    Ok((header.len() + msg.body().len()) as u64)
}

#[cfg(test)]
#[path = "persist_tests.rs"]
mod tests;
