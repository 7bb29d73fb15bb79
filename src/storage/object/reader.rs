//! [`ObjectReader`]: an object read as a seekable file, through ranged GETs that each
//! carry the version it had when opened.

use std::io::{Read, Seek, SeekFrom};
use std::ops::Range;
use std::path::Path as FsPath;
use std::sync::Arc;

use bytes::Bytes;
use futures::StreamExt;
use object_store::{GetOptions, GetRange, ObjectMeta};

use super::{Location, count_get, request_error, runtime};
use crate::rrd::Fetched;
use crate::storage::{StorageError, StorageErrorKind, StorageOptions};

/// Bytes fetched from the end of an object when it is opened: a footer of up to about
/// 900 chunks of two components. A larger footer costs a second, exact GET. (Opening a
/// thousand segments fetches this from each: small enough not to matter beside them.)
pub const TAIL_GUESS: u64 = 64 << 10;

/// A read the cache does not answer fetches at least this much (message headers are read
/// 16 bytes at a time while looking for a store info).
const MIN_FETCH: u64 = 64 << 10;

/// Ranges closer than this are fetched in one GET ([`ObjectReader::prefetch`]): a round
/// trip costs about what this many bytes do.
const COALESCE_GAP: u64 = 1 << 20;

/// No single GET of a prefetch is longer than this, so that several run at once.
const MAX_GET: u64 = 16 << 20;

/// GETs of one prefetch in flight at once.
const GETS_IN_FLIGHT: usize = 8;

/// What is known of an object once opened.
#[derive(Debug)]
struct Object {
    location: Location,
    size: u64,
    /// Sent with every read after the first (`If-Match`); `None` if the store gave none.
    e_tag: Option<String>,
}

/// An object read as a seekable file ([`crate::rrd::RrdInput`]): opened with one GET of its
/// end ([`TAIL_GUESS`] bytes), which learns its size and `ETag`; every later read is a
/// ranged GET with `If-Match` on that `ETag`, so that an object replaced while it is read is
/// [`StorageErrorKind::Changed`], never a mix of two versions. What was fetched is kept
/// (the end for good, a prefetch until the next one), and reads are answered from it.
///
/// Cloning is cheap and makes no request: the clone shares what was fetched at open, and
/// starts from the counts of requests the original had made ([`ObjectReader::fetched`]).
#[derive(Clone, Debug)]
pub struct ObjectReader {
    object: Arc<Object>,
    position: u64,
    /// What was fetched at open: kept.
    kept: Vec<(u64, Bytes)>,
    /// What the last prefetch fetched, sorted by start, and what the last read that
    /// nothing answered fetched: each replaced by the next one, so that reading a whole
    /// object through this keeps a bounded part of it.
    prefetched: Vec<(u64, Bytes)>,
    last_read: Option<(u64, Bytes)>,
    /// The requests this reader made, and their bytes.
    fetched: Fetched,
}

impl ObjectReader {
    /// Opens the object `url` names: one GET of its last [`TAIL_GUESS`] bytes.
    ///
    /// # Errors
    /// A URL that names no object store, a missing object, denied access, a request that
    /// failed after its retries.
    pub fn open(url: &FsPath, options: &StorageOptions) -> Result<Self, StorageError> {
        let location = Location::of_path(url, options)?;
        let url = location.url.clone();
        runtime::wait(&url, Self::open_async(location, None))?
    }

    /// Opens `location`: one GET of its end; with `listed` (its size and `ETag`, from a
    /// LIST), the GET is an exact range that must match the listed version.
    pub(super) async fn open_async(
        location: Location,
        listed: Option<ObjectMeta>,
    ) -> Result<Self, StorageError> {
        let range = match &listed {
            // A listed empty object has no range to ask for: one plain GET says so.
            Some(meta) if meta.size == 0 => None,
            Some(meta) => Some(GetRange::Bounded(
                meta.size.saturating_sub(TAIL_GUESS)..meta.size,
            )),
            None => Some(GetRange::Suffix(TAIL_GUESS)),
        };
        let options = GetOptions {
            range,
            if_match: listed.as_ref().and_then(|m| m.e_tag.clone()),
            ..GetOptions::default()
        };
        let failed = |e: &object_store::Error| request_error(&location.url, e);
        let result = match location.store.get_opts(&location.path, options).await {
            Ok(result) => result,
            // An empty object has no last bytes: S3 answers a suffix range with 416. Only
            // then: any other failure (throttling after its retries, say) is the answer,
            // not a reason to wait through the retries of another request.
            Err(e @ object_store::Error::Generic { .. })
                if listed.is_none() && e.to_string().contains("416 Range Not Satisfiable") =>
            {
                location
                    .store
                    .get_opts(&location.path, GetOptions::default())
                    .await
                    .map_err(|e| failed(&e))?
            }
            Err(e) => return Err(failed(&e)),
        };
        let (meta, range) = (result.meta.clone(), result.range.clone());
        let bytes = result.bytes().await.map_err(|e| failed(&e))?;
        count_get(bytes.len() as u64);
        let fetched = Fetched {
            requests: 1,
            bytes: bytes.len() as u64,
        };
        Ok(Self {
            object: Arc::new(Object {
                location,
                size: meta.size,
                e_tag: meta.e_tag,
            }),
            position: 0,
            kept: vec![(range.start, bytes)],
            prefetched: Vec::new(),
            last_read: None,
            fetched,
        })
    }

    /// The object's URL.
    pub fn url(&self) -> &str {
        &self.object.location.url
    }

    /// Where the object is.
    pub fn location(&self) -> &Location {
        &self.object.location
    }

    /// Whether the open fetched the whole object (one smaller than [`TAIL_GUESS`]): it is
    /// then read with no request.
    pub fn fetched_whole(&self) -> bool {
        self.covered(&(0..self.object.size))
    }

