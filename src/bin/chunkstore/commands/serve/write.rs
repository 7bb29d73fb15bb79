//! The write path of a log stream, apart from the network: each message ingested under the
//! write gate, the stream acknowledged only once the log has synced it in the epoch its
//! first message went into, and after any failed write or sync the log rolled back to its
//! durable bytes and memory rebuilt from them, so that nothing the log lost is served
//! (live readers that had it are ended and read the history again).

use std::sync::Arc;

use chunkstore::hub::IngestError;
use chunkstore::rrd::{DecodedLogMsg, LogMsg};
use tonic::Status;

use super::persist::RollBack;
use super::{Live, ServerState, preload};

/// One write stream's progress.
pub struct WriteStream {
    /// Messages taken so far.
    pub index: u64,
    /// The log's epoch when its first message was taken: a rollback after it dropped
    /// messages of the stream's that were not yet durable.
    epoch: Option<u64>,
}

/// The status a refused message ends its stream with.
fn refused(index: u64, error: &IngestError) -> Status {
    let text = format!("message {index} of this stream: {error}");
    match error {
        IngestError::Listener(_) => Status::unavailable(text),
        _ => Status::invalid_argument(text),
    }
}

/// The status of a stream whose messages a rollback may have dropped.
fn rolled_back(index: u64) -> Status {
    Status::unavailable(format!(
        "message {index} of this stream: the server's log failed to write earlier messages \
         of this stream and dropped them; nothing of this stream is acknowledged"
    ))
}

impl ServerState {
    /// A new write stream; refused while the log cannot be written (after trying to roll
    /// it back once more). Blocking, if the log failed.
    pub fn begin_stream(&self) -> Result<WriteStream, Status> {
        if let Some(log) = &self.persist
            && log.failure().is_some()
        {
            self.recover_log();
            if let Some(why) = log.failure() {
                return Err(Status::unavailable(format!(
                    "the server's log cannot be written ({why}); writes resume once it can"
                )));
            }
        }
        Ok(WriteStream {
            index: 0,
            epoch: None,
        })
    }

    /// Ingests one message of `stream` (decoded and validated, then stored and appended
    /// to the log), counting `decoded_len` ([`LogMsg::decoded_len`], which the caller
    /// has for the memory check) in the metrics. A refused message ends the stream. After
    /// an error, the caller calls [`ServerState::recover_log`] if
    /// [`ServerState::log_failed`] (off the async threads: it may rebuild memory).
    pub fn write(
        &self,
        stream: &mut WriteStream,
        msg: &LogMsg,
        decoded_len: u64,
    ) -> Result<(), Status> {
        // Decoded here rather than by the hub, to count rows by recording.
        let decoded = msg.decode().map_err(IngestError::Decode);
        let (recording, rows) = match &decoded {
            Ok(DecodedLogMsg::Chunk { store_id, chunk }) => {
                (Some(&store_id.recording_id), chunk.num_rows() as u64)
            }
            Ok(DecodedLogMsg::StoreInfo(info)) => (Some(&info.store_id.recording_id), 0),
            Ok(DecodedLogMsg::BlueprintChunk { store_id }) => (Some(&store_id.recording_id), 0),
            _ => (None, 0),
        };
        let recording: Arc<str> = recording.map_or_else(|| Arc::from(""), Arc::clone);
        let ingested = {
            let _gate = self.write_gate.read();
            let rolled_back = self.persist.as_ref().is_some_and(|log| {
                let epoch = log.epoch();
                *stream.epoch.get_or_insert(epoch) != epoch || log.failure().is_some()
            });
            if rolled_back {
                Err(None)
            } else {
                decoded.and_then(|d| self.hub.apply(msg, d)).map_err(Some)
            }
        };
        let index = stream.index;
        match ingested {
            Ok(_) => {
                stream.index += 1;
                self.metrics.ingested(&recording, rows, decoded_len);
                Ok(())
            }
            Err(None) => Err(rolled_back(index)),
            Err(Some(error)) => {
                self.metrics.refused(&recording);
                let status = refused(index, &error);
                if matches!(error, IngestError::Listener(_)) {
                    tracing::warn!("{}", status.message());
                }
                Err(status)
            }
        }
    }

    /// Ends `stream`: with a log, syncs it, and acknowledges only if the sync succeeded
    /// in the epoch of the stream's first message. Blocking (the sync).
    pub fn finish(&self, stream: &WriteStream) -> Result<(), Status> {
        let Some(log) = &self.persist else {
            return Ok(());
        };
        match log.sync() {
            Ok(epoch) if stream.epoch.is_none_or(|first| first == epoch) => Ok(()),
            Ok(_) => Err(rolled_back(stream.index)),
            Err(e) => {
                tracing::warn!("syncing {}: {e}", log.path().display());
                self.recover_log();
                Err(Status::unavailable(format!(
                    "syncing the server's log: {e}; nothing of this stream is acknowledged"
                )))
            }
        }
    }

    /// The log failed and is not yet rolled back.
    pub fn log_failed(&self) -> bool {
        self.persist
            .as_ref()
            .is_some_and(|log| log.failure().is_some())
    }

    /// After a failed write or sync: rolls the log back to its durable bytes and, if that
    /// dropped messages, rebuilds memory from the sources and the durable log, with no
    /// message ingested meanwhile; live readers are told to read the history again.
    pub fn recover_log(&self) {
        let Some(log) = &self.persist else {
            return;
        };
        let _gate = self.write_gate.write();
        let name = log.path().display();
        match log.roll_back() {
            RollBack::Healthy | RollBack::Retried(Err(_)) => return,
            RollBack::Retried(Ok(())) => {
                tracing::info!("{name}: cut back to its durable bytes; taking writes again");
                return;
            }
            RollBack::Dropped(Ok(())) => tracing::warn!(
                "{name}: a write failed; the messages after the last sync were \
                 dropped (none was acknowledged) and the log takes writes again"
            ),
            RollBack::Dropped(Err(e)) => tracing::warn!(
                "{name}: a write failed and the log could not be cut back to its \
                 durable bytes ({e}); no writes are taken until it can"
            ),
        }
        self.hub.clear();
        self.query_sessions.forget();
        for source in &self.sources {
            if let Err(e) = preload(&self.hub, source, &self.storage) {
                tracing::warn!("loading {} again: {e}", source.display());
            }
        }
        if let Err(e) = log.restore_durable(&self.hub) {
            tracing::warn!("{name}: reading back its durable messages: {e}");
        }
        if let Some(limit) = self.memory_limit {
            self.collect_garbage(limit);
        }
        let _ = self.live.send(Live::RolledBack);
    }
}

/// Runs `work` (a sync, a rollback) off the async runtime's threads.
pub async fn blocking<T: Send + 'static>(
    state: &Arc<ServerState>,
    work: impl FnOnce(&ServerState) -> T + Send + 'static,
) -> Result<T, Status> {
    let state = Arc::clone(state);
    tokio::task::spawn_blocking(move || work(&state))
        .await
        .map_err(|e| Status::internal(format!("a server task failed: {e}")))
}
