"""Shared fixtures: the robot recording Rerun 0.41's SDK wrote, and its oracle tables."""

import pathlib

import pyarrow as pa
import pyarrow.ipc
import pytest

RECORDING = pathlib.Path(__file__).resolve().parents[2] / "testdata" / "rerun-0.41" / "a_robot"
RRD = RECORDING / "a_robot.rrd"
CHUNKS = RECORDING / "chunks"
ORACLE = RECORDING / "oracle"
TIMELINES = ["frame_id", "log_time", "sim_time"]


def read_arrow(path: pathlib.Path) -> list:
    """The record batches of an Arrow IPC file."""
    with pa.ipc.open_file(str(path)) as reader:
        return [reader.get_batch(i) for i in range(reader.num_record_batches)]


def chunk_batches() -> list:
    """Every chunk file of the recording, one record batch each, in file order."""
    batches = []
    for path in sorted(CHUNKS.glob("*.arrow")):
        batches.extend(read_arrow(path))
    return batches


@pytest.fixture(params=["lazy", "eager", "chunks"])
def robot(request):
    """The recording, opened each way the package opens it."""
    import chunkstore

    if request.param == "lazy":
        store = chunkstore.open(RRD)
        assert store.is_lazy
    elif request.param == "eager":
        store = chunkstore.open(RRD, lazy=False)
        assert not store.is_lazy
    else:
        store = chunkstore.open(CHUNKS)
    return store
