//! Objects (feature `object-store`): URLs resolved to `object_store` stores, read through
//! [`ObjectReader`], listed as datasets ([`list_rrd_objects`]), written whole or not at all
//! ([`upload_file`]); every request counted ([`counters`]).
//!
//! `object_store` is asynchronous; the rest of the crate is not. Its futures run on one
//! small runtime of the crate's own (`runtime.rs`), and a caller's thread waits for each
//! (or for a batch of them, run concurrently): from a plain thread or from inside another
//! runtime's task (DataFusion's, the server's) alike.

mod list;
mod reader;
mod runtime;
mod stream;
#[cfg(feature = "parquet")]
mod table;
mod upload;

use std::path::Path as FsPath;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use object_store::ObjectStore;
use object_store::path::Path as ObjectPath;
use parking_lot::Mutex;

pub use list::{ListedObjects, OPENS_IN_FLIGHT, list_all, list_rrd_objects, open_all};
pub use reader::{ObjectReader, TAIL_GUESS};
pub use stream::ObjectStream;
#[cfg(feature = "parquet")]
pub use table::ObjectTable;
pub(crate) use upload::write_staged;
pub use upload::{PART_BYTES, upload_file};

use super::{StorageError, StorageErrorKind, StorageOptions};

/// Requests made and bytes fetched from object stores by this process so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct StorageCounters {
    /// GET requests (whole, ranged or suffix).
    pub gets: u64,
    /// LIST requests (pages).
    pub lists: u64,
    /// PUT requests (a multipart upload's parts, its start and its completion each count).
    pub puts: u64,
    /// Bytes received by GETs.
    pub bytes_fetched: u64,
    /// Bytes sent by PUTs.
    pub bytes_sent: u64,
}

impl StorageCounters {
    /// What happened between `earlier` and these counts.
    #[must_use]
    pub fn since(&self, earlier: &Self) -> Self {
        Self {
            gets: self.gets - earlier.gets,
            lists: self.lists - earlier.lists,
            puts: self.puts - earlier.puts,
            bytes_fetched: self.bytes_fetched - earlier.bytes_fetched,
            bytes_sent: self.bytes_sent - earlier.bytes_sent,
        }
    }
}

impl std::fmt::Display for StorageCounters {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} GET ({} bytes), {} LIST, {} PUT ({} bytes)",
            self.gets, self.bytes_fetched, self.lists, self.puts, self.bytes_sent
        )
    }
}

static GETS: AtomicU64 = AtomicU64::new(0);
static LISTS: AtomicU64 = AtomicU64::new(0);
static PUTS: AtomicU64 = AtomicU64::new(0);
static BYTES_FETCHED: AtomicU64 = AtomicU64::new(0);
static BYTES_SENT: AtomicU64 = AtomicU64::new(0);

/// The process's requests and bytes so far (take two and [`StorageCounters::since`] for
/// what an operation cost).
pub fn counters() -> StorageCounters {
    StorageCounters {
        gets: GETS.load(Ordering::Relaxed),
        lists: LISTS.load(Ordering::Relaxed),
        puts: PUTS.load(Ordering::Relaxed),
        bytes_fetched: BYTES_FETCHED.load(Ordering::Relaxed),
        bytes_sent: BYTES_SENT.load(Ordering::Relaxed),
    }
}

fn count_get(bytes: u64) {
    GETS.fetch_add(1, Ordering::Relaxed);
    // (A streamed body adds its bytes as they arrive.)
    BYTES_FETCHED.fetch_add(bytes, Ordering::Relaxed);
}

fn count_lists(pages: u64) {
    LISTS.fetch_add(pages, Ordering::Relaxed);
}

/// Counts a listing that returned `keys` keys (objects and prefixes): S3 pages them by
/// 1,000, and an empty listing is one page too. `object_store` reads every page without
/// saying how many it took.
fn count_listed(keys: usize) {
    count_lists(keys.div_ceil(1000).max(1) as u64);
}

