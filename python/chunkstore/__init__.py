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

import datetime as _dt
import os
from typing import TYPE_CHECKING, Any, Iterable, NamedTuple, Optional, Sequence, Union

from . import _chunkstore
from ._errors import CorruptFileError, Error, InvalidInputError, UnknownTimelineError

__version__: str = _chunkstore.__version__
"""The package's version (the native crate's)."""

if TYPE_CHECKING:
    import pyarrow

__all__ = [
    "CorruptFileError",
    "Dataset",
    "Error",
    "InvalidInputError",
    "Store",
    "Timeline",
    "UnknownTimelineError",
    "__version__",
    "open",
    "open_dataset",
]

Time = Union[int, _dt.datetime, _dt.timedelta, Any]
"""An integer in the timeline's unit, or a datetime/timedelta (Python or numpy)."""

_EPOCH = _dt.datetime(1970, 1, 1, tzinfo=_dt.timezone.utc)


class Timeline(NamedTuple):
    """A timeline of the store: its name, its type (``"sequence"``, ``"duration"`` or
    ``"timestamp"``) and the least and greatest time of its data (integers in its unit,
    ``None`` when no data is left on it)."""

    name: str
    type: str
    min: Optional[int]
    max: Optional[int]

    def span(self) -> Optional[tuple]:
        """``(min, max)`` as Python times: ``datetime`` (UTC) on a timestamp timeline,
        ``timedelta`` on a duration one, ``int`` on a sequence; ``None`` without data.
        Python's times hold microseconds: ``min``/``max`` keep the exact nanoseconds."""
        if self.min is None or self.max is None:
            return None
        return (_from_ns(self.min, self.type), _from_ns(self.max, self.type))


