""":class:`Store` (a chunk store in memory, or a recording read lazily) and :func:`open`."""

from __future__ import annotations

import os
import warnings
from typing import TYPE_CHECKING, Any, Iterable, Mapping, Optional, Sequence, Union

from . import _chunkstore
from ._arguments import contents_rules, dataframe_args, positive, storage_pairs
from ._errors import InvalidInputError
from ._times import Time, Timeline, to_time

if TYPE_CHECKING:
    import pyarrow


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
        return self._native.schema(index, contents_rules(contents))

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

    def read_stats(self) -> Optional[dict]:
        """What a store opened lazily has read from its source so far: ``chunks_in_file``,
        ``chunks_decoded``, ``bytes_read``, and for an object in a bucket ``requests``
        (GETs, the open's included) and ``bytes_fetched`` (what they brought; 0 for a
        local file). Kept once the store is decoded whole. ``None`` for a store that was
        never lazy."""
        stats = self._native.read_stats()
        if stats is None:
            return None
        keys = ("chunks_in_file", "chunks_decoded", "bytes_read", "requests", "bytes_fetched")
        return dict(zip(keys, stats))

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
        return self._native.latest_at(timeline, to_time(time, time_type, "time"), entity, components)

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
            to_time(lo, time_type, "lo"),
            to_time(hi, time_type, "hi"),
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
        return self._native.dataframe(
            dataframe_args(
                self, index, contents, range, index_values, fill_latest_at, batch_rows,
                include_tombstone_columns, include_semantically_empty_columns, exact_index_values,
            )
        )

    # --- files -----------------------------------------------------------------------

    def write_rrd(
        self,
        path: Union[str, os.PathLike],
        application_id: str = "chunkstore",
        recording_id: Optional[str] = None,
        *,
        storage_options: Optional[Mapping[str, str]] = None,
    ) -> int:
        """Writes every chunk to an ``.rrd`` file that Rerun opens (atomically: the file
        appears whole or not at all). Returns its size in bytes. ``path`` may be a URL
        (``s3://bucket/run.rrd``; ``storage_options`` as for :func:`open`): the file is
        written locally, then uploaded whole.

        The recording keeps the store info it was read with (its application and
        recording ids); ``recording_id`` renames it. A store that has none (built in
        memory, or from chunk files) is named ``application_id`` and ``recording_id``
        (default: the file's name). Writing over the file the store was opened from is
        refused (:class:`InvalidInputError`)."""
        return self._native.write_rrd(os.fspath(path), application_id, recording_id, storage_pairs(storage_options))

    def write_parquet(
        self,
        path: Union[str, os.PathLike],
        index: str,
        contents: Union[None, str, Iterable[str]] = None,
        range: Optional[tuple] = None,
        index_values: Optional[Iterable[Time]] = None,
        fill_latest_at: bool = False,
        row_group_rows: Optional[int] = None,
        *,
        include_tombstone_columns: bool = True,
        include_semantically_empty_columns: bool = True,
        exact_index_values: bool = False,
        storage_options: Optional[Mapping[str, str]] = None,
    ) -> int:
        """Writes :meth:`dataframe`'s table (the same arguments) to a Parquet file
        (atomically), with the statistics engines prune by, beside :meth:`write_rrd`.
        ``row_group_rows``: rows per row group at most. Returns the rows written. ``path``
        may be a URL, as for :meth:`write_rrd`."""
        args = dataframe_args(
            self, index, contents, range, index_values, fill_latest_at, None,
            include_tombstone_columns, include_semantically_empty_columns, exact_index_values,
        )
        return self._native.write_parquet(
            os.fspath(path), args, positive(row_group_rows, "row_group_rows"), storage_pairs(storage_options)
        )

    def to_parquet(self, *args: Any, **kwargs: Any) -> int:
        """Deprecated: :meth:`write_parquet`, under the name it had before 0.2 (kept for
        one release)."""
        warnings.warn(
            "Store.to_parquet is deprecated: use Store.write_parquet (the same arguments)",
            DeprecationWarning,
            stacklevel=2,
        )
        return self.write_parquet(*args, **kwargs)


def open(
    path: Union[str, os.PathLike],
    *,
    lazy: bool = True,
    recording: Optional[str] = None,
    storage_options: Optional[Mapping[str, str]] = None,
) -> Store:
    """Opens an ``.rrd`` file (lazily, through its footer, when it has one and ``lazy``
    is true), a directory of Arrow IPC chunk files, or one such file.

    ``path`` may be a URL of an ``.rrd`` object: ``s3://bucket/run.rrd``, ``gs://``,
    ``az://``, ``abfs://``, ``https://``. It is read as a local file is, through ranged
    GETs of the chunks a query needs. Credentials, region and endpoint come from the
    environment (``AWS_*``, ``GOOGLE_*``, ``AZURE_*``) and from ``storage_options``
    (``{"aws_endpoint": ..., "aws_region": ...}``: the keys polars and deltalake take),
    which win.

    A file can hold several recordings (streams concatenated, or several recordings in
    one stream): ``recording`` chooses one by its recording id; without it, such a file
    raises :class:`InvalidInputError` naming them. A blueprint is never read as data.

    Raises ``FileNotFoundError`` (and other ``OSError``) from the file system, and
    :class:`CorruptFileError` for a file that does not parse.
    """
    return Store(_native=_chunkstore.open(os.fspath(path), lazy, recording, storage_pairs(storage_options)))