fn count_put(bytes: u64) {
    PUTS.fetch_add(1, Ordering::Relaxed);
    BYTES_SENT.fetch_add(bytes, Ordering::Relaxed);
}

/// An object (or a prefix) named by URL: its store and its path in it.
#[derive(Clone, Debug)]
pub struct Location {
    /// The URL, as given.
    pub url: String,
    /// The store (shared by every URL of the same bucket and options).
    pub store: Arc<dyn ObjectStore>,
    /// The object's path in its store.
    pub path: ObjectPath,
}

impl Location {
    /// Resolves `url` (`s3://bucket/key`, `gs://…`, `az://…`, `abfs://…`, `https://…`),
    /// with credentials and settings from the environment and `options` (which win).
    ///
    /// # Errors
    /// [`StorageErrorKind::BadUrl`] for a URL that names no object store, or an option its
    /// store does not know, or settings it cannot build a client from.
    pub fn resolve(url: &str, options: &StorageOptions) -> Result<Self, StorageError> {
        static STORES: Mutex<Vec<(String, Arc<dyn ObjectStore>)>> = Mutex::new(Vec::new());
        let bad = |reason: String| StorageError::new(url, StorageErrorKind::BadUrl(reason));
        let parsed = url::Url::parse(url).map_err(|e| bad(format!("not a URL: {e}")))?;
        let (scheme, path) = object_store::ObjectStoreScheme::parse(&parsed)
            .map_err(|e| bad(format!("not an object store URL: {e}")))?;
        // One store per bucket (scheme and authority) and options: its connections are
        // reused by every object in it.
        let key = format!(
            "{}://{}|{options:?}",
            parsed.scheme(),
            parsed.host_str().unwrap_or_default()
        );
        let cached = STORES
            .lock()
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, store)| Arc::clone(store));
        let store = if let Some(store) = cached {
            store
        } else {
            let store =
                with_added_latency(build_store(&scheme, &parsed, options), options).map_err(bad)?;
            STORES.lock().push((key, Arc::clone(&store)));
            store
        };
        Ok(Self {
            url: url.to_owned(),
            store,
            path,
        })
    }

    /// [`Location::resolve`] of a URL held as a path (how sources are named).
    ///
    /// # Errors
    /// As [`Location::resolve`], and a path that is not UTF-8.
    pub fn of_path(url: &FsPath, options: &StorageOptions) -> Result<Self, StorageError> {
        let text = url.to_str().ok_or_else(|| {
            StorageError::new(
                url.display().to_string(),
                StorageErrorKind::BadUrl("not UTF-8".into()),
            )
        })?;
        Self::resolve(text, options)
    }

    /// The URL of `path` in the same store (an object listed under a prefix).
    fn child(&self, path: ObjectPath) -> Self {
        let url = match self.url.find("://").and_then(|s| {
            let after = s + 3;
            self.url[after..].find('/').map(|slash| after + slash)
        }) {
            Some(root) => format!("{}/{}", &self.url[..root], path),
            None => format!("{}/{}", self.url.trim_end_matches('/'), path),
        };
        Self {
            url,
            store: Arc::clone(&self.store),
            path,
        }
    }
}

/// How long and how often a failed request (a network error, a timeout, 5xx, 429 and
/// S3's `SlowDown`) is tried again before its error is the answer.
fn retry_config() -> object_store::RetryConfig {
    object_store::RetryConfig {
        backoff: object_store::BackoffConfig {
            init_backoff: std::time::Duration::from_millis(100),
            max_backoff: std::time::Duration::from_secs(5),
            base: 2.0,
        },
        max_retries: 5,
        retry_timeout: std::time::Duration::from_mins(1),
    }
}

/// The option that adds a fixed delay to every request (benchmarks: what a network's
/// latency does to a query, measured against a server on the same machine).
pub const ADDED_LATENCY_OPTION: &str = "chunkstore_added_latency_ms";