    /// The object's size, as it was when opened.
    pub fn size(&self) -> u64 {
        self.object.size
    }

    /// The object's `ETag` when opened, which every read must match.
    pub fn e_tag(&self) -> Option<&str> {
        self.object.e_tag.as_deref()
    }

    /// The GETs this reader made (its open's included) and the bytes they brought.
    pub fn fetched(&self) -> Fetched {
        self.fetched
    }

    /// Keeps only what was fetched at or after `at` (a footer's start: what opening it
    /// again needs), dropping the rest.
    pub fn keep_from(&mut self, at: u64) {
        self.prefetched.clear();
        self.last_read = None;
        self.kept.retain_mut(|(start, bytes)| {
            let end = *start + bytes.len() as u64;
            if end <= at {
                return false;
            }
            if *start < at {
                let skip = usize::try_from(at - *start).unwrap_or(usize::MAX);
                *bytes = bytes.slice(skip.min(bytes.len())..);
                *start = at;
            }
            true
        });
    }

    /// Fetches `ranges` (sorted by start) with as few GETs as their gaps allow, several in
    /// flight, each matched against the `ETag`; what an earlier prefetch fetched is dropped.
    /// Ranges outside the object are left for the reads to report.
    ///
    /// # Errors
    /// As [`ObjectReader::open`], and [`StorageErrorKind::Changed`].
    pub fn prefetch(&mut self, ranges: &[Range<u64>]) -> std::io::Result<()> {
        self.prefetched.clear();
        let size = self.object.size;
        let mut gets: Vec<Range<u64>> = Vec::new();
        for range in ranges {
            if range.start >= range.end || range.end > size || self.covered(range) {
                continue;
            }
            match gets.last_mut() {
                Some(last)
                    if range.start <= last.end.saturating_add(COALESCE_GAP)
                        && range.end.max(last.end) - last.start <= MAX_GET =>
                {
                    last.end = last.end.max(range.end);
                }
                _ => gets.push(range.clone()),
            }
        }
        if gets.is_empty() {
            return Ok(());
        }
        let object = Arc::clone(&self.object);
        let fetched = runtime::wait(self.url(), async move {
            futures::stream::iter(gets)
                .map(|range| {
                    let object = Arc::clone(&object);
                    async move { fetch(&object, range).await }
                })
                .buffered(GETS_IN_FLIGHT)
                .collect::<Vec<_>>()
                .await
        })
        .map_err(StorageError::into_io)?;
        for result in fetched {
            let (start, bytes) = result.map_err(StorageError::into_io)?;
            self.count(&bytes);
            self.prefetched.push((start, bytes));
        }
        Ok(())
    }

    /// Counts a GET that brought `bytes`.
    fn count(&mut self, bytes: &Bytes) {
        self.fetched.requests += 1;
        self.fetched.bytes += bytes.len() as u64;
    }

    /// Is all of `range` among what was fetched?
    fn covered(&self, range: &Range<u64>) -> bool {
        self.find(range.start)
            .is_some_and(|bytes| bytes.len() as u64 >= range.end - range.start)
    }

    /// What was fetched from `at` on, in one piece, if anything was.
    fn find(&self, at: u64) -> Option<&[u8]> {
        self.kept
            .iter()
            .chain(&self.prefetched)
            .chain(&self.last_read)
            .find(|(start, bytes)| *start <= at && at < start + bytes.len() as u64)
            .map(|(start, bytes)| {
                let skip = usize::try_from(at - start).unwrap_or(usize::MAX);
                &bytes[skip..]
            })
    }
}

/// One ranged GET of `object`, matched against its `ETag`.
async fn fetch(object: &Object, range: Range<u64>) -> Result<(u64, Bytes), StorageError> {
    let options = GetOptions {
        range: Some(GetRange::Bounded(range.clone())),
        if_match: object.e_tag.clone(),
        ..GetOptions::default()
    };
    let location = &object.location;
    let failed = |e: &object_store::Error| request_error(&location.url, e);
    let result = location
        .store
        .get_opts(&location.path, options)
        .await
        .map_err(|e| failed(&e))?;
    // A store that gives no `ETag` is checked by size at least.
    if result.meta.size != object.size {
        return Err(StorageError::new(&location.url, StorageErrorKind::Changed));
    }
    let bytes = result.bytes().await.map_err(|e| failed(&e))?;
    count_get(bytes.len() as u64);
    Ok((range.start, bytes))
}

impl Read for ObjectReader {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        let size = self.object.size;
        if out.is_empty() || self.position >= size {
            return Ok(0);
        }
        if self.find(self.position).is_none() {
            let want = (out.len() as u64).max(MIN_FETCH);
            let range = self.position..self.position.saturating_add(want).min(size);
            let object = Arc::clone(&self.object);
            let fetched = runtime::wait(self.url(), async move { fetch(&object, range).await })
                .and_then(|fetched| fetched)
                .map_err(StorageError::into_io)?;
            self.count(&fetched.1);
            self.last_read = Some(fetched);
        }
        let available = self.find(self.position).unwrap_or_default();
        let n = available.len().min(out.len());
        out[..n].copy_from_slice(&available[..n]);
        self.position += n as u64;
        Ok(n)
    }
}

impl Seek for ObjectReader {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let target = match to {
            SeekFrom::Start(at) => Some(at),
            SeekFrom::End(delta) => self.object.size.checked_add_signed(delta),
            SeekFrom::Current(delta) => self.position.checked_add_signed(delta),
        };
        self.position = target.ok_or_else(|| {
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "seek before the start of the object",
            )
        })?;
        Ok(self.position)
    }
}