def _from_ns(value: int, time_type: str) -> Any:
    """A time in nanoseconds as the Python time of its timeline's type (microseconds,
    rounded towards the past)."""
    if time_type == "timestamp":
        return _EPOCH + _dt.timedelta(microseconds=value // 1_000)
    if time_type == "duration":
        return _dt.timedelta(microseconds=value // 1_000)
    return value


def _timedelta_ns(value: _dt.timedelta) -> int:
    return (value.days * 86_400 + value.seconds) * 1_000_000_000 + value.microseconds * 1_000


_I64_MIN, _I64_MAX = -(2**63), 2**63 - 1


def _in_range(value: int, what: str) -> int:
    """``value``, if an ``i64`` holds it."""
    if not _I64_MIN <= value <= _I64_MAX:
        raise InvalidInputError(f"{what}: {value} is outside the 64-bit range of times")
    return value


def _to_time(value: Time, time_type: str, what: str) -> int:
    """``value`` as an integer on a timeline of ``time_type``."""
    if isinstance(value, bool):
        raise InvalidInputError(f"{what}: a bool is not a time")
    if isinstance(value, int):
        return _in_range(value, what)
    if type(value).__module__.startswith("pyarrow") and hasattr(value, "as_py"):
        # A pyarrow scalar (an item of a pyarrow array, too): its Python value, whose
        # type says the unit. A null is no time.
        if not getattr(value, "is_valid", True):
            raise InvalidInputError(f"{what}: a null is not a time")
        unit_ns = _pyarrow_ns(value)
        if unit_ns is not None:
            return _in_range(unit_ns, what)
        return _to_time(value.as_py(), time_type, what)
    type_name = type(value).__module__ + "." + type(value).__name__
    if type_name == "numpy.datetime64":
        if time_type != "timestamp":
            raise InvalidInputError(f"{what}: a datetime64 on a {time_type} timeline")
        return int(value.astype("datetime64[ns]").astype("int64"))
    if type_name == "numpy.timedelta64":
        if time_type == "sequence":
            raise InvalidInputError(f"{what}: a timedelta64 on a sequence timeline")
        return int(value.astype("timedelta64[ns]").astype("int64"))
    if type(value).__module__ == "numpy" and hasattr(value, "dtype") and value.dtype.kind in "iu":
        return int(value)
    if isinstance(value, _dt.datetime):
        if time_type != "timestamp":
            raise InvalidInputError(f"{what}: a datetime on a {time_type} timeline")
        if value.tzinfo is None:
            value = value.replace(tzinfo=_dt.timezone.utc)
        return _timedelta_ns(value - _EPOCH)
    if isinstance(value, _dt.timedelta):
        if time_type == "sequence":
            raise InvalidInputError(f"{what}: a timedelta on a sequence timeline")
        return _timedelta_ns(value)
    raise InvalidInputError(
        f"{what}: expected an int, datetime or timedelta, got {type(value).__name__}"
    )


def _pyarrow_ns(value: Any) -> Optional[int]:
    """A pyarrow timestamp or duration scalar in nanoseconds, exactly (``as_py`` would
    round to microseconds); ``None`` for other scalars."""
    import pyarrow as pa

    kind = value.type
    if pa.types.is_timestamp(kind) or pa.types.is_duration(kind):
        per_unit = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}[kind.unit]
        return value.cast(pa.int64()).as_py() * per_unit
    return None


def _positive(value: Optional[int], what: str) -> Optional[int]:
    """``value`` (a count of rows), if it is at least 1."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int):
        raise InvalidInputError(f"{what}: expected a positive int, got {type(value).__name__}")
    if not 1 <= value <= _I64_MAX:
        raise InvalidInputError(f"{what}: {value} is not a positive number of rows")
    return value


def _contents(contents: Union[None, str, Iterable[str]]) -> Optional[list]:
    if contents is None:
        return None
    if isinstance(contents, str):
        return [contents]
    rules = list(contents)
    if not all(isinstance(rule, str) for rule in rules):
        raise InvalidInputError("contents: expected a string or strings of entity path rules")
    return rules


class Store:
    """A chunk store in memory (or a recording read lazily through its footer).

    ``Store()`` is empty; :func:`open` reads a file or directory. ``compaction=False``
    keeps chunks exactly as inserted (by default small chunks are merged as they
    arrive, which changes no answer).
    """

    __slots__ = ("_native",)

    def __init__(self, compaction: bool = True, *, _native: Any = None) -> None:
        self._native = _native if _native is not None else _chunkstore.NativeStore(compaction)

    # --- discovery -------------------------------------------------------------------

    def entities(self) -> list:
        """Every entity path with data, sorted (``["/world/robot", ...]``)."""
        return self._native.entities()

    def components(self, entity: str) -> list:
        """The component names of ``entity``, sorted (empty if it holds no data)."""
        return self._native.components(entity)

    def timelines(self) -> list:
        """Every timeline, sorted by name, as :class:`Timeline` tuples."""
        return [Timeline(*t) for t in self._native.timelines()]

    def schema(
        self, index: Optional[str] = None, contents: Union[None, str, Iterable[str]] = None
    ) -> "pyarrow.Schema":
        """The schema :meth:`dataframe` gives on ``index`` (by default the first timeline
        by name) for ``contents``: the index columns, then a list column per (entity,
        component), each with Rerun's field metadata. Empty for a store without
        timelines."""
        if index is None:
            timelines = self._native.timelines()
            if not timelines:
                import pyarrow

                return pyarrow.schema([])
            index = timelines[0][0]
        return self._native.schema(index, _contents(contents))

    @property
    def num_chunks(self) -> int:
        """Chunks held (for a lazy recording: chunks in the file)."""
        return self._native.counts()[1]

    @property
    def heap_bytes(self) -> int:
        """Heap bytes the store's chunks and indices hold (a shared Arrow buffer counted
        once). Decodes a lazy recording whole."""
        return self._native.heap_bytes()

    @property
    def is_lazy(self) -> bool:
        """Is the store still reading its ``.rrd`` lazily (only the chunks queries needed
        are decoded)?"""
        return self._native.is_lazy()

    def __len__(self) -> int:
        """Rows held (for a lazy recording: rows in the file)."""
        return self._native.counts()[0]

    def __repr__(self) -> str:
        rows, chunks = self._native.counts()
        timelines = ", ".join(
            f"{t.name} ({t.type}) [{t.min}, {t.max}]" if t.min is not None else f"{t.name} ({t.type}) empty"
            for t in self.timelines()
        )
        lazy = ", lazy" if self.is_lazy else ""
        return (
            f"<chunkstore.Store: {len(self.entities())} entities, {chunks} chunks, {rows} rows"
            f"{lazy}; timelines: {timelines or 'none'}>"
        )

    # --- writes ----------------------------------------------------------------------

    def insert(self, data: Any) -> int:
        """Inserts chunks in Rerun's chunk layout: a ``pyarrow.RecordBatch`` (one chunk),
        a ``pyarrow.Table`` or any iterable of record batches (one chunk each). Returns
        the rows inserted. Rows the store already holds (same row id) change nothing."""
        import pyarrow

        if isinstance(data, pyarrow.RecordBatch):
            return self._native.insert(data)
        if isinstance(data, pyarrow.Table):
            batches = data.to_batches()
        else:
            batches = data
        return sum(self._native.insert(batch) for batch in batches)

    def gc(
        self,
        fraction: Optional[float] = None,
        *,
        bytes: Optional[int] = None,
        protect_latest: int = 0,
    ) -> tuple:
        """Garbage collection: drops whole temporal chunks until at least ``fraction`` of
        the heap (or ``bytes`` bytes) is freed; with neither, every unprotected temporal
        chunk. Static data is never dropped; ``protect_latest=n`` keeps the ``n`` latest
        chunks of every (entity, timeline, component). Returns ``(chunks, rows)``
        dropped."""
        return self._native.gc(fraction, bytes, protect_latest)

    def compact(self) -> tuple:
        """Merges small chunks into time-sorted ones (answers unchanged). Returns
        ``(chunks before, chunks after)``."""
        return self._native.compact()

    # --- queries ---------------------------------------------------------------------

    def _time_type(self, timeline: str) -> str:
        if not isinstance(timeline, str):
            raise InvalidInputError(f"timeline: expected a name (str), got {type(timeline).__name__}")
        return self._native.time_type(timeline)

    def latest_at(
        self,
        timeline: str,
        time: Time,
        entity: str,
        components: Union[None, str, Sequence[str]] = None,
    ) -> "pyarrow.RecordBatch":
        """The value of each component of ``entity`` as of ``time`` on ``timeline``
        (static data wins; Clears hide older values).

        One row: the greatest time and row id among the answers, then one list column per
        component (null where it has no value yet). No row when no component has one.
        """
        time_type = self._time_type(timeline)
        if isinstance(components, str):
            components = [components]
        elif components is not None:
            components = list(components)
        return self._native.latest_at(timeline, _to_time(time, time_type, "time"), entity, components)

    def range(
        self,
        timeline: str,
        lo: Time,
        hi: Time,
        *,
        entity: str,
        component: str,
    ) -> "pyarrow.Table":
        """Every value of ``entity``'s ``component`` logged in ``[lo, hi]`` (inclusive) on
        ``timeline``, in (time, row id) order: columns ``<timeline>``, ``row_id`` and the
        component's list column. Static data shows as one row with a null time."""
        time_type = self._time_type(timeline)
        return self._native.range(
            timeline,
            _to_time(lo, time_type, "lo"),
            _to_time(hi, time_type, "hi"),
            entity,
            component,
        )

    def sql(self, query: str) -> "pyarrow.RecordBatchReader":
        """The answer of a SQL query (DataFusion's dialect) over a snapshot of the store,
        streamed batch by batch: one table per timeline (its dataframe view, every
        column, no fill), ``chunks`` (every stored row) and the table function
        ``latest_at('<timeline>', <time>)`` (``docs/SEMANTICS.md`` section 12). Filters on
        the index and on ``entity_path`` are answered by the store's indices. A lazy
        recording is decoded whole first; writes after the call are not seen.

        >>> store.sql('SELECT avg("/robot/arm:torque"[1]) FROM frame WHERE frame < 100').read_all()

        Raises :class:`InvalidInputError` for a query that cannot be planned."""
        if not isinstance(query, str):
            raise InvalidInputError(f"query: expected SQL text (str), got {type(query).__name__}")
        return self._native.sql(query)

    def dataframe(
        self,
        index: str,
        contents: Union[None, str, Iterable[str]] = None,
        range: Optional[tuple] = None,
        index_values: Optional[Iterable[Time]] = None,
        fill_latest_at: bool = False,
        batch_rows: Optional[int] = None,
        *,
        include_tombstone_columns: bool = True,
        include_semantically_empty_columns: bool = True,
        exact_index_values: bool = False,
    ) -> "pyarrow.RecordBatchReader":
        """The store as a table on timeline ``index`` (SEMANTICS.md section 9), streamed
        from one snapshot as a ``pyarrow.RecordBatchReader``.

        ``include_tombstone_columns`` and ``include_semantically_empty_columns``: keep the
        ``Clear:is_recursive`` columns and the columns whose every cell is null or empty
        (both kept by default; Rerun's reader leaves them out by default).
        ``exact_index_values``: with ``index_values``, each row shows only what was logged
        at exactly that value (Rerun's sampling without ``fill_latest_at``).

        ``contents``: entity path rules (``"/world/**"``, ``"-/world/noise"``); by default
        every entity but ``/__properties``. ``range=(lo, hi)``: only rows in it.
        ``index_values``: one row per value given, each column's latest-at there, instead
        of a row per time with data. ``fill_latest_at``: nulls filled with the latest
        value before. ``batch_rows``: rows per batch (by default about a million cells a
        batch, and at least 4,096 rows: each batch and column costs a fixed import).

        ``.read_all()`` gives a ``pyarrow.Table``; ``polars.from_arrow(reader)`` a Polars
        frame; ``reader.read_pandas()`` a pandas one.
        """
        return _reader(self, index, contents, range, index_values, fill_latest_at, batch_rows,
                       include_tombstone_columns, include_semantically_empty_columns, exact_index_values)

    def _view_times(self, index: str, range: Optional[tuple], index_values: Optional[Iterable[Time]]) -> tuple:
        """A view's range and sampled values as integers on timeline ``index``."""
        time_type = self._time_type(index)
        if range is not None:
            try:
                lo, hi = range
            except (TypeError, ValueError):
                raise InvalidInputError("range: expected a (lo, hi) pair") from None
            range = (_to_time(lo, time_type, "range"), _to_time(hi, time_type, "range"))
        if index_values is not None:
            if type(index_values).__module__ == "numpy":
                index_values = index_values.tolist() if index_values.dtype.kind in "iu" else list(index_values)
            index_values = [_to_time(v, time_type, "index_values") for v in index_values]
        return range, index_values

    # --- files -----------------------------------------------------------------------

    def write_rrd(
        self,
        path: Union[str, os.PathLike],
        application_id: str = "chunkstore",
        recording_id: Optional[str] = None,
    ) -> int:
        """Writes every chunk to an ``.rrd`` file that Rerun opens (atomically: the file
        appears whole or not at all). Returns its size in bytes.

        The recording keeps the store info it was read with (its application and
        recording ids); ``recording_id`` renames it. A store that has none (built in
        memory, or from chunk files) is named ``application_id`` and ``recording_id``
        (default: the file's name). Writing over the file the store was opened from is
        refused (:class:`InvalidInputError`)."""
        return self._native.write_rrd(os.fspath(path), application_id, recording_id)

    def to_parquet(
        self,
        path: Union[str, os.PathLike],
        index: str,
        contents: Union[None, str, Iterable[str]] = None,
        range: Optional[tuple] = None,
        index_values: Optional[Iterable[Time]] = None,
        fill_latest_at: bool = False,
        row_group_rows: Optional[int] = None,
    ) -> int:
        """Writes :meth:`dataframe`'s table to a Parquet file (atomically), with the
        statistics engines prune by. Returns the rows written."""
        range, index_values = self._view_times(index, range, index_values)
        return self._native.to_parquet(
            os.fspath(path),
            index,
            _contents(contents),
            range,
            index_values,
            fill_latest_at,
            _positive(row_group_rows, "row_group_rows"),
        )