fn with_added_latency(
    store: Result<Arc<dyn ObjectStore>, String>,
    options: &StorageOptions,
) -> Result<Arc<dyn ObjectStore>, String> {
    let store = store?;
    let Some(text) = options.get(ADDED_LATENCY_OPTION) else {
        return Ok(store);
    };
    let ms: u64 = text
        .parse()
        .map_err(|_| format!("{ADDED_LATENCY_OPTION}={text:?} is not a whole number of ms"))?;
    let wait = std::time::Duration::from_millis(ms);
    let config = object_store::throttle::ThrottleConfig {
        wait_get_per_call: wait,
        wait_list_per_call: wait,
        wait_list_with_delimiter_per_call: wait,
        wait_put_per_call: wait,
        wait_delete_per_call: wait,
        ..object_store::throttle::ThrottleConfig::default()
    };
    Ok(Arc::new(object_store::throttle::ThrottledStore::new(
        store, config,
    )))
}

fn build_store(
    scheme: &object_store::ObjectStoreScheme,
    url: &url::Url,
    options: &StorageOptions,
) -> Result<Arc<dyn ObjectStore>, String> {
    use object_store::ObjectStoreScheme as Scheme;
    // Each key must be one the store knows: a misspelt option is an error, not ignored.
    macro_rules! configured {
        ($builder:expr, $key:ty) => {{
            let mut builder = $builder
                .with_url(url.to_string())
                .with_retry(retry_config());
            for (key, value) in options.pairs().filter(|(k, _)| *k != ADDED_LATENCY_OPTION) {
                let parsed: $key = key
                    .parse()
                    .map_err(|_| format!("{key:?} is not a storage option of this store"))?;
                builder = builder.with_config(parsed, value);
            }
            Arc::new(builder.build().map_err(|e| e.to_string())?) as Arc<dyn ObjectStore>
        }};
    }
    Ok(match scheme {
        Scheme::AmazonS3 => configured!(
            object_store::aws::AmazonS3Builder::from_env(),
            object_store::aws::AmazonS3ConfigKey
        ),
        Scheme::GoogleCloudStorage => configured!(
            object_store::gcp::GoogleCloudStorageBuilder::from_env(),
            object_store::gcp::GoogleConfigKey
        ),
        Scheme::MicrosoftAzure => configured!(
            object_store::azure::MicrosoftAzureBuilder::from_env(),
            object_store::azure::AzureConfigKey
        ),
        Scheme::Http => {
            let root = &url[..url::Position::BeforePath];
            let mut builder = object_store::http::HttpBuilder::new()
                .with_url(root)
                .with_retry(retry_config());
            for (key, value) in options.pairs().filter(|(k, _)| *k != ADDED_LATENCY_OPTION) {
                let parsed: object_store::ClientConfigKey = key
                    .parse()
                    .map_err(|_| format!("{key:?} is not a storage option of this store"))?;
                builder = builder.with_config(parsed, value);
            }
            Arc::new(builder.build().map_err(|e| e.to_string())?)
        }
        _ => return Err("not an object store URL (a local file is named by its path)".into()),
    })
}

/// The error of a failed request on `url`.
fn request_error(url: &str, error: &object_store::Error) -> StorageError {
    use object_store::Error;
    let kind = match error {
        Error::NotFound { .. } => StorageErrorKind::NotFound,
        Error::PermissionDenied { .. } | Error::Unauthenticated { .. } => {
            StorageErrorKind::AccessDenied
        }
        Error::Precondition { .. } | Error::NotModified { .. } => StorageErrorKind::Changed,
        Error::AlreadyExists { .. } => StorageErrorKind::AlreadyExists,
        other => StorageErrorKind::Request(one_line(&other.to_string())),
    };
    StorageError::new(url, kind)
}

/// `object_store`'s errors nest their causes over several lines; one line says it.
fn one_line(text: &str) -> String {
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}
