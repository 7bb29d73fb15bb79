//! `--persist FILE.rrd`: the server's write-ahead log. Every accepted message is appended
//! as an `.rrd` frame (its body as the client sent it) in the order the hub accepted it;
//! a write stream is acknowledged only after the log is flushed and `fdatasync`ed, and a
//! timer syncs once a second besides. On start the file is read back (a torn last message,
//! from a crash mid-write, is cut off with one warning) and appended to.
//!
//! When the log holds much more than the stores (after garbage collection), it is
//! rewritten from what the stores hold, beside the original, then renamed over it: a
//! crash at any moment leaves either the old log or the new one, both complete.

use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow_buffer::Buffer;
use chunkstore::hub::StoreHub;
use chunkstore::rrd::{LogMsg, log_stream_header, scan_log};
use parking_lot::Mutex;

/// The open log.
pub struct PersistLog {
    path: PathBuf,
    file: Mutex<LogFile>,
}

struct LogFile {
    out: BufWriter<File>,
    /// A second handle on the same file, synced outside the lock.
    sync_handle: Arc<File>,
    len: u64,
    dirty: bool,
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

impl PersistLog {
    /// Opens `path` for appending, creating it if needed; an existing log is scanned (and
    /// kept for [`PersistLog::replay_into`]). A torn tail is cut off with a warning; bytes
    /// that are not `.rrd` framing are an error (the file is not touched).
    pub fn create_or_append(path: &Path) -> Result<Self, String> {
        let name = path.display();
        let existing = match std::fs::read(path) {
            Ok(bytes) => Some(bytes),
            Err(e) if e.kind() == io::ErrorKind::NotFound => None,
            Err(e) => return Err(format!("{name}: {e}")),
        };
        let mut backlog = Vec::new();
        let mut needs_header = true;
        let mut keep = 0u64;
        if let Some(bytes) = existing {
            let total = bytes.len() as u64;
            let scan = scan_log(&Buffer::from(bytes));
            if let Some(fault) = &scan.fault {
                if !scan.is_torn_tail() {
                    return Err(format!(
                        "{name}: not an .rrd log this server can append to: {fault}"
                    ));
                }
                eprintln!(
                    "warning: {name}: dropped a torn last message ({} bytes from byte {}, \
                     a write cut short): {fault}",
                    total - scan.valid_len,
                    scan.valid_len
                );
            }
            keep = scan.valid_len;
            needs_header = !scan.open_stream;
            backlog = scan.messages;
        }
        let file = OpenOptions::new()
            .create(true)
            .truncate(false)
            .read(true)
            .write(true)
            .open(path)
            .map_err(|e| format!("{name}: {e}"))?;
        file.set_len(keep).map_err(|e| format!("{name}: {e}"))?;
        let mut file = file;
        io::Seek::seek(&mut file, io::SeekFrom::End(0)).map_err(|e| format!("{name}: {e}"))?;
        let sync_handle = Arc::new(file.try_clone().map_err(|e| format!("{name}: {e}"))?);
        let mut log = LogFile {
            out: BufWriter::with_capacity(1 << 20, file),
            sync_handle,
            len: keep,
            dirty: false,
            captured: None,
            backlog: Some(backlog),
        };
        if needs_header {
            let header = log_stream_header();
            log.out
                .write_all(&header)
                .map_err(|e| format!("{name}: {e}"))?;
            log.len += header.len() as u64;
            log.dirty = true;
        }
        let persist = Self {
            path: path.to_owned(),
            file: Mutex::new(log),
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
        self.file.lock().len
    }

    /// Feeds what the log held at start into `hub` (without logging it again). A message
    /// that does not decode or is refused is skipped with a warning: the log is what was
    /// accepted, so that is damage on disk, and the rest is still worth having.
    pub fn replay_into(&self, hub: &StoreHub) -> ReplayReport {
        let backlog = self.file.lock().backlog.take().unwrap_or_default();
        let mut report = ReplayReport {
            messages: 0,
            skipped: 0,
        };
        for (i, msg) in backlog.into_iter().enumerate() {
            match hub.restore(&msg) {
                Ok(_) => report.messages += 1,
                Err(e) => {
                    report.skipped += 1;
                    eprintln!("warning: {}: message {i} skipped: {e}", self.path.display());
                }
            }
        }
        report
    }

    /// Appends one message (buffered: [`PersistLog::sync`] makes it durable).
    pub fn append(&self, seq: u64, msg: &LogMsg) -> io::Result<()> {
        let mut file = self.file.lock();
        file.len += write_frame(&mut file.out, msg)?;
        file.dirty = true;
        if let Some(captured) = &mut file.captured {
            captured.push((seq, msg.clone()));
        }
        Ok(())
    }

    /// Flushes and syncs everything appended so far. The sync runs outside the lock, so
    /// appends go on meanwhile.
    pub fn sync(&self) -> io::Result<()> {
        let handle = {
            let mut file = self.file.lock();
            file.out.flush()?;
            file.dirty = false;
            Arc::clone(&file.sync_handle)
        };
        handle.sync_data()
    }

    /// [`PersistLog::sync`] if anything was appended since the last.
    pub fn sync_if_dirty(&self) -> io::Result<()> {
        if self.file.lock().dirty {
            self.sync()
        } else {
            Ok(())
        }
    }

    /// Rewrites the log from what `hub` holds now (plus what arrives meanwhile) and renames
    /// it over the old one. Returns the sizes before and after.
    pub fn rewrite(&self, hub: &StoreHub) -> io::Result<(u64, u64)> {
        // Capture first, then take the history: a message accepted in between is in both
        // and is written once (by sequence number).
        {
            let mut file = self.file.lock();
            if file.captured.is_some() {
                return Err(io::Error::other("a rewrite is already under way"));
            }
            file.captured = Some(Vec::new());
        }
        let replay = hub.replay();
        let history_seq = replay.seq;
        let temporary = self.path.with_extension("rrd.rewrite");
        let written = (|| -> io::Result<(BufWriter<File>, u64)> {
            let file = File::create(&temporary)?;
            let mut out = BufWriter::with_capacity(1 << 20, file);
            let header = log_stream_header();
            out.write_all(&header)?;
            let mut len = header.len() as u64;
            for msg in replay.into_messages() {
                len += write_frame(&mut out, &msg.map_err(io::Error::other)?)?;
            }
            Ok((out, len))
        })();
        let mut file = self.file.lock();
        let captured = file.captured.take().unwrap_or_default();
        let (mut out, mut len) = match written {
            Ok(written) => written,
            Err(e) => {
                let _ = std::fs::remove_file(&temporary);
                return Err(e);
            }
        };
        let finished = (|| -> io::Result<()> {
            for (seq, msg) in &captured {
                if *seq > history_seq {
                    len += write_frame(&mut out, msg)?;
                }
            }
            out.flush()?;
            out.get_ref().sync_all()?;
            std::fs::rename(&temporary, &self.path)?;
            if let Some(dir) = self.path.parent().filter(|p| !p.as_os_str().is_empty()) {
                File::open(dir)?.sync_all()?;
            }
            Ok(())
        })();
        if let Err(e) = finished {
            let _ = std::fs::remove_file(&temporary);
            return Err(e);
        }
        let before = file.len;
        // The old handle's unsynced bytes are in the new file too (captured): drop them.
        let sync_handle = Arc::new(out.get_ref().try_clone()?);
        file.out = out;
        file.sync_handle = sync_handle;
        file.len = len;
        file.dirty = false;
        Ok((before, len))
    }
}

/// Writes `msg` as an `.rrd` frame; returns the bytes written.
fn write_frame(out: &mut impl Write, msg: &LogMsg) -> io::Result<u64> {
    let header = msg.frame_header();
    out.write_all(&header)?;
    out.write_all(msg.body().as_slice())?;
    Ok((header.len() + msg.body().len()) as u64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use chunkstore::StoreConfig;
    use chunkstore::rrd::{StoreId, StoreInfo};

    #[test]
    fn a_log_reads_back_cuts_a_torn_tail_and_refuses_garbage() {
        let dir = std::env::temp_dir().join(format!("chunkstore-persist-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("log.rrd");
        let _ = std::fs::remove_file(&path);
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
        log.append(3, &msg).unwrap();
        log.sync().unwrap();
        drop(log);
        let again = PersistLog::create_or_append(&path).unwrap();
        assert_eq!(again.file.lock().backlog.as_ref().map(Vec::len), Some(2));
        drop(again);

        std::fs::write(&path, b"this is not a log").unwrap();
        let err = PersistLog::create_or_append(&path).err().unwrap();
        assert!(err.contains("not an .rrd log"), "{err}");
        assert_eq!(std::fs::read(&path).unwrap(), b"this is not a log");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_rewrite_keeps_what_the_stores_hold_and_what_came_after() {
        let dir = std::env::temp_dir().join(format!("chunkstore-rewrite-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("log.rrd");
        let _ = std::fs::remove_file(&path);
        let log = Arc::new(PersistLog::create_or_append(&path).unwrap());
        let listener_log = Arc::clone(&log);
        let hub = StoreHub::with_listener(
            StoreConfig::DEFAULT,
            Box::new(move |seq, msg: &LogMsg| {
                listener_log.append(seq, msg).map_err(|e| e.to_string())
            }),
        )
        .unwrap();
        let id = StoreId::recording("a", "r");
        let chunk = |frame: i64| {
            let values: Vec<f64> = (0..500).map(f64::from).collect();
            chunkstore::ChunkBuilder::new(
                chunkstore::ChunkId::new(),
                chunkstore::EntityPath::parse("/x").unwrap(),
            )
            .with_row(
                chunkstore::RowId::new(),
                [(chunkstore::Timeline::sequence("frame"), frame)],
                [(
                    "x",
                    std::sync::Arc::new(arrow_array::Float64Array::from(values))
                        as arrow_array::ArrayRef,
                )],
            )
            .build()
            .unwrap()
        };
        hub.ingest(&LogMsg::from_store_info(&StoreInfo::new(id.clone())))
            .unwrap();
        for frame in 0..100 {
            hub.ingest(&LogMsg::from_chunk(&id, &chunk(frame), false).unwrap())
                .unwrap();
        }
        hub.collect_garbage(hub.heap_bytes() / 5);
        let (before, after) = log.rewrite(&hub).unwrap();
        assert!(after < before / 2, "{before} -> {after}");
        // Appends go to the new log.
        hub.ingest(&LogMsg::from_chunk(&id, &chunk(1000), false).unwrap())
            .unwrap();
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
}
