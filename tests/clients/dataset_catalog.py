"""A dataset's table checked cell by cell against Rerun 0.41's own catalog server (issue 36).

Writes a few dozen recordings with Rerun's SDK into a directory (varied entities, two
timelines, static data, Clears, out-of-order times, a segment without the index, a
static-only one, one whose footer is missing), then asks both sides for the same tables:

- Rerun: ``rr.server.Server(datasets={"ds": DIR})``, then
  ``client.get_dataset("ds").filter_contents(["/**"]).reader(index=...,
  fill_latest_at=..., include_semantically_empty_columns=True,
  include_tombstone_columns=True)``;
- chunkstore: ``chunkstore DIR dataframe INDEX [--fill-latest-at] --out T.arrow``.

They must hold the same columns (by name: Rerun's order of the index columns depends on
its scheduling, ours is by name) and, rows sorted by (segment, index) on Rerun's side,
the same cells, except where docs/SEMANTICS.md says ours differ on purpose, all with
``fill_latest_at``: Rerun fills values back through Clears (ours are null after a
Clear, section 9), and gives other index columns in filled rows a maximum over the
filled cells too (section 9). Then a corrupt file: Rerun skips it silently,
chunkstore names it (exit 2), and with ``--skip-bad`` warns and answers the rest.

The same files uploaded as they are to the S3 test server's bucket (``CHUNKSTORE_TEST_S3``)
and read by ``chunkstore s3://.../dataset/ dataframe`` give the same tables.

Then past one machine: ``chunkstore DIR hive OUT`` (by segment and time bucket, and by
segment and entity) read back by DuckDB (``read_parquet(..., hive_partitioning = true)``)
and by DataFusion's listing table (the ``datafusion`` package) equals the dataset's own
table, and an aggregation over it equals the same SQL run by ``chunkstore DIR sql``. And
the dataset as a Delta table in the S3 test server's bucket (``CHUNKSTORE_TEST_S3``):
``hive s3://... --delta``, then two ``--append`` run at once; deltalake, Polars and
DuckDB's ``delta_scan`` read it as the dataset's table.

Usage: python tests/clients/dataset_catalog.py path/to/chunkstore   (Rerun is run with a
temporary HOME.)

With ``--python`` instead of a binary, the same tables come from the Python package
(``chunkstore.open_dataset(DIR).dataframe(INDEX, fill_latest_at=...)``, in a venv where
it is installed beside Rerun's SDK), checked against Rerun's the same way, and the corrupt
file is a ``CorruptFileError`` naming it, or with ``skip_bad`` one warning.
"""

import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import pyarrow as pa
import pyarrow.ipc as ipc
import rerun as rr
from s3_env import s3_client, s3_endpoint, s3_options, tool_env

SEGMENTS = 30

# Per segment, over a range of frames: chunkstore's SQL over the dataset and another
# engine over a copy of it must agree.
SEGMENT_AGGREGATE = (
    "SELECT rerun_segment_id, count(*) AS n, min(frame) AS first, max(frame) AS last, "
    "count(\"/robot/camera/points:Points3D:positions\") AS points "
    "FROM {table} WHERE frame BETWEEN 3 AND 14 GROUP BY rerun_segment_id "
    "ORDER BY rerun_segment_id"
)


def write_recordings(directory):
    """Writes the dataset's recordings with Rerun's SDK; returns their recording ids."""
    ids = []
    rng = np.random.default_rng(7)
    for n in range(SEGMENTS):
        recording_id = f"episode-{n:03}"
        ids.append(recording_id)
        rec = rr.RecordingStream("rerun_example_dataset", recording_id=recording_id)
        rec.save(os.path.join(directory, f"{recording_id}.rrd"))
        if n % 7 != 3:
            # Static data: the robot's name, and for some its map.
            rec.log("robot", rr.TextDocument(f"robot {n % 4}"), static=True)
        if n == 5:
            # Static only: no row on any index.
            rec.flush()
            rec.disconnect()
            continue
        frames = list(range(20 + n % 5))
        if n % 3 == 1:
            rng.shuffle(frames)  # out of order
        for frame in frames:
            if n != 9:  # episode 9 has no `frame` timeline, only `sim_time`
                rec.set_time("frame", sequence=frame)
            rec.set_time("sim_time", duration=frame * 0.05)
            rec.log("robot/arm/joint", rr.Scalars([float(frame * 10 + n)]))
            if frame % 2 == 0:
                rec.log(
                    "robot/camera/points",
                    rr.Points3D(rng.normal(size=(3, 3)).astype(np.float32)),
                )
            if n % 4 == 0 and frame % 5 == 0:
                rec.log(f"robot/leg_{n % 3}", rr.Scalars([float(frame)]))
            if n % 6 == 2 and frame == 10:
                rec.log("robot/arm", rr.Clear(recursive=True))
            if n % 5 == 4 and frame == 12:
                rec.log("robot/camera/points", rr.Clear(recursive=False))
        rec.flush()
        rec.disconnect()
    return ids


