"""Recordings and datasets in an S3 bucket (SeaweedFS, which CI starts and names in
``CHUNKSTORE_TEST_S3``): written there by the package, read back lazily, answering as the
local file does; bad URLs and options raise the typed errors. Without a server these tests
are skipped, except under CI, where they fail."""

import os
import uuid

import pytest

import chunkstore

from conftest import RRD

ENDPOINT = os.environ.get("CHUNKSTORE_TEST_S3")
if not ENDPOINT and os.environ.get("CI"):
    raise RuntimeError("CI runs the object storage tests: CHUNKSTORE_TEST_S3 must name an S3 server")
pytestmark = pytest.mark.skipif(not ENDPOINT, reason="CHUNKSTORE_TEST_S3 names no S3 server")

OPTIONS = {
    "aws_endpoint": ENDPOINT or "",
    "aws_allow_http": "true",
    "aws_access_key_id": "key",
    "aws_secret_access_key": "secret",
    "aws_region": "us-east-1",
}


@pytest.fixture
def prefix():
    return f"s3://chunkstore-test/python-{uuid.uuid4().hex[:12]}/"


def test_a_recording_written_to_a_bucket_reads_back_as_the_file(prefix):
    local = chunkstore.open(RRD)
    url = prefix + "robot.rrd"
    assert local.write_rrd(url, storage_options=OPTIONS) > 0
    remote = chunkstore.open(url, storage_options=OPTIONS)
    assert remote.is_lazy
    opened = remote.read_stats()
    # The end, then the start (stream header and store info): nothing decoded yet.
    assert (opened["requests"], opened["chunks_decoded"]) == (2, 0), opened
    assert remote.entities() == local.entities()
    for entity in local.entities():
        assert remote.latest_at("frame_id", 30, entity).equals(local.latest_at("frame_id", 30, entity)), entity
    read = remote.read_stats()
    # Only the chunks the queries needed: at most one GET each, never the whole object.
    assert 0 < read["chunks_decoded"] < read["chunks_in_file"], read
    assert 0 < read["requests"] - opened["requests"] <= read["chunks_decoded"], read
    assert read["bytes_fetched"] < os.path.getsize(RRD), read
    # Kept once the store is decoded whole, which reads the rest.
    remote.heap_bytes
    assert remote.read_stats()["chunks_decoded"] == read["chunks_in_file"]
    # Refused: writing over the source.
    with pytest.raises(chunkstore.InvalidInputError, match="overwrite"):
        remote.write_rrd(url, storage_options=OPTIONS)


def test_a_dataset_over_a_prefix_is_the_dataset_of_its_files(prefix, tmp_path):
    local = chunkstore.open(RRD)
    for n in range(3):
        local.write_rrd(prefix + f"episode-{n}.rrd", recording_id=f"episode-{n}", storage_options=OPTIONS)
        local.write_rrd(tmp_path / f"episode-{n}.rrd", recording_id=f"episode-{n}")
    remote = chunkstore.open_dataset(prefix, storage_options=OPTIONS)
    on_disk = chunkstore.open_dataset(tmp_path)
    assert [s.id for s in remote.segments()] == ["episode-0", "episode-1", "episode-2"]
    assert [s.path for s in remote.segments()] == [prefix + f"episode-{n}.rrd" for n in range(3)]
    assert remote.dataframe("frame_id").read_all().equals(on_disk.dataframe("frame_id").read_all())
    read, read_on_disk = remote.read_stats(), on_disk.read_stats()
    assert read["chunks_decoded"] > 0 and read_on_disk["chunks_decoded"] > 0, (read, read_on_disk)
    assert 0 < read["requests"] <= read["chunks_decoded"], read
    assert read["bytes_fetched"] > 0, read
    assert (read_on_disk["requests"], read_on_disk["bytes_fetched"]) == (0, 0), read_on_disk


def test_missing_objects_and_bad_options_raise_typed_errors(prefix):
    missing = prefix + "nothing.rrd"
    with pytest.raises(FileNotFoundError, match="no such object"):
        chunkstore.open(missing, storage_options=OPTIONS)
    with pytest.raises(OSError, match="is not a storage option"):
        chunkstore.open(missing, storage_options={**OPTIONS, "aws_endpoint_urll": "x"})
    with pytest.raises(PermissionError, match="access denied"):
        chunkstore.open(RRD).write_rrd(missing, storage_options={**OPTIONS, "aws_secret_access_key": "wrong"})
    with pytest.raises(chunkstore.InvalidInputError, match="storage_options"):
        chunkstore.open(missing, storage_options=["aws_region"])


def test_write_delta_to_a_bucket_commits_once_per_write(prefix, tmp_path):
    import json

    from pyarrow import fs

    local = chunkstore.open(RRD)
    local.write_rrd(tmp_path / "one.rrd")
    table = prefix + "table/"
    made = chunkstore.open_dataset(tmp_path).write_delta(table, storage_options=OPTIONS)
    assert made["version"] == 0 and made["files"] > 0, made
    with pytest.raises(chunkstore.InvalidInputError, match="in the table already"):
        chunkstore.open_dataset(tmp_path).write_delta(table, append=True, storage_options=OPTIONS)
    s3 = fs.S3FileSystem(
        access_key="key", secret_key="secret", region="us-east-1",
        endpoint_override=ENDPOINT, scheme="http",
    )
    root = table[len("s3://"):]
    entries = s3.get_file_info(fs.FileSelector(root + "_delta_log"))
    assert [e.base_name for e in entries] == ["00000000000000000000.json"]
    with s3.open_input_stream(entries[0].path) as log:
        adds = [json.loads(line)["add"] for line in log.read().decode().splitlines() if '"add"' in line]
    assert len(adds) == made["files"]
    assert sum(json.loads(a["stats"])["numRecords"] for a in adds) == made["rows"]
