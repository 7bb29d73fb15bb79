//! `chunkstore.open(path)`: an `.rrd` file (lazily through its footer when it has one), a
//! directory of Arrow IPC chunk files, or one such file, told apart by their contents.

use std::io::Read as _;
use std::path::{Path, PathBuf};

use chunkstore::ChunkStore;
use chunkstore::rrd::{LazyRecording, RecordingSelector, RrdItem, RrdReader, StoreInfo};
use pyo3::prelude::*;

use crate::errors::{
    CorruptFileError, ipc_error, no_panic, os_error, recording_error, recording_or_rrd_error,
    rrd_error,
};
use crate::store::NativeStore;

/// Opens `path`: see the module docs. `lazy=False` decodes an `.rrd` whole at once;
/// `recording` chooses one recording of a file that holds several.
#[pyfunction]
#[pyo3(signature = (path, lazy = true, recording = None))]
pub fn open(
    py: Python<'_>,
    path: PathBuf,
    lazy: bool,
    recording: Option<String>,
) -> PyResult<NativeStore> {
    py.detach(|| no_panic(|| open_path(&path, lazy, recording.as_deref())))
}

fn open_path(path: &Path, lazy: bool, recording: Option<&str>) -> PyResult<NativeStore> {
    let metadata = std::fs::metadata(path).map_err(|e| os_error(path, e))?;
    if metadata.is_dir() {
        let info = chunkstore::rrd::read_directory_recording(path, recording).map_err(|error| {
            if error.is_recording_choice() {
                recording_error(path, error.kind)
            } else {
                rrd_error(&path.join(chunkstore::rrd::STORE_INFO_FILE), error)
            }
        })?;
        return load_directory(path).map(|store| NativeStore::loaded(store, info, Some(path)));
    }
    let head = file_head(path)?;
    if chunkstore::rrd::looks_like_rrd(&head) {
        if lazy {
            match LazyRecording::open_recording(path, recording) {
                Ok(Some(lazy)) => return Ok(NativeStore::lazy(lazy, path.to_owned())),
                Ok(None) => {}
                Err(error) => return Err(recording_or_rrd_error(path, error)),
            }
        }
        let (store, info) = load_rrd(path, recording)?;
        return Ok(NativeStore::loaded(store, info, Some(path)));
    }
    if head.starts_with(b"ARROW1") || head.starts_with(&[0xff; 4]) {
        let mut store = new_store();
        insert_ipc_file(&mut store, path)?;
        return Ok(NativeStore::loaded(store, None, Some(path)));
    }
    Err(CorruptFileError::new_err(format!(
        "{}: neither an .rrd file nor Arrow IPC (it starts with {:?})",
        path.display(),
        String::from_utf8_lossy(&head)
    )))
}

fn new_store() -> ChunkStore {
    ChunkStore::new()
}

/// The first 8 bytes (fewer if the file is shorter).
fn file_head(path: &Path) -> PyResult<Vec<u8>> {
    let file = std::fs::File::open(path).map_err(|e| os_error(path, e))?;
    let mut head = Vec::with_capacity(8);
    file.take(8)
        .read_to_end(&mut head)
        .map_err(|e| os_error(path, e))?;
    Ok(head)
}

/// Every chunk of one recording of an `.rrd` file, streamed into a store, and the
/// recording's store info.
fn load_rrd(path: &Path, recording: Option<&str>) -> PyResult<(ChunkStore, Option<StoreInfo>)> {
    let file = std::fs::File::open(path).map_err(|e| os_error(path, e))?;
    let reader = RrdReader::new(std::io::BufReader::with_capacity(1 << 20, file))
        .map_err(|e| rrd_error(path, e))?;
    let mut store = new_store();
    let mut selector = RecordingSelector::new(recording);
    for item in reader {
        match item.map_err(|e| rrd_error(path, e))? {
            RrdItem::Chunk {
                chunk,
                offset,
                store_id,
            } => {
                if !selector
                    .wants(&store_id)
                    .map_err(|kind| recording_error(path, kind))?
                {
                    continue;
                }
                store.insert(chunk).map_err(|e| {
                    CorruptFileError::new_err(format!(
                        "{}: the chunk at byte {offset}: {e}",
                        path.display(),
                    ))
                })?;
            }
            RrdItem::StoreInfo(found) => selector.observe(&found),
            _ => {}
        }
    }
    let info = selector
        .finish()
        .map_err(|kind| recording_error(path, kind))?;
    Ok((store, info))
}

/// Every Arrow IPC file (`.arrow`, `.arrows`, `.ipc`, `.feather`) of a directory, in name
/// order.
fn load_directory(dir: &Path) -> PyResult<ChunkStore> {
    let files = chunkstore::io::chunk_files(dir).map_err(ipc_error)?;
    if files.is_empty() {
        return Err(CorruptFileError::new_err(format!(
            "{}: no Arrow IPC files (.{})",
            dir.display(),
            chunkstore::io::IPC_EXTENSIONS.join(", .")
        )));
    }
    let mut store = new_store();
    for file in &files {
        insert_ipc_file(&mut store, file)?;
    }
    Ok(store)
}

fn insert_ipc_file(store: &mut ChunkStore, path: &Path) -> PyResult<()> {
    for chunk in chunkstore::io::read_chunks_from_path(path).map_err(ipc_error)? {
        store
            .insert(chunk)
            .map_err(|e| CorruptFileError::new_err(format!("{}: {e}", path.display())))?;
    }
    Ok(())
}
