//! `chunkstore._chunkstore`: the native half of the `chunkstore` Python package.
//!
//! The Python half (`python/chunkstore/`) takes the user's arguments as Python likes them
//! (times as `datetime`, `numpy.datetime64` or `int`; contents as one string or many),
//! turns them into plain integers and strings, and calls this module. This module holds
//! the store, runs every query with the GIL released on a snapshot (so other Python
//! threads query, and one inserts, meanwhile), and hands tables back through the Arrow C
//! data interface: no copy, no Python object per cell.
//!
//! Errors: every failure is a Python exception, never a panic. User input the store
//! refuses raises `chunkstore.InvalidInputError`, a file that does not parse
//! `chunkstore.CorruptFileError`, an unknown timeline `chunkstore.UnknownTimelineError`
//! (all three subclasses of `chunkstore.Error`, and of `ValueError`, `ValueError` and
//! `KeyError`: they are defined in `chunkstore/_errors.py`), and a failing file system Python's own
//! `OSError` subclass. A panic inside the store (a bug) is caught at the boundary and
//! raised as `chunkstore.Error` naming it as one.

#![allow(
    clippy::needless_pass_by_value,
    reason = "pyo3 hands arguments over owned: a method takes what Python gave it"
)]

mod dataframe_args;
mod dataset;
mod errors;
mod open;
mod store;
mod tables;

use pyo3::prelude::*;

/// The native module.
#[pymodule]
fn _chunkstore(module: &Bound<'_, PyModule>) -> PyResult<()> {
    module.add("__version__", env!("CARGO_PKG_VERSION"))?;
    module.add_class::<store::NativeStore>()?;
    module.add_function(wrap_pyfunction!(open::open, module)?)?;
    module.add_class::<dataset::NativeDataset>()?;
    module.add_function(wrap_pyfunction!(dataset::open_dataset, module)?)?;
    Ok(())
}
