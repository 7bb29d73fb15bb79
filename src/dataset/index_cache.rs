//! The index cache ([`DatasetOptions::index_cache`](super::DatasetOptions::index_cache)):
//! a segment whose file has no footer is scanned once, and its detached index
//! (`crate::rrd::index`) kept in the cache directory under a name drawn from the file's
//! path, size and modification time. Later opens read the index instead of the file, and
//! queries read the file in part through it, as through a footer. Nothing is ever written
//! beside the data; a file that changes gets a new index (the old one stays until the
//! directory is cleared).

use std::path::{Path, PathBuf};

use super::{DatasetError, DatasetOptions, Opened, SegmentInfo};
use crate::ChunkStore;
use crate::recording::{LoadFault, OpenError, RecordingReader};
use crate::rrd::LazyRecording;

/// Where the index of `path` (whose metadata is `metadata`) is kept in `dir`.
fn index_file(dir: &Path, path: &Path, metadata: &std::fs::Metadata) -> PathBuf {
    use sha2::Digest as _;
    const HEX: &[u8; 16] = b"0123456789abcdef";
    let canonical = path.canonicalize().unwrap_or_else(|_| path.to_owned());
    let mtime = metadata
        .modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_nanos());
    let mut hash = sha2::Sha256::new();
    hash.update(canonical.as_os_str().as_encoded_bytes());
    hash.update(metadata.len().to_le_bytes());
    hash.update(mtime.to_le_bytes());
    let digest = hash.finalize();
    let name: String = digest[..16]
        .iter()
        .flat_map(|b| [HEX[usize::from(b >> 4)], HEX[usize::from(b & 0xF)]])
        .map(char::from)
        .collect();
    dir.join(format!("{name}.rrd-index"))
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
    if index.is_file()
        && let Ok(Some(lazy)) = LazyRecording::open_indexed(path, &index, None)
        && let Some(info) = lazy.store_info().cloned()
        && lazy
            .manifest()
            .entries
            .iter()
            .all(|e| e.byte_offset.saturating_add(e.byte_size) <= file_bytes)
    {
        let mut lazy = lazy.map_input(crate::storage::Input::File);
        let reader = RecordingReader::lazy(&mut lazy);
        let mut segment = SegmentInfo::read(path, &info.store_id, &reader, file_bytes, false);
        segment.index_file = Some(index);
        return Ok(Opened::new(segment, None));
    }
    std::fs::create_dir_all(dir).map_err(|source| DatasetError::Io {
        path: dir.to_owned(),
        source,
    })?;
    let index_io = |source| DatasetError::Io {
        path: index.clone(),
        source,
    };
    // Written under a temporary name and renamed: a scan that fails, or a process that
    // dies, leaves no index that is not whole.
    let (info, chunks) = crate::output::atomic_write(&index, index_io, |file| {
        let (scanned, out) = crate::rrd::index::scan_and_index(path, std::io::BufWriter::new(file))
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
    segment.index_file = Some(index);
    Ok(Opened::new(segment, Some(store.snapshot())))
}
