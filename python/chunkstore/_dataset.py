""":class:`Dataset` (many recordings, one ``.rrd`` file each, as one table),
:class:`Segment` and :func:`open_dataset`."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Iterable, Mapping, NamedTuple, Optional, Union

from . import _chunkstore
from ._arguments import dataframe_args, positive_or_zero, storage_pairs
from ._errors import InvalidInputError, UnknownTimelineError
from ._times import Time, Timeline

if TYPE_CHECKING:
    import pyarrow


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

    def write_delta(
        self,
        table: Union[str, os.PathLike],
        *,
        index: Optional[str] = None,
        bucket: Optional[int] = None,
        append: bool = False,
        storage_options: Optional[Mapping[str, str]] = None,
    ) -> dict:
        """Writes the dataset as a Delta Lake table that Spark, DuckDB, Polars and
        ``deltalake`` read (``docs/SEMANTICS.md`` section 15): ``table`` is a new directory
        or a bucket's prefix (``s3://bucket/tables/episodes/``), or with ``append=True`` an
        existing table the dataset's segments are added to, as one commit (a segment in
        it already is refused, as is another partitioning). Partitioned by ``segment``,
        then by ``entity`` (rows ordered on ``index`` if given), or with ``index`` and
        ``bucket`` by ``<index>_bucket`` every ``bucket`` index values. Returns the
        commit: ``version``, ``rows``, ``files``, ``segments`` and ``retries`` (commits
        other writers made first). Raises ``FileExistsError`` for a new table where
        something is, ``InvalidInputError`` for what the table refuses."""
        version, rows, files, segments, retries = self._native.write_delta(
            os.fspath(table), index, bucket, append, storage_pairs(storage_options)
        )
        return {"version": version, "rows": rows, "files": files, "segments": segments, "retries": retries}

    def read_stats(self) -> dict:
        """What queries have read from the segments' files so far (opening aside):
        ``segment_reads``, ``chunks_decoded``, ``bytes_read``, and for segments in a
        bucket ``requests`` (GETs) and ``bytes_fetched`` (what they brought; 0 for local
        files)."""
        keys = ("segment_reads", "chunks_decoded", "bytes_read", "requests", "bytes_fetched")
        return dict(zip(keys, self._native.read_stats()))

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
        return self._native.dataframe(
            dataframe_args(
                self, index, contents, range, index_values, fill_latest_at, batch_rows,
                include_tombstone_columns, include_semantically_empty_columns, exact_index_values,
            )
        )

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
    storage_options: Optional[Mapping[str, str]] = None,
) -> Dataset:
    """Opens a dataset: a directory's regular ``.rrd`` files (or one ``.rrd`` file),
    each a segment named by its recording id, reading their footers only.

    ``skip_bad``: skip a file that cannot be read (see :meth:`Dataset.take_warnings`)
    rather than raise. ``memory_budget``: bytes of loaded segments kept between uses (by
    default a quarter of the machine's memory). ``index_cache``: a directory where the
    index of each file without a footer is kept once it has been scanned, so that later
    opens read the index instead of the file (never written beside the data).

    ``path`` may be a URL: a prefix ending in ``/`` (``s3://bucket/episodes/``) is a
    dataset of the ``.rrd`` objects directly under it, listed once and opened many at a
    time (one GET of each object's end). ``storage_options`` as for :func:`open`.

    Raises :class:`CorruptFileError` for a file that does not parse (or a directory
    without ``.rrd`` files), :class:`InvalidInputError` for two files of one recording.
    """
    cache = None if index_cache is None else os.fspath(index_cache)
    return Dataset(
        _native=_chunkstore.open_dataset(
            os.fspath(path), skip_bad, positive_or_zero(memory_budget), cache, storage_pairs(storage_options)
        )
    )
