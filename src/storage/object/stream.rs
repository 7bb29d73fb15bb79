//! [`ObjectStream`]: an object read once from start to end, as one GET whose body arrives
//! while it is read (a file without a footer, read whole).

use std::io::Read;
use std::path::Path as FsPath;
use std::sync::mpsc::{Receiver, sync_channel};

use bytes::Bytes;
use futures::StreamExt;
use object_store::GetOptions;

use super::{Location, ObjectReader, count_get, request_error, runtime};
use crate::storage::{StorageError, StorageErrorKind, StorageOptions};

/// Pieces of the body received ahead of the reader (each what the connection delivered,
/// typically tens of kilobytes).
const PIECES_AHEAD: usize = 64;

/// An object read once, start to end: one GET, its body handed to [`Read`] as it arrives.
#[derive(Debug)]
pub struct ObjectStream {
    url: String,
    size: u64,
    pieces: Receiver<Result<Bytes, StorageError>>,
    current: Bytes,
}

impl ObjectStream {
    /// Starts the GET of the object `url` names (waiting for its headers: a missing
    /// object is an error here, not at the first read).
    ///
    /// # Errors
    /// As [`super::ObjectReader::open`].
    pub fn open(url: &FsPath, options: &StorageOptions) -> Result<Self, StorageError> {
        let location = Location::of_path(url, options)?;
        Self::start(location, GetOptions::default(), None)
    }

    /// Starts the GET of the whole object `reader` reads, at the version it opened
    /// (`If-Match` its `ETag`, and its size checked).
    ///
    /// # Errors
    /// As [`super::ObjectReader::open`]; [`StorageErrorKind::Changed`] if the object was
    /// replaced since `reader` opened it.
    pub fn of_version(reader: &ObjectReader) -> Result<Self, StorageError> {
        let options = GetOptions {
            if_match: reader.e_tag().map(str::to_owned),
            ..GetOptions::default()
        };
        Self::start(reader.location().clone(), options, Some(reader.size()))
    }

    fn start(
        location: Location,
        options: GetOptions,
        size: Option<u64>,
    ) -> Result<Self, StorageError> {
        let url = location.url.clone();
        let result = runtime::wait(&url, async move {
            location.store.get_opts(&location.path, options).await
        })?
        .map_err(|e| request_error(&url, &e))?;
        count_get(0);
        if size.is_some_and(|size| size != result.meta.size) {
            return Err(StorageError::new(&url, StorageErrorKind::Changed));
        }
        let size = result.meta.size;
        let (sender, pieces) = sync_channel(PIECES_AHEAD);
        let body_url = url.clone();
        runtime::spawn(&url, async move {
            let mut body = result.into_stream();
            while let Some(piece) = body.next().await {
                let piece = piece.map_err(|e| request_error(&body_url, &e));
                if let Ok(bytes) = &piece {
                    super::BYTES_FETCHED
                        .fetch_add(bytes.len() as u64, std::sync::atomic::Ordering::Relaxed);
                }
                let failed = piece.is_err();
                // The reader stopped early: the rest of the body is not wanted.
                if sender.send(piece).is_err() || failed {
                    break;
                }
            }
        })?;
        Ok(Self {
            url,
            size,
            pieces,
            current: Bytes::new(),
        })
    }

    /// The object's size.
    pub fn size(&self) -> u64 {
        self.size
    }

    /// The object's URL.
    pub fn url(&self) -> &str {
        &self.url
    }
}

impl Read for ObjectStream {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        while self.current.is_empty() {
            match self.pieces.recv() {
                Ok(Ok(bytes)) => self.current = bytes,
                Ok(Err(error)) => return Err(error.into_io()),
                Err(_) => return Ok(0), // the body ended
            }
        }
        let n = self.current.len().min(out.len());
        out[..n].copy_from_slice(&self.current[..n]);
        self.current = self.current.slice(n..);
        Ok(n)
    }
}
