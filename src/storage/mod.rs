//! Where sources and outputs live: a local path, or (feature `object-store`) an object in
//! S3, Google Cloud Storage, Azure Blob Storage or on a web server, named by URL
//! (`s3://bucket/key.rrd`, `gs://…`, `az://…`, `abfs://…`, `https://…`, `file://…`).
//!
//! A recording or dataset is named by a path everywhere; a path whose text is a URL of
//! one of these schemes names an object ([`url_scheme`]). [`Input`] reads either, and
//! [`open_input`] opens one. Over a network an `.rrd` is read as a lazy file is: the end
//! first (one ranged GET that usually holds the whole footer), then only the chunks a
//! query needs, fetched together ([`crate::rrd::RrdInput::prefetch`]). Every read after
//! the first carries the object's `ETag` (`If-Match`): an object rewritten while it is read
//! is an error naming it, never a mix of two versions (`docs/STORAGE.md`).
//!
//! Credentials, region and endpoint come from the environment the clouds' own tools read
//! (`AWS_*`, `GOOGLE_*`, `AZURE_*`) and from [`StorageOptions`], which win.

mod error;
#[cfg(feature = "object-store")]
pub mod object;

use std::io::{Read, Seek, SeekFrom};
use std::ops::Range;
use std::path::Path;

pub use error::{StorageError, StorageErrorKind};

use crate::rrd::{Fetched, RrdInput};

/// The URL schemes that name objects.
pub const URL_SCHEMES: [&str; 9] = [
    "s3", "s3a", "gs", "az", "abfs", "abfss", "azure", "http", "https",
];

/// Options of the object stores a URL names, as `KEY=VALUE` pairs (`aws_endpoint`,
/// `aws_region`, `aws_allow_http`, `google_service_account`, `azure_storage_account_name`,
/// …: `object_store`'s configuration keys, the ones polars, deltalake and DuckDB users
/// know), on top of what the environment says. A key that no store of the URL's kind
/// knows is an error when the URL is opened.
///
/// ```
/// use chunkstore::storage::StorageOptions;
/// let options = StorageOptions::default().with("aws_endpoint", "http://127.0.0.1:8333");
/// assert_eq!(options.get("aws_endpoint"), Some("http://127.0.0.1:8333"));
/// ```
#[derive(Clone, Debug, Default, PartialEq, Eq, Hash)]
pub struct StorageOptions {
    /// The pairs, keys lower-cased, sorted by key, each key once (the last given wins).
    pairs: Vec<(String, String)>,
}

impl StorageOptions {
    /// With `key` set to `value` (replacing what it was).
    #[must_use]
    pub fn with(mut self, key: impl AsRef<str>, value: impl Into<String>) -> Self {
        self.set(key, value);
        self
    }

    /// Sets `key` to `value` (replacing what it was).
    pub fn set(&mut self, key: impl AsRef<str>, value: impl Into<String>) {
        let key = key.as_ref().trim().to_ascii_lowercase();
        let value = value.into();
        match self.pairs.binary_search_by(|(k, _)| k.as_str().cmp(&key)) {
            Ok(at) => self.pairs[at].1 = value,
            Err(at) => self.pairs.insert(at, (key, value)),
        }
    }

    /// Parses `KEY=VALUE` (a command-line `--storage-option`).
    ///
    /// # Errors
    /// If `text` has no `=` or an empty key.
    pub fn parse_pair(text: &str) -> Result<(String, String), String> {
        match text.split_once('=') {
            Some((key, value)) if !key.trim().is_empty() => {
                Ok((key.trim().to_owned(), value.to_owned()))
            }
            _ => Err(format!("{text:?} is not KEY=VALUE")),
        }
    }

    /// The value of `key`, if set.
    pub fn get(&self, key: &str) -> Option<&str> {
        let key = key.to_ascii_lowercase();
        self.pairs
            .binary_search_by(|(k, _)| k.as_str().cmp(&key))
            .ok()
            .map(|at| self.pairs[at].1.as_str())
    }

    /// The pairs, sorted by key.
    pub fn pairs(&self) -> impl Iterator<Item = (&str, &str)> {
        self.pairs.iter().map(|(k, v)| (k.as_str(), v.as_str()))
    }

    /// Is none set?
    pub fn is_empty(&self) -> bool {
        self.pairs.is_empty()
    }
}

impl<K: AsRef<str>, V: Into<String>> FromIterator<(K, V)> for StorageOptions {
    fn from_iter<I: IntoIterator<Item = (K, V)>>(pairs: I) -> Self {
        let mut options = Self::default();
        for (key, value) in pairs {
            options.set(key, value);
        }
        options
    }
}

