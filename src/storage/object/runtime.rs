//! The runtime `object_store`'s futures run on, and the one way the crate's synchronous
//! code waits for them.

use std::future::Future;
use std::sync::OnceLock;

use crate::storage::{StorageError, StorageErrorKind};

/// Runs `future`, a request on the object `url`, on the crate's runtime and waits for it
/// on this thread. Safe to call from inside another Tokio runtime's task (the wait is a
/// plain channel's, which never tries to drive a runtime), where `Runtime::block_on` would
/// panic. The runtime failing to start, or dropping the request, is an error on `url`.
pub(super) fn wait<F>(url: &str, future: F) -> Result<F::Output, StorageError>
where
    F: Future + Send + 'static,
    F::Output: Send + 'static,
{
    let (sender, receiver) = std::sync::mpsc::sync_channel(1);
    spawn(url, async move {
        let _ = sender.send(future.await);
    })?;
    receiver.recv().map_err(|_| {
        StorageError::new(
            url,
            StorageErrorKind::Request("the request was dropped before it finished".into()),
        )
    })
}

/// Starts `future`, a request on the object `url`, on the crate's runtime, without
/// waiting for it.
pub(super) fn spawn<F>(url: &str, future: F) -> Result<(), StorageError>
where
    F: Future<Output = ()> + Send + 'static,
{
    static RUNTIME: OnceLock<Result<tokio::runtime::Runtime, String>> = OnceLock::new();
    let runtime = RUNTIME
        .get_or_init(|| {
            // Two workers: requests wait on the network, not on a core; the number of
            // requests in flight is set by the callers, not by these threads.
            tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .thread_name("chunkstore-storage")
                .enable_all()
                .build()
                .map_err(|e| format!("cannot start the object-store runtime: {e}"))
        })
        .as_ref()
        .map_err(|e| StorageError::new(url, StorageErrorKind::Request(e.clone())))?;
    drop(runtime.spawn(future));
    Ok(())
}
