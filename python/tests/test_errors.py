"""Bad input: a Python exception of the package's own types, with a message that names
the problem; never a panic."""

import pyarrow as pa
import pytest

import chunkstore
from conftest import RRD, chunk_batches

COST = "/metrics/planner/cost"


def test_exception_hierarchy():
    for error in (chunkstore.InvalidInputError, chunkstore.CorruptFileError, chunkstore.UnknownTimelineError):
        assert issubclass(error, chunkstore.Error)
    assert issubclass(chunkstore.Error, Exception)
    # Issue 32, item 17: the built-in exceptions callers catch, as pyarrow's errors do.
    assert issubclass(chunkstore.InvalidInputError, ValueError)
    assert issubclass(chunkstore.CorruptFileError, ValueError)
    assert issubclass(chunkstore.UnknownTimelineError, KeyError)
    assert issubclass(chunkstore.UnknownTimelineError, LookupError)


def test_errors_raised_by_the_native_module_are_the_package_s(robot):
    with pytest.raises(KeyError) as raised:
        robot.latest_at("FRAME_ID", 3, "/world/robot")
    assert isinstance(raised.value, chunkstore.UnknownTimelineError)
    # A sentence, not KeyError's quoted repr.
    assert str(raised.value).startswith("unknown timeline"), str(raised.value)
    with pytest.raises(ValueError):
        robot.latest_at("frame_id", 3, "no/such//path")


def test_version():
    assert isinstance(chunkstore.__version__, str) and chunkstore.__version__.count(".") == 2


def test_pyarrow_and_out_of_range_values(robot):
    ints = robot.range("frame_id", 3, 5, entity="/world/robot", component="Transform3D:translation")
    scalars = robot.range(
        "frame_id", pa.scalar(3), pa.scalar(5, pa.int32()), entity="/world/robot", component="Transform3D:translation"
    )
    assert scalars.equals(ints)
    values = robot.dataframe("frame_id", index_values=pa.array([1, 2, 3])).read_all()
    assert values.equals(robot.dataframe("frame_id", index_values=[1, 2, 3]).read_all())
    # A pyarrow timestamp keeps its nanoseconds (as_py would round to microseconds).
    log = [t for t in robot.timelines() if t.name == "log_time"][0]
    at_ns = robot.latest_at("log_time", log.max, "/world/robot")
    at_scalar = robot.latest_at("log_time", pa.scalar(log.max, pa.timestamp("ns")), "/world/robot")
    assert at_scalar.equals(at_ns)
    with pytest.raises(chunkstore.InvalidInputError, match="null"):
        robot.latest_at("frame_id", pa.scalar(None, pa.int64()), "/world/robot")
    for bad in (2**63, -(2**63) - 1, 10**30):
        with pytest.raises(chunkstore.InvalidInputError, match="64-bit"):
            robot.latest_at("frame_id", bad, "/world/robot")
    for bad in (-1, 0, 2**64):
        with pytest.raises(chunkstore.InvalidInputError, match="batch_rows"):
            robot.dataframe("frame_id", batch_rows=bad)


def test_files_that_are_not_there_or_not_recordings(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.rrd"):
        chunkstore.open(tmp_path / "missing.rrd")
    text = tmp_path / "notes.txt"
    text.write_text("hello, world")
    with pytest.raises(chunkstore.CorruptFileError, match="neither an .rrd file nor Arrow IPC"):
        chunkstore.open(text)
    with pytest.raises(chunkstore.CorruptFileError, match="no Arrow IPC files"):
        chunkstore.open(tmp_path)


@pytest.mark.parametrize("lazy", [True, False])
def test_truncated_and_corrupted_recordings(tmp_path, lazy):
    data = RRD.read_bytes()
    for name, corrupt in {
        "truncated": data[: len(data) // 2],
        "header_only": data[:16],
        "flipped": data[:1000] + bytes(b ^ 0xFF for b in data[1000:1400]) + data[1400:],
    }.items():
        path = tmp_path / f"{name}.rrd"
        path.write_bytes(corrupt)
        with pytest.raises(chunkstore.Error) as info:
            store = chunkstore.open(path, lazy=lazy)
            store.dataframe("frame_id").read_all()
        assert str(info.value), name
        assert "PanicException" not in type(info.value).__name__


def test_random_bytes_never_panic(tmp_path):
    import random

    rng = random.Random(7)
    for i in range(40):
        blob = bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 600)))
        if i % 2:
            blob = b"RRF2" + blob
        path = tmp_path / f"r{i}.rrd"
        path.write_bytes(blob)
        try:
            chunkstore.open(path).dataframe("frame_id").read_all()
        except chunkstore.Error:
            pass