def _reader(owner: Any, index: str, contents: Any, range: Any, index_values: Any, fill_latest_at: bool,
            batch_rows: Optional[int], tombstones: bool, semantically_empty: bool, exact: bool) -> Any:
    """A store's or a dataset's ``dataframe``: the arguments checked and read on the index's
    type, then the native reader."""
    range, index_values = Store._view_times(owner, index, range, index_values)
    return owner._native.dataframe(
        index,
        _contents(contents),
        range,
        index_values,
        fill_latest_at,
        _positive(batch_rows, "batch_rows"),
        tombstones,
        semantically_empty,
        exact,
    )


def open(path: Union[str, os.PathLike], *, lazy: bool = True, recording: Optional[str] = None) -> Store:
    """Opens an ``.rrd`` file (lazily, through its footer, when it has one and ``lazy``
    is true), a directory of Arrow IPC chunk files, or one such file.

    A file can hold several recordings (streams concatenated, or several recordings in
    one stream): ``recording`` chooses one by its recording id; without it, such a file
    raises :class:`InvalidInputError` naming them. A blueprint is never read as data.

    Raises ``FileNotFoundError`` (and other ``OSError``) from the file system, and
    :class:`CorruptFileError` for a file that does not parse.
    """
    return Store(_native=_chunkstore.open(os.fspath(path), lazy, recording))


