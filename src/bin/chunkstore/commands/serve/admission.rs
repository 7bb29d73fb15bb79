//! Which log streams the server takes: at most `--max-write-streams` at once, at most
//! [`PER_CONNECTION`] from one connection, each sending its first message within
//! [`FIRST_MESSAGE`]; when every slot is taken, the stream that has sent nothing for the
//! longest (and for at least [`IDLE_GRACE`]) is ended to make room, so that idle streams
//! cannot lock loggers out. Every stream refused or ended leaves one line on stderr with
//! its peer and the reason.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use parking_lot::Mutex;
use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore};
use tonic::Status;

/// Write streams one connection may hold open at once.
pub const PER_CONNECTION: usize = 16;
/// How long a new stream may take to send its first message (the SDK sends its store
/// info at once).
pub const FIRST_MESSAGE: Duration = Duration::from_secs(10);
/// How long a stream must have been idle before it gives way to a new one.
pub const IDLE_GRACE: Duration = Duration::from_secs(10);
/// How long a new stream waits for the slot an idle one gives up.
const HANDOVER: Duration = Duration::from_secs(2);

/// The open write streams.
pub struct Admission {
    slots: Arc<Semaphore>,
    streams: Mutex<Streams>,
}

#[derive(Default)]
struct Streams {
    next_id: u64,
    open: ahash::HashMap<u64, Entry>,
}

struct Entry {
    peer: Option<SocketAddr>,
    last_message: Instant,
    give_way: Arc<Notify>,
}

/// One admitted stream: its slot, released when dropped.
pub struct Admitted {
    id: u64,
    admission: Arc<Admission>,
    /// Notified when the stream must end to make room.
    pub give_way: Arc<Notify>,
    _slot: OwnedSemaphorePermit,
}

impl Admitted {
    /// The stream sent a message.
    pub fn touch(&self) {
        if let Some(entry) = self.admission.streams.lock().open.get_mut(&self.id) {
            entry.last_message = Instant::now();
        }
    }
}

impl Drop for Admitted {
    fn drop(&mut self) {
        self.admission.streams.lock().open.remove(&self.id);
    }
}

/// How a peer is named in a log line.
pub fn peer_name(peer: Option<SocketAddr>) -> String {
    peer.map_or_else(|| "an unknown peer".to_owned(), |p| p.to_string())
}

/// One line on stderr for a stream refused or ended.
pub fn log_refusal(peer: Option<SocketAddr>, status: &Status) {
    tracing::warn!(
        "log stream from {} ended: {} ({:?})",
        peer_name(peer),
        status.message(),
        status.code()
    );
}

impl Admission {
    /// Room for `max_streams` streams at once.
    pub fn new(max_streams: usize) -> Arc<Self> {
        Arc::new(Self {
            slots: Arc::new(Semaphore::new(max_streams)),
            streams: Mutex::new(Streams::default()),
        })
    }

    /// Streams admitted and still open.
    pub fn open_streams(&self) -> usize {
        self.streams.lock().open.len()
    }

    /// Admits a stream from `peer`, or says why not. When every slot is taken, the stream
    /// idle longest (at least [`IDLE_GRACE`]) is told to give way, and this one waits a
    /// moment for its slot.
    pub async fn admit(self: &Arc<Self>, peer: Option<SocketAddr>) -> Result<Admitted, Status> {
        if let Some(peer) = peer {
            let from_peer = self
                .streams
                .lock()
                .open
                .values()
                .filter(|e| e.peer == Some(peer))
                .count();
            if from_peer >= PER_CONNECTION {
                return Err(Status::resource_exhausted(format!(
                    "this connection already has {PER_CONNECTION} log streams open"
                )));
            }
        }
        let slot = if let Ok(slot) = Arc::clone(&self.slots).try_acquire_owned() {
            slot
        } else {
            if !self.make_room() {
                return Err(Status::resource_exhausted(
                    "too many log streams open at once (--max-write-streams), none of them \
                     idle long enough to give way",
                ));
            }
            tokio::time::timeout(HANDOVER, Arc::clone(&self.slots).acquire_owned())
                .await
                .ok()
                .and_then(Result::ok)
                .ok_or_else(|| {
                    Status::resource_exhausted(
                        "too many log streams open at once (--max-write-streams)",
                    )
                })?
        };
        let give_way = Arc::new(Notify::new());
        let mut streams = self.streams.lock();
        let id = streams.next_id;
        streams.next_id += 1;
        streams.open.insert(
            id,
            Entry {
                peer,
                last_message: Instant::now(),
                give_way: Arc::clone(&give_way),
            },
        );
        Ok(Admitted {
            id,
            admission: Arc::clone(self),
            give_way,
            _slot: slot,
        })
    }

    /// Tells the stream idle longest, if idle for [`IDLE_GRACE`], to give way; whether
    /// one was.
    fn make_room(&self) -> bool {
        let streams = self.streams.lock();
        let idlest = streams
            .open
            .values()
            .filter(|e| e.last_message.elapsed() >= IDLE_GRACE)
            .min_by_key(|e| e.last_message);
        match idlest {
            Some(entry) => {
                entry.give_way.notify_one();
                true
            }
            None => false,
        }
    }
}