def test_unknown_names(robot):
    with pytest.raises(chunkstore.UnknownTimelineError, match=r'unknown timeline "tick" \(the store has: frame_id, log_time, sim_time\)'):
        robot.latest_at("tick", 0, COST)
    with pytest.raises(chunkstore.UnknownTimelineError):
        robot.dataframe("tick")
    with pytest.raises(chunkstore.InvalidInputError, match="no data at entity /nope"):
        robot.latest_at("frame_id", 0, "/nope")
    with pytest.raises(chunkstore.InvalidInputError, match='has no component "Nope"'):
        robot.latest_at("frame_id", 0, COST, ["Nope"])
    with pytest.raises(chunkstore.InvalidInputError, match='has no component "Nope"'):
        robot.range("frame_id", 0, 1, entity=COST, component="Nope")


def test_wrong_types_and_values(robot):
    with pytest.raises(chunkstore.InvalidInputError, match="a datetime on a sequence timeline"):
        import datetime

        robot.latest_at("frame_id", datetime.datetime(2020, 1, 1), COST)
    with pytest.raises(chunkstore.InvalidInputError, match="a bool is not a time"):
        robot.latest_at("frame_id", True, COST)
    with pytest.raises(chunkstore.InvalidInputError, match="expected an int"):
        robot.latest_at("frame_id", "30", COST)
    with pytest.raises(chunkstore.InvalidInputError, match="timeline: expected a name"):
        robot.latest_at(3, 30, COST)
    with pytest.raises(chunkstore.InvalidInputError, match="start is after the end"):
        robot.range("frame_id", 5, 1, entity=COST, component="Scalars:scalars")
    with pytest.raises(chunkstore.InvalidInputError, match="out of range"):
        robot.latest_at("frame_id", -(2**63), COST)
    # Issue 32, item 17: the package's own error, not OverflowError.
    with pytest.raises(chunkstore.InvalidInputError, match="64-bit"):
        robot.latest_at("frame_id", 2**64, COST)
    with pytest.raises(chunkstore.InvalidInputError, match="entity path"):
        robot.latest_at("frame_id", 0, "/a//b")
    with pytest.raises(chunkstore.InvalidInputError, match="contents"):
        robot.dataframe("frame_id", contents="/a/**/b")
    with pytest.raises(chunkstore.InvalidInputError, match="batch_rows"):
        robot.dataframe("frame_id", batch_rows=0)
    with pytest.raises(chunkstore.InvalidInputError, match=r"range: expected a \(lo, hi\) pair"):
        robot.dataframe("frame_id", range=5)
    with pytest.raises(chunkstore.InvalidInputError, match="gc"):
        robot.gc(fraction=2.0)
    with pytest.raises(chunkstore.InvalidInputError, match="not both"):
        robot.gc(fraction=0.5, bytes=10)


def test_record_batches_that_are_not_chunks():
    store = chunkstore.Store()
    with pytest.raises(chunkstore.InvalidInputError, match="not a valid chunk"):
        store.insert(pa.record_batch({"x": [1, 2, 3]}))
    good = chunk_batches()[1]
    without_row_ids = good.drop_columns([good.schema.names[0]]) if hasattr(good, "drop_columns") else None
    if without_row_ids is not None:
        with pytest.raises(chunkstore.InvalidInputError):
            store.insert(without_row_ids)
    with pytest.raises(TypeError):
        store.insert(42)
    assert len(store) == 0  # nothing half-inserted
