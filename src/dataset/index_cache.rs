//! The index cache ([`DatasetOptions::index_cache`](super::DatasetOptions::index_cache)):
//! a segment whose file has no footer is scanned once, and its detached index
//! (`crate::rrd::index`) kept in the cache directory under a name drawn from the file's
//! path, size and modification time (for an object in a bucket: its URL, size and `ETag`).
//! Later opens read the index instead of the file, and queries read the file in part
//! through it, as through a footer. Nothing is ever written beside the data; a file that
//! changes gets a new index (the old one stays until the directory is cleared).

use std::io::Read;
use std::path::{Path, PathBuf};

use super::{DatasetError, DatasetOptions, Opened, SegmentInfo};
use crate::ChunkStore;
use crate::recording::{LoadFault, OpenError, RecordingReader};
use crate::rrd::LazyRecording;
use crate::storage::Input;

/// The index named by a digest of `identity` (what tells the data file and its version
/// apart) in `dir`.
fn index_named(dir: &Path, identity: &[&[u8]]) -> PathBuf {
    use sha2::Digest as _;
    const HEX: &[u8; 16] = b"0123456789abcdef";
    let mut hash = sha2::Sha256::new();
    for part in identity {
        hash.update(part);
    }
    let digest = hash.finalize();
    let name: String = digest[..16]
        .iter()
        .flat_map(|b| [HEX[usize::from(b >> 4)], HEX[usize::from(b & 0xF)]])
        .map(char::from)
        .collect();
    dir.join(format!("{name}.rrd-index"))
}

/// Where the index of `path` (whose metadata is `metadata`) is kept in `dir`.
fn index_file(dir: &Path, path: &Path, metadata: &std::fs::Metadata) -> PathBuf {
    let canonical = path.canonicalize().unwrap_or_else(|_| path.to_owned());
    let mtime = metadata
        .modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_nanos());
    index_named(
        dir,
        &[
            canonical.as_os_str().as_encoded_bytes(),
            &metadata.len().to_le_bytes(),
            &mtime.to_le_bytes(),
        ],
    )
}

/// Opens the footerless file `path` through its index in `dir`, scanning it and writing
/// the index first if there is none (or it does not read).
pub(super) fn open_indexed(
    path: &Path,
    dir: &Path,
    options: &DatasetOptions,
    metadata: &std::fs::Metadata,
) -> Result<Opened, DatasetError> {
    let index = index_file(dir, path, metadata);
    let file_bytes = metadata.len();
    let data = || std::fs::File::open(path).ok().map(Input::File);
    if let Some(segment) = open_through(path, data, &index, file_bytes) {
        return Ok(Opened::new(segment, None));
    }
    let file = std::fs::File::open(path).map_err(|source| OpenError::Io {
        path: path.to_owned(),
        source,
    })?;
    scan(
        path,
        std::io::BufReader::new(file),
        dir,
        &index,
        options,
        file_bytes,
    )
}

