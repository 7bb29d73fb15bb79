"""The SQL benchmark's query on the store's view exported as Parquet, through DuckDB and
DataFusion's Python package (`pip install duckdb datafusion`), for docs/PERFORMANCE.md.

    cargo run --release --features datafusion --example sql_bench -- 100 1000000 1000 /tmp/v.parquet
    python benches/sql_engines.py /tmp/v.parquet 500000 509999 [RUNS]

RUNS runs of each query (3 by default), the median. `frame % 2^62` defeats the range's
pushdown (every frame here is below 2^62, so it keeps the answer): a full scan.
`frame + 0` does not, in DuckDB: its optimizer folds the `+ 0` away and prunes the file's
row groups by their statistics (its `EXPLAIN` shows `(frame >= LO) AND (frame <= HI)` as
the Parquet scan's filter), so that query is the pushed-down range again; it is kept,
labelled so, because earlier measurements quoted it as a full scan.
"""

import resource
import statistics
import sys
import time

import datafusion
import duckdb


RUNS = 3
# The same expression as `examples/sql_bench.rs`'s "no pushdown" query.
FULL_SCAN = "frame % 4611686018427387904"


def bench(name, run):
    times = []
    answer = None
    for _ in range(RUNS):
        start = time.perf_counter()
        answer = run()
        times.append(time.perf_counter() - start)
    print(f"{name}: median {statistics.median(times):.4f} s (min {min(times):.4f}) of {len(times)} runs, answer {answer}")


def main():
    global RUNS
    path, lo, hi = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    if len(sys.argv) > 4:
        RUNS = int(sys.argv[4])

    def query(source, column):
        return (
            f'SELECT count(*) AS n, avg("/e/7:x"[1]) AS mean FROM {source} '
            f"WHERE {column} BETWEEN {lo} AND {hi}"
        )

    con = duckdb.connect()
    source = f"read_parquet('{path}')"
    bench(f"duckdb {duckdb.__version__} range", lambda: con.sql(query(source, "frame")).fetchall())
    bench(
        f"duckdb {duckdb.__version__} frame + 0 (folded: the range again)",
        lambda: con.sql(query(source, "frame + 0")).fetchall(),
    )
    bench(f"duckdb {duckdb.__version__} no pushdown", lambda: con.sql(query(source, FULL_SCAN)).fetchall())
    ctx = datafusion.SessionContext()
    ctx.register_parquet("v", path)
    bench(f"datafusion {datafusion.__version__} range", lambda: ctx.sql(query("v", "frame")).collect()[0].to_pylist())
    bench(
        f"datafusion {datafusion.__version__} no pushdown",
        lambda: ctx.sql(query("v", FULL_SCAN)).collect()[0].to_pylist(),
    )
    print("peak RSS MiB", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024)


if __name__ == "__main__":
    main()
