//! Writing an object whole or not at all: a local file uploaded as one PUT, or as a
//! multipart upload that is completed only once every part is in, and aborted (no
//! orphaned parts left behind) on an error or when the caller cancels.

use std::io::Read;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use object_store::{ObjectStoreExt, PutPayload, WriteMultipart};

use super::{Location, count_put, request_error, runtime};
use crate::storage::{StorageError, StorageErrorKind, StorageOptions};

/// Files up to this size are one PUT; larger ones a multipart upload of parts this size
/// (S3's least part is 5 MiB).
pub const PART_BYTES: usize = 16 << 20;

/// Parts of one upload in flight at once (what the upload holds in memory: this many
/// parts).
const PARTS_IN_FLIGHT: usize = 4;

/// Uploads the local file `file` to the object `url`, which becomes visible only once
/// whole. `cancel` (Ctrl-C) is checked between parts: set, the upload is aborted and the
/// object not written.
///
/// # Errors
/// As [`Location::resolve`]; a failed, denied or cancelled upload (after it was
/// aborted); the local file's error.
pub fn upload_file(
    file: &Path,
    url: &str,
    options: &StorageOptions,
    cancel: Arc<AtomicBool>,
) -> Result<(), StorageError> {
    upload_to(file, Location::resolve(url, options)?, cancel)
}

/// [`upload_file`] to a resolved location (whose key may hold what a URL would decode,
/// such as a Hive partition's `%2F`).
pub(crate) fn upload_to(
    file: &Path,
    location: Location,
    cancel: Arc<AtomicBool>,
) -> Result<(), StorageError> {
    let url = location.url.clone();
    let url = url.as_str();
    if cancel.load(Ordering::Relaxed) {
        return Err(StorageError::new(
            url,
            StorageErrorKind::Request("cancelled".into()),
        ));
    }
    let local = |e: std::io::Error| {
        StorageError::new(
            url,
            StorageErrorKind::Request(format!("reading {}: {e}", file.display())),
        )
    };
    let size = std::fs::metadata(file).map_err(local)?.len();
    let mut input = std::fs::File::open(file).map_err(local)?;
    let url_owned = url.to_owned();
    if size <= PART_BYTES as u64 {
        let mut bytes = Vec::new();
        input.read_to_end(&mut bytes).map_err(local)?;
        let len = bytes.len() as u64;
        runtime::wait(url, async move {
            location
                .store
                .put(&location.path, PutPayload::from(bytes))
                .await
        })?
        .map_err(|e| request_error(url, &e))?;
        count_put(len);
        return Ok(());
    }
    runtime::wait(url, async move {
        let failed = |e: &object_store::Error| request_error(&url_owned, e);
        let upload = location
            .store
            .put_multipart(&location.path)
            .await
            .map_err(|e| failed(&e))?;
        count_put(0);
        let mut writer = WriteMultipart::new_with_chunk_size(upload, PART_BYTES);
        let mut part = vec![0u8; PART_BYTES];
        let outcome: Result<(), StorageError> = async {
            loop {
                if cancel.load(Ordering::Relaxed) {
                    return Err(StorageError::new(
                        &url_owned,
                        StorageErrorKind::Request("cancelled".into()),
                    ));
                }
                let n = read_full(&mut input, &mut part).map_err(|e| {
                    StorageError::new(
                        &url_owned,
                        StorageErrorKind::Request(format!("reading the output: {e}")),
                    )
                })?;
                if n == 0 {
                    return Ok(());
                }
                writer
                    .wait_for_capacity(PARTS_IN_FLIGHT)
                    .await
                    .map_err(|e| failed(&e))?;
                writer.write(&part[..n]);
                count_put(n as u64);
            }
        }
        .await;
        match outcome {
            Ok(()) => {
                writer.finish().await.map_err(|e| failed(&e))?;
                count_put(0);
                Ok(())
            }
            Err(error) => {
                // Its parts are deleted with it: nothing of it stays in the bucket.
                let _ = writer.abort().await;
                Err(error)
            }
        }
    })?
}

/// Reads until `out` is full or the input ends; how much was read.
fn read_full(input: &mut impl Read, out: &mut [u8]) -> std::io::Result<usize> {
    let mut filled = 0;
    while filled < out.len() {
        match input.read(&mut out[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}

/// [`crate::storage::write_output`] for a URL: written to a staging file, then uploaded.
pub(crate) fn write_staged<T, E>(
    out: &Path,
    options: &StorageOptions,
    cancel: &Arc<AtomicBool>,
    write: impl FnOnce(&Path) -> Result<T, E>,
) -> Result<T, crate::storage::OutputError<E>> {
    use crate::storage::OutputError;
    let url = out.to_string_lossy();
    let name = out
        .file_name()
        .map_or_else(|| "output".into(), |n| n.to_string_lossy().into_owned());
    let staging = std::env::temp_dir().join(format!(
        "chunkstore-upload-{}-{:x}",
        std::process::id(),
        crate::RowId::new().as_u128()
    ));
    let staging_failed = |e: std::io::Error| {
        OutputError::Upload(StorageError::new(
            url.as_ref(),
            StorageErrorKind::Request(format!("staging in {}: {e}", staging.display())),
        ))
    };
    // Registered: Ctrl-C removes it as it removes any unfinished output.
    let (_registered, ()) =
        crate::output::UnfinishedOutput::create(&staging, |dir| std::fs::create_dir(dir))
            .map_err(staging_failed)?;
    let staged = staging.join(name);
    let result = write(&staged)
        .map_err(OutputError::Write)
        .and_then(|value| {
            upload_file(&staged, &url, options, Arc::clone(cancel))
                .map(|()| value)
                .map_err(OutputError::Upload)
        });
    let _ = std::fs::remove_dir_all(&staging);
    result
}
