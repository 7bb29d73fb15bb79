"""The Python package's read benchmark: open a recording, read one series whole, read
the whole dataframe, with chunkstore or with Rerun 0.41's own Python reader, in this
process; prints one JSON line (seconds per step, rows, peak RSS).

    cargo run --release --example read_bench -- generate /tmp/r1m.rrd 100 10000
    python python/bench/read_bench.py /tmp/r1m.rrd chunkstore [RUNS]
    python python/bench/read_bench.py /tmp/r1m.rrd rerun [RUNS]     # rerun-sdk==0.41.0
    python python/bench/read_bench.py /tmp/r1m.rrd compare          # same answers?
    cargo run --release --example read_bench -- measure /tmp/r1m.rrd  # the same in Rust

Steps (each the median of RUNS, default 5, except opening, done once):
- open: every chunk decoded into a store (chunkstore: ``open(path, lazy=False)``;
  Rerun: ``ChunkStore.from_chunks(RrdReader(path).stream().to_chunks())``); chunkstore's
  lazy open (footer only) is timed too.
- range: the scalar series of ``/fleet/g0/r0`` whole, as a pyarrow table (chunkstore:
  ``Store.range``; Rerun: its dataframe reader with that one column, which is how its
  Python API reads one series).
- dataframe: the whole sparse dataframe on ``frame`` as one ``pyarrow.Table``
  (``dataframe("frame").read_all()``; Rerun: ``reader(index="frame").to_arrow_table()``).
``compare`` loads the file with both and checks that the series and the whole table are
the same, column by column (Rerun's columns cast to ours where it widens a type). Not run
by CI.
"""

import json
import resource
import sys
import time

path, engine = sys.argv[1], sys.argv[2]
runs = int(sys.argv[3]) if len(sys.argv) > 3 else 5
ENTITY, COMPONENT = "/fleet/g0/r0", "scalar"


def median_time(step):
    times, result = [], None
    for _ in range(runs):
        # The previous run's result is freed before the clock starts: `result = step()`
        # alone would free it inside the next run's time (a 100 MB table, about a fifth
        # of chunkstore's whole-table read of the 1 M file).
        result = None
        start = time.perf_counter()
        result = step()
        times.append(time.perf_counter() - start)
    times.sort()
    return times[len(times) // 2], result


out = {"engine": engine}
if engine == "chunkstore":
    import chunkstore

    start = time.perf_counter()
    lazy = chunkstore.open(path)
    out["lazy_open_s"] = round(time.perf_counter() - start, 4)
    out["lazy_range_s"], lazy_series = median_time(
        lambda: lazy.range("frame", -(2**62), 2**62, entity=ENTITY, component=COMPONENT)
    )
    del lazy
    start = time.perf_counter()
    store = chunkstore.open(path, lazy=False)
    out["open_s"] = round(time.perf_counter() - start, 4)
    out["rows_stored"] = len(store)
    out["range_s"], series = median_time(
        lambda: store.range("frame", -(2**62), 2**62, entity=ENTITY, component=COMPONENT)
    )
    assert series.equals(lazy_series)
    out["dataframe_s"], table = median_time(lambda: store.dataframe("frame").read_all())
elif engine == "rerun":
    import rerun.chunk as rc

    start = time.perf_counter()
    store = rc.ChunkStore.from_chunks(rc.RrdReader(path).stream().to_chunks())
    out["open_s"] = round(time.perf_counter() - start, 4)
    out["range_s"], series = median_time(
        lambda: store.reader(index="frame", contents={ENTITY: [COMPONENT]}).to_arrow_table()
    )
    out["dataframe_s"], table = median_time(lambda: store.reader(index="frame").to_arrow_table())
elif engine == "compare":
    import chunkstore
    import rerun.chunk as rc

    ours = chunkstore.open(path, lazy=False)
    theirs = rc.ChunkStore.from_chunks(rc.RrdReader(path).stream().to_chunks())
    series = ours.range("frame", -(2**62), 2**62, entity=ENTITY, component=COMPONENT)
    their_series = theirs.reader(index="frame", contents={ENTITY: [COMPONENT]}).to_arrow_table()
    column = f"{ENTITY}:{COMPONENT}"
    same_series = series.column(COMPONENT).to_pylist() == their_series.column(column).to_pylist() and (
        series.column("frame").to_pylist() == their_series.column("frame").to_pylist()
    )
    table = ours.dataframe("frame").read_all()
    their_table = theirs.reader(index="frame").to_arrow_table().sort_by("frame")
    same_names = table.column_names == their_table.column_names
    mismatched = [
        name
        for name in table.column_names
        if ":" in name
        and not table.column(name)
        .combine_chunks()
        .cast(their_table.schema.field(name).type)
        .equals(their_table.column(name).combine_chunks())
    ]
    print(json.dumps({
        "engine": "compare",
        "same_series": same_series,
        "series_rows": series.num_rows,
        "same_column_names": same_names,
        "data_columns": sum(":" in n for n in table.column_names),
        "mismatched_columns": mismatched[:5],
        "rows": [table.num_rows, their_table.num_rows],
        "same_frame_column": table.column("frame").to_pylist() == their_table.column("frame").to_pylist(),
    }), flush=True)
    sys.exit(0 if same_series and same_names and not mismatched else 1)
else:
    sys.exit(f"unknown engine {engine!r}: chunkstore, rerun or compare")

out["range_rows"] = series.num_rows
out["dataframe_rows"] = table.num_rows
out["dataframe_columns"] = table.num_columns
# Data columns only (`<entity>:<component>`), as the Rust side counts them.
out["non_null_cells"] = sum(
    len(c) - c.null_count for name, c in zip(table.column_names, table.columns) if ":" in name
)
out["peak_rss_mib"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
for key in ("range_s", "dataframe_s", "lazy_range_s"):
    if key in out:
        out[key] = round(out[key], 6)
print(json.dumps(out), flush=True)
