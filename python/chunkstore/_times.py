"""Times as the user writes them (``int``, ``datetime``, ``timedelta``, numpy's and
pyarrow's), as integers on a timeline of a given type; and :class:`Timeline`."""

from __future__ import annotations

import datetime as _dt
from typing import Any, NamedTuple, Optional, Union

from ._errors import InvalidInputError

Time = Union[int, _dt.datetime, _dt.timedelta, Any]
"""An integer in the timeline's unit, or a datetime/timedelta (Python or numpy)."""

EPOCH = _dt.datetime(1970, 1, 1, tzinfo=_dt.timezone.utc)


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
        return (from_ns(self.min, self.type), from_ns(self.max, self.type))


def from_ns(value: int, time_type: str) -> Any:
    """A time in nanoseconds as the Python time of its timeline's type (microseconds,
    rounded towards the past)."""
    if time_type == "timestamp":
        return EPOCH + _dt.timedelta(microseconds=value // 1_000)
    if time_type == "duration":
        return _dt.timedelta(microseconds=value // 1_000)
    return value


def timedelta_ns(value: _dt.timedelta) -> int:
    return (value.days * 86_400 + value.seconds) * 1_000_000_000 + value.microseconds * 1_000


I64_MIN, I64_MAX = -(2**63), 2**63 - 1


def in_range(value: int, what: str) -> int:
    """``value``, if an ``i64`` holds it."""
    if not I64_MIN <= value <= I64_MAX:
        raise InvalidInputError(f"{what}: {value} is outside the 64-bit range of times")
    return value


def to_time(value: Time, time_type: str, what: str) -> int:
    """``value`` as an integer on a timeline of ``time_type``."""
    if isinstance(value, bool):
        raise InvalidInputError(f"{what}: a bool is not a time")
    if isinstance(value, int):
        return in_range(value, what)
    if type(value).__module__.startswith("pyarrow") and hasattr(value, "as_py"):
        # A pyarrow scalar (an item of a pyarrow array, too): its Python value, whose
        # type says the unit. A null is no time.
        if not getattr(value, "is_valid", True):
            raise InvalidInputError(f"{what}: a null is not a time")
        unit_ns = pyarrow_ns(value)
        if unit_ns is not None:
            return in_range(unit_ns, what)
        return to_time(value.as_py(), time_type, what)
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
        return timedelta_ns(value - EPOCH)
    if isinstance(value, _dt.timedelta):
        if time_type == "sequence":
            raise InvalidInputError(f"{what}: a timedelta on a sequence timeline")
        return timedelta_ns(value)
    raise InvalidInputError(
        f"{what}: expected an int, datetime or timedelta, got {type(value).__name__}"
    )


def pyarrow_ns(value: Any) -> Optional[int]:
    """A pyarrow timestamp or duration scalar in nanoseconds, exactly (``as_py`` would
    round to microseconds); ``None`` for other scalars."""
    import pyarrow as pa

    kind = value.type
    if pa.types.is_timestamp(kind) or pa.types.is_duration(kind):
        per_unit = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}[kind.unit]
        return value.cast(pa.int64()).as_py() * per_unit
    return None