def rerun_table(directory, index, fill):
    with rr.server.Server(datasets={"ds": directory}) as server:
        dataset = server.client().get_dataset("ds")
        reader = dataset.filter_contents(["/**"]).reader(
            index=index,
            fill_latest_at=fill,
            include_semantically_empty_columns=True,
            include_tombstone_columns=True,
        )
        return reader.to_arrow_table()


def chunkstore_table(binary, directory, index, fill, scratch, env=None):
    out = os.path.join(scratch, f"table-{index}-{fill}.arrow")
    if os.path.exists(out):
        os.remove(out)
    args = [binary, directory, "dataframe", index, "--out", out]
    if fill:
        args.append("--fill-latest-at")
    subprocess.run(args, check=True, env=env)
    with ipc.open_file(out) as reader:
        return reader.read_all()


def python_table(directory, index, fill):
    import chunkstore

    return chunkstore.open_dataset(directory).dataframe(index, fill_latest_at=fill).read_all()


def check_tables(directory, ours_of, label=""):
    """Our tables (`ours_of(index, fill)`) against Rerun's, on both indices, with and
    without fill; returns the cells checked."""
    checked = 0
    for index in ("frame", "sim_time"):
        for fill in (False, True):
            theirs = rerun_table(directory, index, fill)
            ours = ours_of(index, fill)
            differences = compare(ours, theirs, index, fill)
            checked += ours.num_rows * ours.num_columns
            print(
                f"{label}{index} fill={fill}: {ours.num_rows} rows x {ours.num_columns} columns"
                f" equal ({differences} cells differ as section 9 says)"
            )
    return checked


def check_python(directory, ids):
    """The Python package's tables against Rerun's, then the corrupt file."""
    import chunkstore

    checked = check_tables(directory, lambda index, fill: python_table(directory, index, fill), "python ")
    with open(os.path.join(directory, "corrupt.rrd"), "wb") as f:
        f.write(b"RRF2" + bytes(100))
    try:
        chunkstore.open_dataset(directory)
    except chunkstore.CorruptFileError as error:
        assert "corrupt.rrd" in str(error), error
    else:
        raise AssertionError("a corrupt file was not named")
    dataset = chunkstore.open_dataset(directory, skip_bad=True)
    rest = dataset.dataframe("frame").read_all()
    warnings = dataset.take_warnings()
    assert len(warnings) == 1 and "corrupt.rrd" in warnings[0], warnings
    compare(rest, rerun_table(directory, "frame", False), "frame", False)
    print(f"the Python package's dataset tables equal Rerun 0.41's catalog: {checked} cells, {len(ids)} segments")


def sorted_by_segment_and_index(table, index):
    order = pa.compute.sort_indices(
        table, sort_keys=[("rerun_segment_id", "ascending"), (index, "ascending")]
    )
    return table.take(order)


def after_clear(table, column, row):
    """Is this cell of ours null because a Clear hides it (SEMANTICS.md section 5)?

    Rerun fills values back through Clears; ours is null. Recognised by the entity's own
    or an ancestor's Clear column: the dataset logs Clears at `/robot/arm` (recursive)
    and `/robot/camera/points`.
    """
    entity = column.split(":", 1)[0]
    for clear in ("/robot/arm:Clear:is_recursive", "/robot/camera/points:Clear:is_recursive"):
        owner = clear.split(":", 1)[0]
        if (entity == owner or entity.startswith(owner + "/")) and clear in table.column_names:
            cells = table.column(clear).to_pylist()[: row + 1]
            if any(cell is not None for cell in cells):
                return True
    return False


