"""chunkstore: a columnar chunk store for spatiotemporal data, from Python.

Open a Rerun recording (``.rrd``) or a directory of Arrow IPC chunk files, ask for the
latest value of a component at a time, every value in a time range, or a whole
dataframe view, and get Arrow data back: ``pyarrow`` record batches and tables that
Polars, pandas and DuckDB read without a copy.

>>> import chunkstore
>>> store = chunkstore.open("recording.rrd")            # doctest: +SKIP
>>> store.timelines()                                   # doctest: +SKIP
[Timeline(name='frame_id', type='sequence', min=0, max=59), ...]
>>> store.dataframe("frame_id").read_all()              # doctest: +SKIP

Times are integers in the timeline's unit (sequence numbers, or nanoseconds), or, on
duration and timestamp timelines, ``datetime.timedelta``/``numpy.timedelta64`` and
``datetime.datetime``/``numpy.datetime64`` (a naive ``datetime`` is taken as UTC).

Every query runs on a snapshot with the GIL released: other Python threads may query,
and one may insert, at the same time.
"""

from __future__ import annotations

from . import _chunkstore
from ._dataset import Dataset, Segment, open_dataset
from ._errors import CorruptFileError, Error, InvalidInputError, UnknownTimelineError
from ._store import Store, open
from ._times import Time, Timeline

# The package's modules are private (`_store.py`, `_dataset.py`, `_times.py`,
# `_arguments.py`, `_errors.py`): what users name is re-exported here, as polars does.

__version__: str = _chunkstore.__version__
"""The package's version (the native crate's)."""

__all__ = [
    "CorruptFileError",
    "Dataset",
    "Error",
    "InvalidInputError",
    "Segment",
    "Store",
    "Time",
    "Timeline",
    "UnknownTimelineError",
    "__version__",
    "open",
    "open_dataset",
]