/// Opens the footerless object `object` (at `path`, its URL) through its index in `dir`,
/// reading it once and writing the index first if there is none: from what its open
/// fetched if that was all of it, else with one GET streamed through the scan, at the
/// version `object` opened. `None` for an object with no `ETag`: its versions cannot be
/// told apart, so it is read whole each time, as without a cache.
#[cfg(feature = "object-store")]
pub(super) fn open_indexed_object(
    path: &Path,
    object: crate::storage::object::ObjectReader,
    dir: &Path,
    options: &DatasetOptions,
) -> Option<Result<Opened, DatasetError>> {
    use std::io::{Seek as _, SeekFrom};

    use crate::storage::object::ObjectStream;

    let size = object.size();
    let index = index_named(
        dir,
        &[
            object.url().as_bytes(),
            &size.to_le_bytes(),
            object.e_tag()?.as_bytes(),
        ],
    );
    let with_object = |opened: Opened, mut object: crate::storage::object::ObjectReader| {
        // What its open fetched (its end) is no footer: not kept.
        object.keep_from(size);
        Opened {
            object: Some(object),
            ..opened
        }
    };
    let data = || Some(Input::Object(object.clone()));
    if let Some(segment) = open_through(path, data, &index, size) {
        return Some(Ok(with_object(Opened::new(segment, None), object)));
    }
    let io = |error: std::io::Error| {
        DatasetError::from(OpenError::Io {
            path: path.to_owned(),
            source: error,
        })
    };
    let scanned = if object.fetched_whole() {
        let mut whole = object.clone();
        whole
            .seek(SeekFrom::Start(0))
            .map_err(io)
            .and_then(|_| scan(path, whole, dir, &index, options, size))
    } else {
        ObjectStream::of_version(&object)
            .map_err(|error| io(error.into_io()))
            .and_then(|stream| scan(path, stream, dir, &index, options, size))
    };
    Some(scanned.map(|opened| with_object(opened, object)))
}

/// The segment of `path` opened from `data` through the index `index`, if the index is
/// there, names the recording and places every chunk within the data's `data_bytes`.
fn open_through(
    path: &Path,
    data: impl FnOnce() -> Option<Input>,
    index: &Path,
    data_bytes: u64,
) -> Option<SegmentInfo> {
    if !index.is_file() {
        return None;
    }
    let index_file = std::fs::File::open(index).ok()?;
    let mut lazy = LazyRecording::with_index(data()?, index_file, None).ok()??;
    let info = lazy.store_info().cloned()?;
    if !lazy
        .manifest()
        .entries
        .iter()
        .all(|e| e.byte_offset.saturating_add(e.byte_size) <= data_bytes)
    {
        return None;
    }
    let reader = RecordingReader::lazy(&mut lazy);
    let mut segment = SegmentInfo::read(path, &info.store_id, &reader, data_bytes, false);
    segment.index_file = Some(index.to_owned());
    Some(segment)
}

/// Reads `path` from `input` once, start to end, writing its index to `index` in `dir`:
/// the segment, with what it read as its store.
fn scan(
    path: &Path,
    input: impl Read,
    dir: &Path,
    index: &Path,
    options: &DatasetOptions,
    file_bytes: u64,
) -> Result<Opened, DatasetError> {
    std::fs::create_dir_all(dir).map_err(|source| DatasetError::Io {
        path: dir.to_owned(),
        source,
    })?;
    let index_io = |source| DatasetError::Io {
        path: index.to_owned(),
        source,
    };
    // Written under a temporary name and renamed: a scan that fails, or a process that
    // dies, leaves no index that is not whole.
    let (info, chunks) = crate::output::atomic_write(index, index_io, |file| {
        let (scanned, out) =
            crate::rrd::index::scan_stream_and_index(input, std::io::BufWriter::new(file))
                .map_err(|error| DatasetError::from(OpenError::rrd(path, error)))?;
        let Some(info) = scanned.store_info else {
            return Err(DatasetError::NoRecordingId {
                path: path.to_owned(),
            });
        };
        let file = out.into_inner().map_err(|e| index_io(e.into_error()))?;
        Ok((file, (info, scanned.chunks)))
    })?;
    let mut store = ChunkStore::with_config(options.config)
        .map_err(|e| DatasetError::from(OpenError::Config(e)))?;
    for chunk in chunks {
        let id = chunk.id();
        store.insert(chunk).map_err(|error| {
            DatasetError::from(OpenError::Fault(Box::new(LoadFault::Chunk {
                path: path.to_owned(),
                id,
                offset: None,
                error,
            })))
        })?;
    }
    let reader = RecordingReader::view(&store);
    let mut segment = SegmentInfo::read(path, &info.store_id, &reader, file_bytes, false);
    segment.index_file = Some(index.to_owned());
    Ok(Opened::new(segment, Some(store.snapshot())))
}