/// The scheme of `path` if its text is a URL naming an object (`s3://bucket/key` gives
/// `s3`), lower-cased; `None` for a local path (a `file://` URL is a local path: see
/// [`local_path`]).
///
/// ```
/// use chunkstore::storage::url_scheme;
/// assert_eq!(url_scheme("s3://bucket/a.rrd".as_ref()).as_deref(), Some("s3"));
/// assert_eq!(url_scheme("runs/a.rrd".as_ref()), None);
/// assert_eq!(url_scheme("file:///runs/a.rrd".as_ref()), None);
/// ```
pub fn url_scheme(path: &Path) -> Option<String> {
    let text = path.to_str()?;
    let (scheme, rest) = text.split_once("://")?;
    let scheme = scheme.to_ascii_lowercase();
    (URL_SCHEMES.contains(&scheme.as_str()) && !rest.is_empty()).then_some(scheme)
}

/// Is `path` a URL naming a prefix (a dataset: the `.rrd` objects under it)? A URL ending
/// in `/`.
///
/// ```
/// use chunkstore::storage::is_prefix_url;
/// assert!(is_prefix_url("s3://bucket/episodes/".as_ref()));
/// assert!(!is_prefix_url("s3://bucket/episodes/run.rrd".as_ref()));
/// assert!(!is_prefix_url("episodes/".as_ref()));
/// ```
pub fn is_prefix_url(path: &Path) -> bool {
    url_scheme(path).is_some() && path.to_str().is_some_and(|text| text.ends_with('/'))
}

/// The local path a `file://` URL names (`file:///runs/a.rrd` is `/runs/a.rrd`); any
/// other path as it is.
pub fn local_path(path: &Path) -> &Path {
    path.to_str()
        .and_then(|text| {
            let (scheme, rest) = text.split_once("://")?;
            scheme.eq_ignore_ascii_case("file").then_some(rest)
        })
        .map_or(path, Path::new)
}

/// An I/O error on `path` as its message says it: `path: error`, or an object's error
/// alone, which names its URL already.
pub fn io_error_text(path: &Path, error: &std::io::Error) -> String {
    if StorageError::from_io(error).is_some() {
        error.to_string()
    } else {
        format!("{}: {error}", path.display())
    }
}

/// What an `.rrd` is read from: a local file, or (feature `object-store`) an object.
#[derive(Debug)]
pub enum Input {
    /// A local file.
    File(std::fs::File),
    /// An object in a bucket or on a web server.
    #[cfg(feature = "object-store")]
    Object(object::ObjectReader),
}

impl Input {
    /// The input's size in bytes.
    ///
    /// # Errors
    /// If a local file's metadata cannot be read.
    pub fn size(&self) -> std::io::Result<u64> {
        match self {
            Self::File(file) => file.metadata().map(|m| m.len()),
            #[cfg(feature = "object-store")]
            Self::Object(object) => Ok(object.size()),
        }
    }
}

impl Read for Input {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Self::File(file) => file.read(out),
            #[cfg(feature = "object-store")]
            Self::Object(object) => object.read(out),
        }
    }
}

impl Seek for Input {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        match self {
            Self::File(file) => file.seek(to),
            #[cfg(feature = "object-store")]
            Self::Object(object) => object.seek(to),
        }
    }
}

impl RrdInput for Input {
    fn prefetch(&mut self, ranges: &[Range<u64>]) -> std::io::Result<()> {
        match self {
            Self::File(file) => file.prefetch(ranges),
            #[cfg(feature = "object-store")]
            Self::Object(object) => object.prefetch(ranges),
        }
    }

    fn fetched(&self) -> Fetched {
        match self {
            Self::File(file) => file.fetched(),
            #[cfg(feature = "object-store")]
            Self::Object(object) => object.fetched(),
        }
    }
}

/// Opens `path` for reading: a local file, or the object its URL names (one request,
/// which fetches the object's end and learns its size and version).
///
/// # Errors
/// [`StorageErrorKind::NotFound`], a denied or failed request, a URL whose scheme needs
/// the `object-store` feature; a local file's own error, as an I/O error.
pub fn open_input(path: &Path, options: &StorageOptions) -> std::io::Result<Input> {
    if url_scheme(path).is_some() {
        #[cfg(feature = "object-store")]
        return object::ObjectReader::open(path, options)
            .map(Input::Object)
            .map_err(StorageError::into_io);
        #[cfg(not(feature = "object-store"))]
        {
            let _ = options;
            return Err(StorageError::needs_feature(path).into_io());
        }
    }
    std::fs::File::open(local_path(path)).map(Input::File)
}

