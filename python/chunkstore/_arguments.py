"""The arguments of the package's calls, checked and turned into what the native module
takes: counts, contents rules, and a dataframe's keywords as one dict
(:func:`dataframe_args`, read by the native module's ``DataframeArgs``)."""

from __future__ import annotations

from typing import Any, Iterable, Mapping, Optional, Union

from ._errors import InvalidInputError
from ._times import I64_MAX, Time, to_time


def positive(value: Optional[int], what: str) -> Optional[int]:
    """``value`` (a count of rows), if it is at least 1."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int):
        raise InvalidInputError(f"{what}: expected a positive int, got {type(value).__name__}")
    if not 1 <= value <= I64_MAX:
        raise InvalidInputError(f"{what}: {value} is not a positive number of rows")
    return value


def positive_or_zero(value: Optional[int]) -> Optional[int]:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InvalidInputError(f"memory_budget: expected a number of bytes >= 0, got {value!r}")
    return value


def contents_rules(contents: Union[None, str, Iterable[str]]) -> Optional[list]:
    if contents is None:
        return None
    if isinstance(contents, str):
        return [contents]
    rules = list(contents)
    if not all(isinstance(rule, str) for rule in rules):
        raise InvalidInputError("contents: expected a string or strings of entity path rules")
    return rules


def view_times(owner: Any, index: str, range: Optional[tuple], index_values: Optional[Iterable[Time]]) -> tuple:
    """A view's range and sampled values as integers on timeline ``index`` of ``owner``
    (a :class:`Store` or a :class:`Dataset`)."""
    time_type = owner._time_type(index)
    if range is not None:
        try:
            lo, hi = range
        except (TypeError, ValueError):
            raise InvalidInputError("range: expected a (lo, hi) pair") from None
        range = (to_time(lo, time_type, "range"), to_time(hi, time_type, "range"))
    if index_values is not None:
        if type(index_values).__module__ == "numpy":
            index_values = index_values.tolist() if index_values.dtype.kind in "iu" else list(index_values)
        index_values = [to_time(v, time_type, "index_values") for v in index_values]
    return range, index_values


def dataframe_args(
    owner: Any,
    index: str,
    contents: Any = None,
    range: Any = None,
    index_values: Any = None,
    fill_latest_at: bool = False,
    batch_rows: Optional[int] = None,
    include_tombstone_columns: bool = True,
    include_semantically_empty_columns: bool = True,
    exact_index_values: bool = False,
) -> dict:
    """A dataframe's keywords (``Store.dataframe``'s, ``Dataset.dataframe``'s,
    ``Store.write_parquet``'s) checked, times read on the index's type: one dict, the
    native module's ``DataframeArgs``."""
    range, index_values = view_times(owner, index, range, index_values)
    return {
        "index": index,
        "contents": contents_rules(contents),
        "range": range,
        "index_values": index_values,
        "fill_latest_at": bool(fill_latest_at),
        "batch_rows": positive(batch_rows, "batch_rows"),
        "include_tombstone_columns": bool(include_tombstone_columns),
        "include_semantically_empty_columns": bool(include_semantically_empty_columns),
        "exact_index_values": bool(exact_index_values),
    }


def storage_pairs(options: Optional[Mapping[str, str]]) -> Optional[list]:
    """``storage_options`` as the native module takes them: ``(key, value)`` strings."""
    if options is None:
        return None
    if not isinstance(options, Mapping):
        raise InvalidInputError(f"storage_options must be a mapping of str to str, not {type(options).__name__}")
    return [(str(key), str(value)) for key, value in options.items()]
