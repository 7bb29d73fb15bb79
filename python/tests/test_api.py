"""Every method of chunkstore.Store, on the robot recording and on stores built here."""

import datetime as dt
import threading

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import chunkstore
from conftest import CHUNKS, RRD, chunk_batches

ROBOT = "/world/robot"
TRANSLATION = "Transform3D:translation"
COST = "/metrics/planner/cost"
SCALARS = "Scalars:scalars"


# --- discovery ---------------------------------------------------------------------


def test_discovery(robot):
    assert robot.entities() == [
        "/__properties",
        "/logs/nav2",
        "/metrics/planner/cost",
        "/world",
        "/world/map/occupancy",
        "/world/robot",
        "/world/robot/camera/depth",
        "/world/robot/camera/rgb",
    ]
    timelines = robot.timelines()
    assert [t.name for t in timelines] == ["frame_id", "log_time", "sim_time"]
    assert [t.type for t in timelines] == ["sequence", "timestamp", "duration"]
    assert (timelines[0].min, timelines[0].max) == (0, 59)
    assert (timelines[2].min, timelines[2].max) == (0, 5_900_000_000)
    assert robot.components(ROBOT) == ["Transform3D:rotation_axis_angle", TRANSLATION]
    assert robot.components("/nothing/here") == []
    assert len(robot) == 261
    text = repr(robot)
    assert "8 entities" in text and "261 rows" in text and "frame_id (sequence) [0, 59]" in text


def test_schema_matches_the_dataframe(robot):
    schema = robot.schema("frame_id")
    assert isinstance(schema, pa.Schema)
    assert robot.schema() == schema  # frame_id is the first timeline by name
    assert chunkstore.Store().schema() == pa.schema([])
    assert schema == robot.dataframe("frame_id").schema
    assert schema.names[:3] == ["frame_id", "log_time", "sim_time"]
    assert f"{ROBOT}:{TRANSLATION}" in schema.names
    only = robot.schema("frame_id", contents=COST)
    assert only.names == ["frame_id", "log_time", "sim_time", f"{COST}:{SCALARS}"]


def test_a_lazy_store_decodes_only_what_a_query_needs():
    store = chunkstore.open(RRD)
    store.latest_at("frame_id", 30, ROBOT, TRANSLATION)
    assert store.is_lazy  # still lazy: nothing needed every chunk
    read = store.read_stats()
    assert 0 < read["chunks_decoded"] < read["chunks_in_file"], read
    assert (read["requests"], read["bytes_fetched"]) == (0, 0), "a local file"
    store.dataframe("frame_id").read_all()
    assert not store.is_lazy
    assert store.read_stats()["chunks_decoded"] == read["chunks_in_file"]
    assert chunkstore.open(RRD, lazy=False).read_stats() is None
    assert len(store) == 261
    assert store.heap_bytes > 200_000  # the images alone are about that


# --- latest-at and range -----------------------------------------------------------


def test_latest_at_one_row_of_every_component(robot):
    batch = robot.latest_at("frame_id", 30, ROBOT)
    assert isinstance(batch, pa.RecordBatch)
    assert batch.num_rows == 1
    assert batch.schema.names == ["frame_id", "row_id", "Transform3D:rotation_axis_angle", TRANSLATION]
    assert batch.column("frame_id").to_pylist() == [30]
    assert batch.schema.field("row_id").type == pa.binary(16)
    translation = batch.column(TRANSLATION).to_pylist()[0][0]
    assert translation == pytest.approx([0.1414744, 1.99499, 0.0], abs=1e-5)
    meta = batch.schema.field(TRANSLATION).metadata
    assert meta[b"rerun:entity_path"] == ROBOT.encode()
    # Before the first row: no answer, no row.
    assert robot.latest_at("frame_id", -1, ROBOT).num_rows == 0
    # One component, by name or list.
    assert robot.latest_at("frame_id", 30, ROBOT, TRANSLATION).schema.names == ["frame_id", "row_id", TRANSLATION]


def test_latest_at_static_data_has_a_null_time(robot):
    batch = robot.latest_at("frame_id", 0, "/world")
    assert batch.num_rows == 1
    assert batch.column("frame_id").to_pylist() == [None]
    assert batch.column("ViewCoordinates:xyz").to_pylist() == [[[3, 5, 1]]]


