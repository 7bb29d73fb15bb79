//! `chunkstore.open(path)`: any source the library's recording layer opens (an `.rrd`
//! file, lazily through its footer when it has one; a directory of Arrow IPC chunk files;
//! one such file), told apart by their contents.

use std::path::{Path, PathBuf};

use chunkstore::recording::{OpenOptions, Recording};
use chunkstore::storage::StorageOptions;
use pyo3::prelude::*;

use crate::errors::{no_panic, open_error};
use crate::store::NativeStore;

/// Opens `path`: see the module docs. `lazy=False` decodes an `.rrd` whole at once;
/// `recording` chooses one recording of a file that holds several; `storage_options`
/// are the object store's, for a URL.
#[pyfunction]
#[pyo3(signature = (path, lazy = true, recording = None, storage_options = None))]
pub fn open(
    py: Python<'_>,
    path: PathBuf,
    lazy: bool,
    recording: Option<String>,
    storage_options: Option<Vec<(String, String)>>,
) -> PyResult<NativeStore> {
    let storage = storage_from(storage_options);
    py.detach(|| no_panic(|| open_path(&path, lazy, recording, storage)))
}

/// The `storage_options` every function that names a source or an output takes: the
/// Python side's `(key, value)` pairs (`_arguments.storage_pairs`), or none.
pub fn storage_from(pairs: Option<Vec<(String, String)>>) -> StorageOptions {
    pairs.into_iter().flatten().collect()
}

fn open_path(
    path: &Path,
    lazy: bool,
    recording: Option<String>,
    storage: StorageOptions,
) -> PyResult<NativeStore> {
    let mut options = OpenOptions::default().with_lazy(lazy).with_storage(storage);
    if let Some(recording) = recording {
        options = options.with_recording(recording);
    }
    let recording = Recording::open(path, &options, &mut ()).map_err(open_error)?;
    NativeStore::open(recording)
}