class Segment(NamedTuple):
    """One recording of a :class:`Dataset`: its recording id (the segment's name), the
    application that logged it, its file, its rows and chunks, and its timelines."""

    id: str
    application_id: str
    path: str
    num_rows: int
    num_chunks: int
    timelines: list


class Dataset:
    """Many recordings, one ``.rrd`` file each, queried as one table with a
    ``rerun_segment_id`` column first (``docs/SEMANTICS.md`` section 15), as Rerun's
    catalog serves a dataset. Made by :func:`open_dataset`."""

    __slots__ = ("_native",)

    def __init__(self, *, _native: Any) -> None:
        self._native = _native

    def segments(self) -> list:
        """The segments, sorted by recording id."""
        return [
            Segment(id, app, os.fspath(path), rows, chunks, [Timeline(*t) for t in timelines])
            for (id, app, path, rows, chunks, timelines) in self._native.segments()
        ]

    def timelines(self) -> list:
        """Every timeline of any segment, sorted by name, with its span over all of them."""
        return [Timeline(*t) for t in self._native.timelines()]

    def take_warnings(self) -> list:
        """What was skipped so far (``skip_bad``), each once."""
        return self._native.take_warnings()

    def __len__(self) -> int:
        """Segments."""
        return len(self._native.segments())

    def __repr__(self) -> str:
        return f"<chunkstore.Dataset: {len(self)} segments>"

    def dataframe(
        self,
        index: str,
        contents: Union[None, str, Iterable[str]] = None,
        range: Optional[tuple] = None,
        index_values: Optional[Iterable[Time]] = None,
        fill_latest_at: bool = False,
        batch_rows: Optional[int] = None,
        *,
        include_tombstone_columns: bool = True,
        include_semantically_empty_columns: bool = True,
        exact_index_values: bool = False,
    ) -> "pyarrow.RecordBatchReader":
        """Every segment's table on timeline ``index`` (each exactly what
        :meth:`Store.dataframe` gives on that recording, filled within it), one after
        another in segment order, in the union of their columns: ``rerun_segment_id``,
        the timelines, then every segment's data columns (null where a segment lacks
        one). A segment without data on ``index`` gives no rows; an index no segment has
        raises :class:`UnknownTimelineError`. The arguments are
        :meth:`Store.dataframe`'s."""
        return _reader(self, index, contents, range, index_values, fill_latest_at, batch_rows,
                       include_tombstone_columns, include_semantically_empty_columns, exact_index_values)

    def sql(self, query: str) -> "pyarrow.RecordBatchReader":
        """The answer of a SQL query (DataFusion's dialect) over the dataset's tables,
        streamed batch by batch: one table per timeline (the dataset's table on it, as
        :meth:`dataframe` gives it with every column and no fill) and ``chunks`` (every
        segment's stored rows), each with ``rerun_segment_id`` first. Filters on
        ``rerun_segment_id`` and on the index skip whole files and chunks before any is
        read (``EXPLAIN`` shows what was pruned). ``docs/SEMANTICS.md`` section 15.

        >>> dataset.sql("SELECT rerun_segment_id, count(*) FROM frame GROUP BY 1").read_all()

        Raises :class:`InvalidInputError` for a query that cannot be planned (SQL that
        does not parse, a table or column that is not there); a file that fails while
        the answer streams raises from the reader."""
        if not isinstance(query, str):
            raise InvalidInputError(f"query: expected SQL text (str), got {type(query).__name__}")
        return self._native.sql(query)

    def _time_type(self, timeline: str) -> str:
        if not isinstance(timeline, str):
            raise InvalidInputError(f"timeline: expected a name (str), got {type(timeline).__name__}")
        time_type = self._native.time_type(timeline)
        if time_type is None:
            known = ", ".join(t.name for t in self.timelines()) or "none"
            raise UnknownTimelineError(
                f"no segment has the index: unknown timeline {timeline!r} (the timelines are: {known})"
            )
        return time_type


