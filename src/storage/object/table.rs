//! [`ObjectTable`]: a Delta table under a prefix in a bucket (features `object-store` and
//! `parquet`). Files are uploaded whole ([`upload_file`](super::upload_file)'s way) before
//! the commit names them, and a commit is a conditional PUT (`If-None-Match: *`), which
//! S3, GCS and Azure refuse when the log entry exists: two writers never both commit one
//! version.

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use futures::StreamExt;
use object_store::path::Path as ObjectPath;
use object_store::{ObjectStoreExt, PutMode, PutOptions, PutPayload};

use super::{Location, count_get, count_listed, count_lists, count_put, request_error, runtime};
use crate::parquet::delta::{DeltaError, StagingDir, TableStore};
use crate::storage::{StorageError, StorageErrorKind, StorageOptions};

/// Files uploaded at once while a commit's files are placed.
const UPLOADS_IN_FLIGHT: usize = 8;

/// A Delta table under the prefix `url` (`s3://bucket/tables/episodes/`).
#[derive(Clone, Debug)]
pub struct ObjectTable {
    /// The prefix's URL, without its trailing `/`.
    url: String,
    root: Location,
    cancel: Arc<AtomicBool>,
}

impl ObjectTable {
    /// The table under `url`; `cancel` (Ctrl-C), once set, aborts the upload in progress
    /// and fails the write (which then deletes what it uploaded).
    ///
    /// # Errors
    /// As [`Location::resolve`].
    pub fn new(
        url: &str,
        options: &StorageOptions,
        cancel: Arc<AtomicBool>,
    ) -> Result<Self, StorageError> {
        let url = url.trim_end_matches('/').to_owned();
        let root = Location::resolve(&url, options)?;
        Ok(Self { url, root, cancel })
    }

    /// The object at `relative` under the table, its key exactly that (a partition's
    /// `%2F` stays as it is: a URL would decode it).
    fn at(&self, relative: &str) -> Result<Location, DeltaError> {
        let url = format!("{}/{relative}", self.url);
        let key = if self.root.path.as_ref().is_empty() {
            relative.to_owned()
        } else {
            format!("{}/{relative}", self.root.path)
        };
        let path = ObjectPath::parse(&key).map_err(|e| {
            storage_error(StorageError::new(
                &url,
                StorageErrorKind::BadUrl(format!("not an object key: {e}")),
            ))
        })?;
        Ok(Location {
            url,
            store: Arc::clone(&self.root.store),
            path,
        })
    }

    fn log(&self, name: &str) -> Result<Location, DeltaError> {
        self.at(&format!("{}/{name}", crate::parquet::delta::log::LOG_DIR))
    }
}

fn storage_error(error: StorageError) -> DeltaError {
    DeltaError::io(error.url.clone(), error.into_io())
}

impl TableStore for ObjectTable {
    fn name(&self) -> String {
        format!("{}/", self.url)
    }

    fn check_new(&self) -> Result<(), DeltaError> {
        let store = Arc::clone(&self.root.store);
        let prefix = self.root.path.clone();
        let url = self.name();
        let first = runtime::wait(&url, async move {
            let prefix = (!prefix.as_ref().is_empty()).then_some(&prefix);
            store.list(prefix).next().await.transpose()
        })
        .map_err(storage_error)?
        .map_err(|e| storage_error(request_error(&url, &e)))?;
        count_lists(1);
        match first {
            Some(_) => Err(DeltaError::Exists { table: url }),
            None => Ok(()),
        }
    }

    fn log_files(&self) -> Result<Vec<String>, DeltaError> {
        let dir = self.at(crate::parquet::delta::log::LOG_DIR)?;
        let store = Arc::clone(&dir.store);
        let path = dir.path.clone();
        let listed = runtime::wait(&dir.url, async move {
            store.list_with_delimiter(Some(&path)).await
        })
        .map_err(storage_error)?
        .map_err(|e| storage_error(request_error(&dir.url, &e)))?;
        count_listed(listed.objects.len());
        Ok(listed
            .objects
            .into_iter()
            .filter_map(|meta| meta.location.filename().map(str::to_owned))
            .collect())
    }

    fn read_log(&self, name: &str) -> Result<Vec<u8>, DeltaError> {
        let location = self.log(name)?;
        let url = location.url.clone();
        let bytes = runtime::wait(&url, async move {
            let got = location.store.get(&location.path).await?;
            got.bytes().await
        })
        .map_err(storage_error)?
        .map_err(|e| storage_error(request_error(&url, &e)))?;
        count_get(bytes.len() as u64);
        Ok(bytes.to_vec())
    }

    fn put_log_if_absent(&self, name: &str, bytes: Vec<u8>) -> Result<bool, DeltaError> {
        use object_store::Error;
        let location = self.log(name)?;
        let url = location.url.clone();
        let len = bytes.len() as u64;
        let put = runtime::wait(&url, async move {
            let options = PutOptions {
                mode: PutMode::Create,
                ..PutOptions::default()
            };
            location
                .store
                .put_opts(&location.path, PutPayload::from(bytes), options)
                .await
        })
        .map_err(storage_error)?;
        count_put(len);
        match put {
            Ok(_) => Ok(true),
            Err(Error::AlreadyExists { .. } | Error::Precondition { .. }) => Ok(false),
            Err(Error::NotImplemented { .. }) => Err(storage_error(StorageError::new(
                &url,
                StorageErrorKind::Request(
                    "this store makes no conditional PUT, which a commit needs (for S3, the \
                     storage option aws_conditional_put=etag)"
                        .into(),
                ),
            ))),
            Err(e) => Err(storage_error(request_error(&url, &e))),
        }
    }

    fn staging_dir(&self) -> Result<StagingDir, DeltaError> {
        StagingDir::create(std::env::temp_dir().join(format!(
            ".chunkstore-delta-{}",
            crate::parquet::delta::log::random_uuid()
        )))
    }

    fn place(&self, staged: &Path, relative: &str) -> Result<(), DeltaError> {
        super::upload::upload_to(staged, self.at(relative)?, Arc::clone(&self.cancel))
            .map_err(storage_error)
    }

    fn remove_placed(&self, relative: &str) {
        if let Ok(location) = self.at(relative) {
            let url = location.url.clone();
            let _ = runtime::wait(
                &url,
                async move { location.store.delete(&location.path).await },
            );
        }
    }

    fn parallel_places(&self) -> usize {
        UPLOADS_IN_FLIGHT
    }
}