/// The whole of `path`: a local file, or the object its URL names (one GET).
///
/// # Errors
/// As [`open_input`], and the read's own.
pub fn read_whole(path: &Path, options: &StorageOptions) -> std::io::Result<Vec<u8>> {
    if url_scheme(path).is_none() {
        return std::fs::read(local_path(path));
    }
    let (mut stream, size) = open_stream(path, options)?;
    // The size the store gave, as a first guess only: the body itself says how long it is.
    let mut bytes = Vec::with_capacity(usize::try_from(size.min(64 << 20)).unwrap_or(0));
    stream.read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// Opens `path` to be read once, start to end: a local file, or one GET of the object its
/// URL names, its body read as it arrives. Gives the reader and the size.
///
/// # Errors
/// As [`open_input`].
pub fn open_stream(
    path: &Path,
    options: &StorageOptions,
) -> std::io::Result<(Box<dyn Read + Send>, u64)> {
    if url_scheme(path).is_some() {
        #[cfg(feature = "object-store")]
        return object::ObjectStream::open(path, options)
            .map(|stream| {
                let size = stream.size();
                (Box::new(stream) as Box<dyn Read + Send>, size)
            })
            .map_err(StorageError::into_io);
        #[cfg(not(feature = "object-store"))]
        {
            let _ = options;
            return Err(StorageError::needs_feature(path).into_io());
        }
    }
    let file = std::fs::File::open(local_path(path))?;
    let size = file.metadata().map_or(0, |m| m.len());
    Ok((Box::new(file), size))
}

/// What went wrong writing an output with [`write_output`]: the writer's own error, or
/// the upload's.
#[derive(Debug)]
pub enum OutputError<E> {
    /// The writer failed (nothing was uploaded).
    Write(E),
    /// The upload failed or was cancelled (and was aborted: nothing is in the bucket), or
    /// the staging file could not be made.
    Upload(StorageError),
}

impl<E: std::fmt::Display> std::fmt::Display for OutputError<E> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Write(error) => write!(f, "{error}"),
            Self::Upload(error) => write!(f, "{error}"),
        }
    }
}

impl<E: std::error::Error + 'static> std::error::Error for OutputError<E> {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Write(error) => Some(error),
            Self::Upload(error) => Some(error),
        }
    }
}

/// Writes the output `out` with `write`, which writes a local file (atomically, as the
/// crate's writers do): to `out` itself, or, for a URL, to a staging file in the system's
/// temporary directory (removed after, and on Ctrl-C: [`crate::output`]) that is then
/// uploaded, appearing in the bucket whole or not at all. `cancel`, once set, aborts the
/// upload (a multipart upload checks it between parts).
///
/// # Errors
/// [`OutputError::Write`] with `write`'s error; [`OutputError::Upload`] for a failed,
/// denied or cancelled upload, or a URL that needs the `object-store` feature.
pub fn write_output<T, E>(
    out: &Path,
    options: &StorageOptions,
    cancel: &std::sync::Arc<std::sync::atomic::AtomicBool>,
    write: impl FnOnce(&Path) -> Result<T, E>,
) -> Result<T, OutputError<E>> {
    if url_scheme(out).is_none() {
        return write(local_path(out)).map_err(OutputError::Write);
    }
    #[cfg(feature = "object-store")]
    return object::write_staged(out, options, cancel, write);
    #[cfg(not(feature = "object-store"))]
    {
        let _ = (options, cancel, write);
        Err(OutputError::Upload(StorageError::needs_feature(out)))
    }
}

/// The Delta table `dir` names (features `parquet`; `object-store` for a URL): a local
/// directory ([`LocalTable`](crate::parquet::delta::LocalTable)), or a prefix in a bucket
/// (`object::ObjectTable`), whose uploads stop when `cancel` is set (the write then
/// deletes what it uploaded).
///
/// # Errors
/// A URL that names no object store, or whose scheme needs the `object-store` feature.
#[cfg(feature = "parquet")]
pub fn delta_table(
    dir: &Path,
    options: &StorageOptions,
    cancel: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> Result<Box<dyn crate::parquet::delta::TableStore>, StorageError> {
    if url_scheme(dir).is_none() {
        return Ok(Box::new(crate::parquet::delta::LocalTable::new(
            local_path(dir),
        )));
    }
    #[cfg(feature = "object-store")]
    return object::ObjectTable::new(&dir.to_string_lossy(), options, cancel)
        .map(|table| Box::new(table) as Box<dyn crate::parquet::delta::TableStore>);
    #[cfg(not(feature = "object-store"))]
    {
        let _ = (options, cancel);
        Err(StorageError::needs_feature(dir))
    }
}