def test_range_rows_in_time_order(robot):
    table = robot.range("frame_id", 10, 19, entity=COST, component=SCALARS)
    assert isinstance(table, pa.Table)
    assert table.column_names == ["frame_id", "row_id", SCALARS]
    assert table.column("frame_id").to_pylist() == list(range(10, 20))
    everything = robot.range("frame_id", -(2**62), 2**62, entity=COST, component=SCALARS)
    assert everything.num_rows == 60
    values = [v[0] for v in everything.column(SCALARS).to_pylist()]
    # The same series the dataframe gives.
    frame = pl.from_arrow(robot.dataframe("frame_id", contents=COST))
    assert values == [v[0] for v in frame[f"{COST}:{SCALARS}"].to_list()]
    assert robot.range("frame_id", 100, 200, entity=COST, component=SCALARS).num_rows == 0


def test_times_as_python_and_numpy_values(robot):
    # sim_time is a duration timeline, log_time a timestamp one.
    as_int = robot.latest_at("sim_time", 1_500_000_000, ROBOT, TRANSLATION)
    assert robot.latest_at("sim_time", dt.timedelta(seconds=1.5), ROBOT, TRANSLATION) == as_int
    assert robot.latest_at("sim_time", np.timedelta64(1500, "ms"), ROBOT, TRANSLATION) == as_int
    first, last = robot.timelines()[1].min, robot.timelines()[1].max
    as_datetime = dt.datetime.fromtimestamp(last / 1e9, tz=dt.timezone.utc) + dt.timedelta(seconds=1)
    at_end = robot.latest_at("log_time", as_datetime, ROBOT, TRANSLATION)
    assert at_end == robot.latest_at("log_time", last, ROBOT, TRANSLATION)
    assert robot.latest_at("log_time", np.datetime64(last, "ns"), ROBOT, TRANSLATION) == at_end
    naive = dt.datetime(2000, 1, 1)
    assert robot.latest_at("log_time", naive, ROBOT, TRANSLATION).num_rows == 0
    table = robot.range("log_time", np.datetime64(first, "ns"), np.datetime64(last, "ns"), entity=COST, component=SCALARS)
    assert table.num_rows == 60
    assert table.schema.field("log_time").type == pa.timestamp("ns")
    assert robot.range("sim_time", dt.timedelta(0), dt.timedelta(seconds=1), entity=COST, component=SCALARS).num_rows == 11
    sampled = robot.dataframe("sim_time", index_values=np.array([0, 10**9], dtype="timedelta64[ns]"), contents=COST)
    assert sampled.read_all().num_rows == 2
    assert robot.dataframe("frame_id", index_values=np.arange(5), contents=COST).read_all().num_rows == 5


# --- dataframes --------------------------------------------------------------------


def test_dataframe_is_a_streamed_record_batch_reader(robot):
    reader = robot.dataframe("frame_id", contents=["/world/**", "-/world/robot/camera/**"], batch_rows=7)
    assert isinstance(reader, pa.RecordBatchReader)
    sizes = [batch.num_rows for batch in reader]
    assert max(sizes) <= 7 and sum(sizes) == 60
    table = robot.dataframe("frame_id", range=(10, 19), fill_latest_at=True).read_all()
    assert table.column("frame_id").to_pylist() == list(range(10, 20))
    occupancy = [c for c in table.column_names if c.startswith("/world/map/occupancy")][0]
    assert table.column(occupancy).null_count == 0  # filled from frame 10


def test_round_trip_through_polars_and_pandas(robot):
    table = robot.dataframe("frame_id").read_all()
    frame = pl.from_arrow(table)
    assert frame.height == 60
    back = frame.to_arrow()
    for name in table.column_names:
        assert back.column(name).to_pylist() == table.column(name).to_pylist(), name
    pandas = robot.dataframe("frame_id", contents=COST).read_pandas()
    assert list(pandas["frame_id"]) == list(range(60))


# --- writes ------------------------------------------------------------------------