def compare(ours, theirs, index, fill):
    theirs = sorted_by_segment_and_index(theirs, index)
    assert sorted(ours.column_names) == sorted(theirs.column_names), (
        set(ours.column_names) ^ set(theirs.column_names)
    )
    assert ours.column_names[0] == "rerun_segment_id"
    assert ours.num_rows == theirs.num_rows, (ours.num_rows, theirs.num_rows)
    segments = ours.column("rerun_segment_id").to_pylist()
    assert segments == theirs.column("rerun_segment_id").to_pylist()
    differences = 0
    for name in ours.column_names:
        field = ours.schema.field(name)
        is_index = (field.metadata or {}).get(b"rerun:kind") == b"index"
        if fill and is_index and name != index:
            # Section 9: in filled rows Rerun gives other index columns a maximum over
            # the row's filled cells too; ours count the row's own cells only.
            differences += sum(
                x != y for x, y in zip(ours.column(name).to_pylist(), theirs.column(name).to_pylist())
            )
            continue
        a = ours.column(name).to_pylist()
        b = theirs.column(name).to_pylist()
        for row, (x, y) in enumerate(zip(a, b)):
            if x == y:
                continue
            # Section 9's difference, with fill only: Rerun fills through Clears.
            start = segments.index(segments[row])
            segment_rows = ours.slice(start, row - start + 1)
            if fill and x is None and after_clear(segment_rows, name, row - start):
                differences += 1
                continue
            raise AssertionError(
                f"{index} fill={fill} {name} row {row} ({segments[row]}): ours {x!r}, Rerun {y!r}"
            )
    return differences


def plain(table):
    """`table`'s columns as Python lists, durations and timestamps as their integers
    (DuckDB reads an Arrow duration back from Parquet as a plain integer; a Delta table
    holds both as integers), without partition columns."""
    columns = {}
    for name in table.column_names:
        if name in ("segment", "entity", "frame_bucket", "log_time_bucket"):
            continue
        column = table.column(name)
        if pa.types.is_duration(column.type) or pa.types.is_timestamp(column.type):
            # As a Delta table holds them (SEMANTICS.md section 15): their integers.
            column = column.cast(pa.int64())
        columns[name] = column.to_pylist()
    return columns


def sql_rows(binary, directory, query):
    """`chunkstore DIR sql QUERY --json`'s rows, as tuples."""
    out = subprocess.run(
        [binary, directory, "sql", query, "--json"], check=True, capture_output=True, text=True
    ).stdout
    return [tuple(json.loads(line).values()) for line in out.splitlines()]


def check_hive(binary, directory, scratch, ours):
    """The dataset's Hive copies, read back by DuckDB and DataFusion, equal its table."""
    import datafusion
    import duckdb

    by_bucket = os.path.join(scratch, "hive_by_bucket")
    subprocess.run(
        [binary, directory, "hive", by_bucket, "--index", "frame", "--bucket", "8"], check=True
    )
    expected = plain(ours)
    order = "ORDER BY rerun_segment_id, frame"
    glob = os.path.join(by_bucket, "**", "*.parquet")
    read_by_duckdb = duckdb.sql(
        f"SELECT * FROM read_parquet('{glob}', hive_partitioning = true) {order}"
    ).arrow()
    if not isinstance(read_by_duckdb, pa.Table):
        read_by_duckdb = read_by_duckdb.read_all()
    assert plain(read_by_duckdb) == expected, "DuckDB's read of the Hive copy differs"
    assert set(read_by_duckdb.column_names) >= {"segment", "frame_bucket"}

    ctx = datafusion.SessionContext()
    ctx.register_listing_table(
        "episodes",
        by_bucket,
        table_partition_cols=[("segment", pa.string()), ("frame_bucket", pa.string())],
        file_extension=".parquet",
    )
    read_by_datafusion = ctx.sql(f"SELECT * FROM episodes {order}").to_arrow_table()
    assert plain(read_by_datafusion) == expected, "DataFusion's read of the Hive copy differs"

    # The same aggregation, by chunkstore over the dataset and by DuckDB over the copy.
    query = SEGMENT_AGGREGATE
    ours_rows = sql_rows(binary, directory, query.format(table="frame"))
    duck_rows = duckdb.sql(
        query.format(table=f"read_parquet('{glob}', hive_partitioning = true)")
    ).fetchall()
    assert ours_rows == [tuple(row) for row in duck_rows], (
        ours_rows[:3],
        duck_rows[:3],
    )

    by_entity = os.path.join(scratch, "hive_by_entity")
    subprocess.run([binary, directory, "hive", by_entity, "--index", "frame"], check=True)
    counts = (
        "SELECT rerun_segment_id, entity_path, count(*) AS n FROM {table} "
        "GROUP BY rerun_segment_id, entity_path ORDER BY rerun_segment_id, entity_path"
    )
    ours_counts = sql_rows(binary, directory, counts.format(table="chunks"))
    entity_glob = os.path.join(by_entity, "**", "*.parquet")
    duck_counts = duckdb.sql(
        counts.format(table=f"read_parquet('{entity_glob}', hive_partitioning = true)")
    ).fetchall()
    assert ours_counts == [tuple(row) for row in duck_counts], (ours_counts[:3], duck_counts[:3])
    print(
        f"hive copies read back by DuckDB and DataFusion: {ours.num_rows} rows equal, "
        f"{len(ours_rows)} segments' aggregates and {len(ours_counts)} entity counts equal"
    )


