"""The dataframe workload through Rerun's own dataframe engine, beside chunkstore's.

Usage (Rerun 0.41 from PyPI: `pip install rerun-sdk==0.41.0 datafusion==54.0.0 pyarrow`):

    DATAFRAME_SCALE=S DATAFRAME_RRD=/tmp/df.rrd \
        cargo run --release --features parquet --example workloads dataframe
    python3 benches/rerun_dataframe.py /tmp/df.rrd target/release/chunkstore [RUNS [QUERY...]]

writes the workload's data as an `.rrd` (and times chunkstore on it), then times Rerun's
`ChunkStore.reader(...)` on the same file for the same four queries (sparse and filled,
whole and the middle 1% of frames; or only the QUERY names given) and checks that
`chunkstore <rrd> dataframe` gives the same table (every column, cell by cell). Prints one
JSON line per query. Rerun's filled view of the whole table at full scale outgrows this
machine's 24 GiB: past RERUN_DF_MAX_RSS_GIB (default 16) resident, the script prints a
line saying so and exits 3 rather than let the machine swap. Not run by CI.
"""

import json
import os
import subprocess
import sys
import tempfile
import threading
import time

import psutil

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.ipc as ipc
import rerun.chunk as rc
from datafusion import col, lit

rrd, tool = sys.argv[1], sys.argv[2]
runs = int(sys.argv[3]) if len(sys.argv) > 3 else 3
only = set(sys.argv[4:])
max_rss = float(os.environ.get("RERUN_DF_MAX_RSS_GIB", "16")) * 2**30
current = {"query": None}


def watch_memory():
    me = psutil.Process()
    while True:
        rss = me.memory_info().rss
        if rss > max_rss:
            print(json.dumps({"engine": "rerun-0.41 ChunkStore.reader", "query": current["query"],
                              "exceeded_rss_bytes": rss}), flush=True)
            os._exit(3)
        time.sleep(0.2)


threading.Thread(target=watch_memory, daemon=True).start()

start = time.perf_counter()
store = rc.ChunkStore.from_chunks(rc.RrdReader(rrd).stream().to_chunks())
load_s = time.perf_counter() - start

frames = store.reader(index="frame").select("frame").to_arrow_table().column("frame")
lo_all, hi_all = pc.min(frames).as_py(), pc.max(frames).as_py()
span = hi_all + 1
lo_pct, hi_pct = span // 2, span // 2 + span // 100 - 1

for name, fill, lo, hi in [
    ("sparse_all", False, None, None),
    ("filled_all", True, None, None),
    ("sparse_1pct", False, lo_pct, hi_pct),
    ("filled_1pct", True, lo_pct, hi_pct),
]:
    if only and name not in only:
        continue
    current["query"] = name
    times = []
    table = None
    for _ in range(runs):
        start = time.perf_counter()
        frame = store.reader(index="frame", fill_latest_at=fill)
        if lo is not None:
            frame = frame.filter((col("frame") >= lit(lo)) & (col("frame") <= lit(hi)))
        table = frame.to_arrow_table().sort_by("frame")
        times.append(time.perf_counter() - start)
    times.sort()
    rerun_s = times[len(times) // 2]
    non_null = sum(len(c) - c.null_count for c in table.columns[1:])

    # chunkstore's answer to the same query, through the tool, must be the same table.
    with tempfile.NamedTemporaryFile(suffix=".arrow") as out:
        args = [tool, rrd, "dataframe", "frame", "--out", out.name]
        if fill:
            args.append("--fill-latest-at")
        if lo is not None:
            args += ["--range", str(lo), str(hi)]
        subprocess.run(args, check=True)
        ours = ipc.open_file(out.name).read_all()
    same = ours.column_names == table.column_names and all(
        ours.column(i).combine_chunks().cast(table.schema.field(i).type).equals(
            table.column(i).combine_chunks()
        )
        for i in range(table.num_columns)
    )
    print(
        json.dumps(
            {
                "engine": "rerun-0.41 ChunkStore.reader",
                "query": name,
                "rows": table.num_rows,
                "columns": table.num_columns - 1,
                "non_null_cells": non_null,
                "seconds": round(rerun_s, 4),
                "rows_per_s": round(table.num_rows / rerun_s),
                "cells_per_s": round(table.num_rows * (table.num_columns - 1) / rerun_s),
                "same_table_as_chunkstore": same,
                "load_seconds": round(load_s, 3),
            }
        ),
        flush=True,
    )