def test_insert_record_batches_and_tables():
    batches = chunk_batches()
    store = chunkstore.Store()
    assert len(store) == 0 and store.entities() == []
    rows = sum(store.insert(b) for b in batches)
    assert rows == 261 == len(store)
    # The same rows again change nothing.
    store.insert(batches[5])
    assert len(store) == 261
    expected = chunkstore.open(CHUNKS).dataframe("frame_id").read_all()
    assert store.dataframe("frame_id").read_all().equals(expected)
    # A table: one chunk per batch.
    other = chunkstore.Store(compaction=False)
    assert other.insert(pa.Table.from_batches([batches[3]])) == batches[3].num_rows
    assert other.num_chunks == 1


def test_gc_and_compact_keep_answers():
    store = chunkstore.Store(compaction=False)
    store.insert(chunk_batches())
    before = store.dataframe("frame_id", contents=COST).read_all()
    chunks_before, chunks_after = store.compact()
    assert chunks_after < chunks_before
    assert store.dataframe("frame_id", contents=COST).read_all().equals(before)
    latest = {e: store.latest_at("frame_id", 1000, e) for e in store.entities()}
    dropped_chunks, dropped_rows = store.gc(fraction=0.5, protect_latest=1)
    assert (dropped_chunks, dropped_rows) >= (0, 0)
    assert {e: store.latest_at("frame_id", 1000, e) for e in store.entities()} == latest
    store.gc(bytes=1)
    # Everything temporal goes; static data never does.
    dropped_chunks, dropped_rows = store.gc()
    assert dropped_chunks > 0 and dropped_rows > 0
    assert store.entities() == ["/__properties", "/world"]
    assert store.latest_at("frame_id", 0, "/world").num_rows == 1
    assert len(store) == 2  # the two static rows: /world's view coordinates, the properties


def test_write_rrd_and_parquet(tmp_path, robot):
    out = tmp_path / "copy.rrd"
    size = robot.write_rrd(out)
    assert size == out.stat().st_size > 0
    copy = chunkstore.open(out)
    assert copy.dataframe("frame_id").read_all().equals(robot.dataframe("frame_id").read_all())

    parquet = tmp_path / "cost.parquet"
    assert robot.write_parquet(parquet, "frame_id", contents=COST) == 60
    table = pq.read_table(parquet)
    assert table.column(f"{COST}:{SCALARS}").to_pylist() == robot.dataframe(
        "frame_id", contents=COST
    ).read_all().column(f"{COST}:{SCALARS}").to_pylist()
    assert pl.read_parquet(parquet).height == 60


# --- threads -----------------------------------------------------------------------