def check_from_bucket(binary, directory, scratch):
    """The same files, uploaded as they are to the S3 test server's bucket: chunkstore
    reading the prefix (ranged GETs; the footerless file streamed) gives Rerun's tables
    as it does from the directory (Rerun reads the directory)."""
    endpoint = s3_endpoint("the dataset judged from a bucket")
    if not endpoint:
        return 0
    s3 = s3_client(endpoint)
    prefix = f"catalog-{os.getpid()}-{int(time.time())}/dataset/"
    for name in sorted(os.listdir(directory)):
        if name.endswith(".rrd"):
            s3.upload_file(os.path.join(directory, name), "chunkstore-test", prefix + name)
    url = f"s3://chunkstore-test/{prefix}"
    env = tool_env(endpoint)
    return check_tables(
        directory,
        lambda index, fill: chunkstore_table(binary, url, index, fill, scratch, env),
        label="from the bucket: ",
    )


def duckdb_with_extensions():
    """DuckDB 1.5.5 with httpfs and delta loaded from their PyPI packages (no download),
    and the S3 test server's credentials as its secret."""
    import duckdb
    import duckdb_extension_delta
    import duckdb_extension_httpfs

    con = duckdb.connect()
    for package in (duckdb_extension_httpfs, duckdb_extension_delta):
        folder = os.path.join(os.path.dirname(package.__file__), "extensions", f"v{duckdb.__version__}")
        (extension,) = os.listdir(folder)
        con.execute(f"LOAD '{os.path.join(folder, extension)}'")
    return con


