"""Rerun 0.41's catalog server on a dataset directory, timed: the query `dataset_bench
table` runs on our side (every column of `/robot/sensor0`, in every segment, on `frame`).

    HOME=$(mktemp -d) python benches/dataset_catalog.py DIR

Prints one dict: rows, columns, the server's start and the query's seconds, and the peak
RSS of this process (the server runs in it) and of its children.
"""

import resource
import sys
import time

import rerun as rr

started = time.time()
with rr.server.Server(datasets={"ds": sys.argv[1]}) as server:
    serving = time.time()
    dataset = server.client().get_dataset("ds")
    table = dataset.filter_contents(["/robot/sensor0"]).reader(index="frame").to_arrow_table()
    done = time.time()
    print(
        {
            "rows": table.num_rows,
            "columns": table.num_columns,
            "start_seconds": round(serving - started, 3),
            "query_seconds": round(done - serving, 3),
            "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024,
            "children_peak_rss_mib": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss // 1024,
        }
    )
