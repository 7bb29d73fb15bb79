"""Datasets from Python (SEMANTICS.md section 15): a directory of .rrd files as one table,
each segment's own dataframe under its recording id, in segment order."""

import pyarrow as pa
import pytest

import chunkstore

from conftest import CHUNKS, RRD


@pytest.fixture
def episodes(tmp_path):
    """A dataset of two segments: the robot recording, and its chunks under another id."""
    (tmp_path / "one.rrd").write_bytes(RRD.read_bytes())
    chunkstore.open(CHUNKS).write_rrd(tmp_path / "two.rrd", recording_id="second")
    (tmp_path / "notes.txt").write_text("not a segment")
    return tmp_path


def test_a_dataset_is_each_segments_table_in_turn(episodes):
    dataset = chunkstore.open_dataset(episodes)
    segments = dataset.segments()
    assert [s.id for s in segments] == ["a0000000-0000-4000-8000-00000000000a", "second"]
    assert len(dataset) == 2
    assert {t.name for t in dataset.timelines()} == {"frame_id", "log_time", "sim_time"}
    assert dataset.read_stats()["segment_reads"] == 0, "opening reads no chunk"
    for fill in (False, True):
        table = dataset.dataframe("frame_id", fill_latest_at=fill).read_all()
        assert table.schema.names[0] == "rerun_segment_id"
        own = [
            chunkstore.open(episodes / name).dataframe("frame_id", fill_latest_at=fill).read_all()
            for name in ("one.rrd", "two.rrd")
        ]
        assert table.num_rows == sum(t.num_rows for t in own)
        start = 0
        for segment, part in zip(segments, own):
            piece = table.slice(start, part.num_rows)
            assert set(piece.column("rerun_segment_id").to_pylist()) == {segment.id}
            for name in part.schema.names:
                assert piece.column(name).combine_chunks().equals(part.column(name).combine_chunks()), name
            start += part.num_rows
    read = dataset.read_stats()
    assert read["segment_reads"] >= 2 and read["chunks_decoded"] > 0, read
    assert (read["requests"], read["bytes_fetched"]) == (0, 0), "local files"


def test_a_dataset_takes_times_and_contents_as_a_store_does(episodes):
    dataset = chunkstore.open_dataset(episodes)
    table = dataset.dataframe("frame_id", contents="/world/**", range=(10, 19)).read_all()
    assert table.num_rows == 20
    assert all(name.startswith("/world") for name in table.schema.names[4:])
    with pytest.raises(chunkstore.UnknownTimelineError, match="frame_idd"):
        dataset.dataframe("frame_idd")
    with pytest.raises(chunkstore.InvalidInputError):
        chunkstore.open_dataset(episodes, memory_budget=-1)


def test_bad_datasets_raise_naming_the_file(tmp_path, episodes):
    with pytest.raises(chunkstore.CorruptFileError, match="no .rrd file"):
        chunkstore.open_dataset(_empty(tmp_path))
    (episodes / "broken.rrd").write_bytes(b"RRF2" + bytes(50))
    with pytest.raises(chunkstore.CorruptFileError, match="broken.rrd"):
        chunkstore.open_dataset(episodes)
    dataset = chunkstore.open_dataset(episodes, skip_bad=True)
    assert len(dataset) == 2
    warnings = dataset.take_warnings()
    assert len(warnings) == 1 and "broken.rrd" in warnings[0]
    (episodes / "copy.rrd").write_bytes(RRD.read_bytes())
    # With skip_bad, a second file of one recording is a bad file like the others: skipped
    # with a warning naming both files.
    dataset = chunkstore.open_dataset(episodes, skip_bad=True)
    assert len(dataset) == 2
    warnings = dataset.take_warnings()
    assert len(warnings) == 2 and any("copy.rrd" in w for w in warnings), warnings
    (episodes / "broken.rrd").unlink()
    with pytest.raises(chunkstore.InvalidInputError, match="two files"):
        chunkstore.open_dataset(episodes)