def test_readers_query_while_a_writer_inserts():
    batches = chunk_batches()
    store = chunkstore.Store()
    done = threading.Event()
    errors = []
    seen = []

    def writer():
        try:
            for batch in batches:
                store.insert(batch)
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)
        finally:
            done.set()

    def reader():
        try:
            while not done.is_set():
                rows = store.dataframe("frame_id", contents="/**").read_all().num_rows if store.timelines() else 0
                seen.append(rows)
                store.latest_at("frame_id", 59, COST) if COST in store.entities() else None
        except Exception as e:  # noqa: BLE001
            errors.append(e)

    threads = [threading.Thread(target=writer)] + [threading.Thread(target=reader) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert len(store) == 261
    assert store.dataframe("frame_id").read_all().num_rows == 60


def test_a_missing_answer_has_the_same_type_lazy_or_loaded():
    lazy = chunkstore.open(RRD)
    loaded = chunkstore.open(RRD, lazy=False)
    for entity in loaded.entities():
        before_first = lazy.latest_at("frame_id", -1, entity)
        assert before_first.schema == loaded.latest_at("frame_id", -1, entity).schema, entity
        for field in before_first.schema:
            assert field.type != pa.list_(pa.null()), (entity, field.name)
    assert lazy.range("frame_id", 1000, 2000, entity=COST, component=SCALARS).schema == loaded.range(
        "frame_id", 1000, 2000, entity=COST, component=SCALARS
    ).schema


def test_write_parquet_takes_the_dataframe_arguments(tmp_path, robot):
    path = tmp_path / "sampled.parquet"
    assert robot.write_parquet(path, "sim_time", contents=COST, index_values=np.array([0, 10**9], dtype="timedelta64[ns]")) == 2
    ranged = tmp_path / "ranged.parquet"
    assert robot.write_parquet(ranged, "frame_id", range=(10, 19), fill_latest_at=True, row_group_rows=4) == 10
    assert pq.ParquetFile(ranged).metadata.num_row_groups == 3
    assert pq.read_table(ranged).equals(
        robot.dataframe("frame_id", range=(10, 19), fill_latest_at=True).read_all()
    )
    with pytest.raises(chunkstore.InvalidInputError, match="range"):
        robot.write_parquet(tmp_path / "bad.parquet", "frame_id", range=3)
    assert not (tmp_path / "bad.parquet").exists()
    # Every keyword of dataframe, the same table.
    lean = tmp_path / "lean.parquet"
    robot.write_parquet(lean, "frame_id", include_tombstone_columns=False, include_semantically_empty_columns=False)
    assert pq.read_table(lean).equals(
        robot.dataframe("frame_id", include_tombstone_columns=False, include_semantically_empty_columns=False).read_all()
    )


def test_to_parquet_is_write_parquet_under_its_old_name_with_a_warning(tmp_path, robot):
    old, new = tmp_path / "old.parquet", tmp_path / "new.parquet"
    with pytest.warns(DeprecationWarning, match="write_parquet"):
        rows = robot.to_parquet(old, "frame_id", contents=COST, row_group_rows=7)
    assert rows == robot.write_parquet(new, "frame_id", contents=COST, row_group_rows=7) == 60
    assert pq.read_table(old).equals(pq.read_table(new))


def test_tombstone_and_empty_columns_can_be_left_out(robot):
    """Issue 32, item 11: Rerun's reader defaults, offered as switches (the robot has no
    Clear and no empty column: the switches change nothing there)."""
    full = robot.dataframe("frame_id").read_all()
    rerun_like = robot.dataframe(
        "frame_id", include_tombstone_columns=False, include_semantically_empty_columns=False
    ).read_all()
    assert rerun_like.equals(full)


def test_a_timeline_span_in_python_times(robot):
    """Issue 32, item 17: timestamps as ``datetime`` where the timeline is a timestamp."""
    import datetime

    spans = {t.name: t.span() for t in robot.timelines()}
    start, end = spans["log_time"]
    assert start == datetime.datetime(2026, 11, 21, 12, 55, 48, 902914, tzinfo=datetime.timezone.utc)
    assert end > start
    assert spans["sim_time"] == (datetime.timedelta(0), datetime.timedelta(seconds=5.9))
    assert spans["frame_id"] == (0, 59)
    # Back in, a datetime is the same time to the microsecond (rounded towards the past,
    # so the last one is after the data before the last row).
    assert robot.latest_at("log_time", end, "/world/robot").num_rows == 1


def test_exact_index_values_show_only_what_was_logged_there(robot):
    """Issue 32, item 11: Rerun's sampling without fill, as a switch."""
    latest = robot.dataframe("frame_id", index_values=[5]).read_all()
    exact = robot.dataframe("frame_id", index_values=[5], exact_index_values=True).read_all()
    grid = [n for n in latest.column_names if n.startswith("/world/map/occupancy")]
    assert grid, latest.column_names
    # The grid is logged every 10th frame: frame 5 has the latest-at answer, not a hit.
    assert latest.column(grid[0]).null_count == 0
    assert exact.column(grid[0]).null_count == 1
    sparse = robot.dataframe("frame_id", range=(5, 5)).read_all()
    assert exact.column("/world/robot:Transform3D:translation").equals(
        sparse.column("/world/robot:Transform3D:translation")
    )


def test_sql_answers_from_a_snapshot_of_the_store(robot):
    table = robot.sql("SELECT * FROM frame_id").read_all()
    expected = robot.dataframe("frame_id").read_all()
    assert table.num_rows == expected.num_rows
    assert set(table.schema.names) == set(expected.schema.names)
    counted = robot.sql(
        "SELECT count(*) AS n FROM frame_id WHERE frame_id BETWEEN 10 AND 19"
    ).read_all()
    assert counted.column("n").to_pylist() == [
        robot.dataframe("frame_id", range=(10, 19)).read_all().num_rows
    ]
    latest = robot.sql("SELECT * FROM latest_at('frame_id', 30)").read_all()
    assert latest.num_rows > 0
    with pytest.raises(chunkstore.InvalidInputError, match="no_such_table"):
        robot.sql("SELECT * FROM no_such_table")