def check_delta(binary, directory, scratch, ours):
    """The dataset as a Delta table in the S3 test server's bucket: made by one commit of
    20 segments, then grown by two appends run at once (one of them commits after the
    other), read by deltalake, Polars and DuckDB (`delta_scan`): each read equals the
    dataset's table, and an aggregation over it equals chunkstore's SQL over the dataset.
    A segment appended twice is one line and exit 2."""
    import deltalake
    import polars as pl

    endpoint = s3_endpoint("the Delta table in a bucket")
    if not endpoint:
        return
    env = tool_env(endpoint)
    table = f"s3://chunkstore-test/catalog-delta-{os.getpid()}-{int(time.time())}/episodes/"
    files = sorted(f for f in os.listdir(directory) if f.endswith(".rrd"))
    parts = []
    for n, names in enumerate([files[:20], files[20:25], files[25:]]):
        part = os.path.join(scratch, f"part{n}")
        os.makedirs(part)
        for name in names:
            os.symlink(os.path.join(directory, name), os.path.join(part, name))
        parts.append(part)
    layout = ["--delta", "--index", "frame", "--bucket", "8"]
    subprocess.run([binary, parts[0], "hive", table, *layout], env=env, check=True)
    appends = [
        subprocess.Popen(
            [binary, part, "hive", table, *layout, "--append"],
            env=env,
            stderr=subprocess.PIPE,
            text=True,
        )
        for part in parts[1:]
    ]
    said = [append.communicate()[1] for append in appends]
    assert all(append.returncode == 0 for append in appends), said
    for line in said:
        print(line.strip())
    again = subprocess.run(
        [binary, parts[2], "hive", table, *layout, "--append"], env=env, capture_output=True, text=True
    )
    assert again.returncode == 2 and again.stderr.count("\n") == 1, again.stderr
    assert "is in the table already" in again.stderr, again.stderr

    options = s3_options(endpoint)
    expected = plain(ours)
    order = [("rerun_segment_id", "ascending"), ("frame", "ascending")]
    delta_table = deltalake.DeltaTable(table, storage_options=options)
    assert delta_table.version() == 2, delta_table.version()
    by_deltalake = delta_table.to_pyarrow_table().sort_by(order)
    assert plain(by_deltalake) == expected, "deltalake's read of the Delta table differs"
    by_polars = pl.read_delta(table, storage_options=options).sort(["rerun_segment_id", "frame"])
    assert plain(by_polars.to_arrow()) == expected, "Polars' read of the Delta table differs"

    con = duckdb_with_extensions()
    host = endpoint.split("://", 1)[1]
    con.execute(
        f"CREATE SECRET (TYPE s3, KEY_ID 'key', SECRET 'secret', ENDPOINT '{host}', "
        "URL_STYLE 'path', USE_SSL false, REGION 'us-east-1')"
    )
    scan = f"delta_scan('{table.rstrip('/')}')"
    by_duckdb = con.execute(f"SELECT * FROM {scan} ORDER BY rerun_segment_id, frame").arrow()
    if not isinstance(by_duckdb, pa.Table):
        by_duckdb = by_duckdb.read_all()
    assert plain(by_duckdb) == expected, "DuckDB's read of the Delta table differs"
    query = SEGMENT_AGGREGATE
    ours_rows = sql_rows(binary, directory, query.format(table="frame"))
    duck_rows = con.execute(query.format(table=scan)).fetchall()
    assert ours_rows == [tuple(row) for row in duck_rows], (ours_rows[:3], duck_rows[:3])
    print(
        f"Delta table in a bucket (3 commits, 2 of them racing) read by deltalake, Polars and "
        f"DuckDB: {ours.num_rows} rows equal, {len(ours_rows)} segments' aggregates equal"
    )


def main():
    python = sys.argv[1] == "--python"
    binary = None if python else os.path.abspath(sys.argv[1])
    with tempfile.TemporaryDirectory() as scratch:
        os.environ["HOME"] = scratch  # Rerun writes its settings under HOME
        directory = os.path.join(scratch, "dataset")
        os.makedirs(directory)
        ids = write_recordings(directory)
        if python:
            check_python(directory, ids)
            return
        checked = check_tables(
            directory, lambda index, fill: chunkstore_table(binary, directory, index, fill, scratch)
        )
        checked += check_from_bucket(binary, directory, scratch)
        frame_table = chunkstore_table(binary, directory, "frame", False, scratch)
        check_hive(binary, directory, scratch, frame_table)
        check_delta(binary, directory, scratch, frame_table)
        # A corrupt file: Rerun skips it without a word; we name it, or skip it and say so.
        with open(os.path.join(directory, "corrupt.rrd"), "wb") as f:
            f.write(b"RRF2" + bytes(100))
        failed = subprocess.run(
            [binary, directory, "dataframe", "frame", "--out", os.path.join(scratch, "x.arrow")],
            capture_output=True,
            text=True,
        )
        assert failed.returncode == 2, failed
        assert "corrupt.rrd" in failed.stderr and failed.stderr.count("\n") == 1, failed.stderr
        skipped = subprocess.run(
            [binary, "--skip-bad", directory, "dataframe", "frame", "--out",
             os.path.join(scratch, "y.arrow")],
            capture_output=True,
            text=True,
        )
        assert skipped.returncode == 0, skipped.stderr
        assert "corrupt.rrd" in skipped.stderr, skipped.stderr
        with ipc.open_file(os.path.join(scratch, "y.arrow")) as reader:
            rest = reader.read_all()
        theirs = rerun_table(directory, "frame", False)
        compare(rest, theirs, "frame", False)
        print(f"dataset tables equal Rerun 0.41's catalog: {checked} cells, {len(ids)} segments")


if __name__ == "__main__":
    main()
