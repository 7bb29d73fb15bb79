//! A dataset over a prefix: its `.rrd` objects listed, and each opened, many at once; a
//! recording's chunk files over a prefix, listed.

use futures::StreamExt;

use super::{Location, ObjectReader, count_listed, request_error, runtime};
use crate::storage::{StorageError, StorageOptions};

/// Objects opened at once when a dataset over a prefix opens (each is one GET).
pub const OPENS_IN_FLIGHT: usize = 64;

/// The `.rrd` objects directly under a prefix, sorted by key, what to warn of, and the
/// Arrow IPC chunk files beside them (a prefix of those and no `.rrd` is one recording's
/// chunk directory).
#[derive(Debug)]
pub struct ListedObjects {
    /// Each object: its location and what the listing says of it.
    pub objects: Vec<(Location, object_store::ObjectMeta)>,
    /// "Subdirectories" (common prefixes) that were not looked into.
    pub subdirectories: usize,
    /// The objects named like Arrow IPC files ([`crate::ipc::IPC_EXTENSIONS`]), by URL,
    /// sorted.
    pub chunk_files: Vec<String>,
}

/// Lists the `.rrd` objects directly under the prefix `url` (`s3://bucket/episodes/`):
/// one paginated LIST (a page per 1,000 keys on S3).
///
/// # Errors
/// As [`Location::resolve`], and a failed or denied LIST.
pub fn list_rrd_objects(
    url: &str,
    options: &StorageOptions,
) -> Result<ListedObjects, StorageError> {
    let prefix = Location::resolve(url, options)?;
    let store = std::sync::Arc::clone(&prefix.store);
    let path = prefix.path.clone();
    let listed = runtime::wait(url, async move {
        let prefix = (!path.as_ref().is_empty()).then_some(&path);
        store.list_with_delimiter(prefix).await
    })?
    .map_err(|e| request_error(url, &e))?;
    // `list_with_delimiter` reads every page; the count is of the pages it needed.
    count_listed(listed.objects.len() + listed.common_prefixes.len());
    let mut objects: Vec<(Location, object_store::ObjectMeta)> = listed
        .objects
        .iter()
        .filter(|meta| {
            meta.location
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("rrd"))
        })
        .map(|meta| (prefix.child(meta.location.clone()), meta.clone()))
        .collect();
    objects.sort_by(|a, b| a.1.location.cmp(&b.1.location));
    let mut chunk_files: Vec<String> = listed
        .objects
        .iter()
        .filter(|meta| {
            meta.location.extension().is_some_and(|e| {
                crate::ipc::IPC_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str())
            })
        })
        .map(|meta| prefix.child(meta.location.clone()).url)
        .collect();
    chunk_files.sort();
    Ok(ListedObjects {
        objects,
        subdirectories: listed.common_prefixes.len(),
        chunk_files,
    })
}

/// Opens every listed object ([`ObjectReader`]: one GET of its end each), up to
/// [`OPENS_IN_FLIGHT`] at once; one result per object, in order.
pub fn open_all(listed: &ListedObjects) -> Vec<Result<ObjectReader, StorageError>> {
    let objects = listed.objects.clone();
    let urls: Vec<String> = objects.iter().map(|(l, _)| l.url.clone()).collect();
    let first = urls.first().cloned().unwrap_or_default();
    match runtime::wait(&first, async move {
        futures::stream::iter(objects)
            .map(|(location, meta)| ObjectReader::open_async(location, Some(meta)))
            .buffered(OPENS_IN_FLIGHT)
            .collect::<Vec<_>>()
            .await
    }) {
        Ok(results) => results,
        Err(error) => urls
            .into_iter()
            .map(|url| Err(StorageError::new(url, error.kind.clone())))
            .collect(),
    }
}

/// Every object under the prefix `url`, however deep, with its size: its key relative to
/// the prefix (as stored: a Hive partition's `%2F` stays as it is), sorted.
///
/// # Errors
/// As [`Location::resolve`], and a failed or denied LIST.
pub fn list_all(url: &str, options: &StorageOptions) -> Result<Vec<(String, u64)>, StorageError> {
    let prefix = Location::resolve(url, options)?;
    let store = std::sync::Arc::clone(&prefix.store);
    let path = prefix.path.clone();
    let listed = runtime::wait(url, async move {
        let prefix = (!path.as_ref().is_empty()).then_some(&path);
        store.list(prefix).collect::<Vec<_>>().await
    })?;
    count_listed(listed.len());
    let root = prefix.path.as_ref();
    let mut objects = Vec::with_capacity(listed.len());
    for meta in listed {
        let meta = meta.map_err(|e| request_error(url, &e))?;
        let key = meta.location.as_ref();
        let relative = key
            .strip_prefix(root)
            .map_or(key, |k| k.trim_start_matches('/'));
        objects.push((relative.to_owned(), meta.size));
    }
    objects.sort();
    Ok(objects)
}
