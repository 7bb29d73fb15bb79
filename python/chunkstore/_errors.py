"""The package's exceptions. Defined in Python (the native module raises them) so that
each also subclasses the built-in exception a caller expects, as pyarrow's do: bad input
and corrupt files are ``ValueError``, an unknown timeline is a ``KeyError`` (a
``LookupError``), and every one is a :class:`Error`."""


class Error(Exception):
    """Every error chunkstore raises (besides OSError from the file system)."""


class InvalidInputError(Error, ValueError):
    """Input the store refuses: a record batch that is not a chunk, a bad entity path or
    filter, an argument out of range."""


class CorruptFileError(Error, ValueError):
    """A file that is not what it claims: not an .rrd or Arrow IPC, truncated, or corrupt."""


class UnknownTimelineError(Error, KeyError):
    """A timeline the store has never seen."""

    def __str__(self) -> str:
        # KeyError quotes its message; this one is a sentence.
        return Exception.__str__(self)