def open_dataset(
    path: Union[str, os.PathLike],
    *,
    skip_bad: bool = False,
    memory_budget: Optional[int] = None,
    index_cache: Union[None, str, os.PathLike] = None,
) -> Dataset:
    """Opens a dataset: a directory's regular ``.rrd`` files (or one ``.rrd`` file),
    each a segment named by its recording id, reading their footers only.

    ``skip_bad``: skip a file that cannot be read (see :meth:`Dataset.take_warnings`)
    rather than raise. ``memory_budget``: bytes of loaded segments kept between uses (by
    default a quarter of the machine's memory). ``index_cache``: a directory where the
    index of each file without a footer is kept once it has been scanned, so that later
    opens read the index instead of the file (never written beside the data).

    Raises :class:`CorruptFileError` for a file that does not parse (or a directory
    without ``.rrd`` files), :class:`InvalidInputError` for two files of one recording.
    """
    cache = None if index_cache is None else os.fspath(index_cache)
    return Dataset(
        _native=_chunkstore.open_dataset(os.fspath(path), skip_bad, _positive_or_zero(memory_budget), cache)
    )


def _positive_or_zero(value: Optional[int]) -> Optional[int]:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InvalidInputError(f"memory_budget: expected a number of bytes >= 0, got {value!r}")
    return value