def _empty(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    return empty


def test_sql_over_a_dataset_is_its_table_and_prunes_segments(episodes):
    dataset = chunkstore.open_dataset(episodes)
    answer = dataset.sql("SELECT * FROM frame_id ORDER BY rerun_segment_id, frame_id")
    assert isinstance(answer, pa.RecordBatchReader)
    table = answer.read_all()
    expected = dataset.dataframe("frame_id").read_all()
    assert table.schema.names == expected.schema.names
    for name in expected.schema.names:
        assert table.column(name).combine_chunks().equals(expected.column(name).combine_chunks()), name
    counts = dataset.sql(
        "SELECT rerun_segment_id, count(*) AS n FROM frame_id GROUP BY 1 ORDER BY 1"
    ).read_all()
    own = chunkstore.open(episodes / "two.rrd").dataframe("frame_id").read_all().num_rows
    assert counts.column("rerun_segment_id").to_pylist() == [s.id for s in dataset.segments()]
    assert counts.column("n").to_pylist() == [own, own]
    plan = dataset.sql(
        "EXPLAIN SELECT count(*) FROM frame_id WHERE rerun_segment_id = 'second'"
    ).read_all()
    text = "\n".join(plan.column("plan").to_pylist())
    assert "segments=1 of 2 (pruned: 1 by rerun_segment_id)" in text, text
    chunks = dataset.sql("SELECT DISTINCT rerun_segment_id FROM chunks ORDER BY 1").read_all()
    assert chunks.column(0).to_pylist() == [s.id for s in dataset.segments()]


def test_sql_that_cannot_be_planned_raises(episodes):
    dataset = chunkstore.open_dataset(episodes)
    with pytest.raises(chunkstore.InvalidInputError, match="nope"):
        dataset.sql("SELECT * FROM nope")
    with pytest.raises(chunkstore.InvalidInputError, match="--segment"):
        dataset.sql("SELECT * FROM latest_at('frame_id', 3)")
    with pytest.raises(chunkstore.InvalidInputError, match="query"):
        dataset.sql(42)


def test_an_index_cache_is_written_only_for_files_without_a_footer(tmp_path, episodes):
    cache = tmp_path / "index-cache"
    dataset = chunkstore.open_dataset(episodes, index_cache=cache)
    assert len(dataset) == 2
    # Every segment here has a footer: nothing to index, and no directory made.
    assert not cache.exists()
    assert dataset.dataframe("frame_id").read_all().num_rows == (
        chunkstore.open_dataset(episodes).dataframe("frame_id").read_all().num_rows
    )


def test_write_delta_makes_a_table_and_appends_to_it(tmp_path, episodes):
    import json

    import pyarrow.parquet as pq

    dataset = chunkstore.open_dataset(episodes)
    first = tmp_path / "dataset-one"
    first.mkdir()
    (first / "one.rrd").write_bytes((episodes / "one.rrd").read_bytes())
    table = tmp_path / "table"
    made = chunkstore.open_dataset(first).write_delta(table, index="frame_id", bucket=10)
    assert made["version"] == 0 and made["segments"] == ["a0000000-0000-4000-8000-00000000000a"], made
    # The same segment again, and a new table where one is, are refused.
    with pytest.raises(chunkstore.InvalidInputError, match="in the table already"):
        dataset.write_delta(table, index="frame_id", bucket=10, append=True)
    with pytest.raises(FileExistsError):
        dataset.write_delta(table, index="frame_id", bucket=10)
    with pytest.raises(chunkstore.InvalidInputError, match="bucket needs an index"):
        dataset.write_delta(tmp_path / "other", bucket=10)
    # The other segment, appended: one commit.
    second = tmp_path / "dataset-two"
    second.mkdir()
    (second / "two.rrd").write_bytes((episodes / "two.rrd").read_bytes())
    appended = chunkstore.open_dataset(second).write_delta(table, index="frame_id", bucket=10, append=True)
    assert appended["version"] == 1 and appended["segments"] == ["second"], appended
    # Every file a commit adds holds the rows it says; together, the dataset's table.
    adds = [
        json.loads(line)["add"]
        for entry in sorted((table / "_delta_log").iterdir())
        for line in entry.read_text().splitlines()
        if '"add"' in line
    ]
    assert len(adds) == made["files"] + appended["files"]
    rows = 0
    for add in adds:
        path = table / add["path"].replace("%25", "%")
        stats = json.loads(add["stats"])
        assert pq.read_metadata(path).num_rows == stats["numRecords"]
        rows += stats["numRecords"]
    assert rows == made["rows"] + appended["rows"] == dataset.dataframe("frame_id").read_all().num_rows
