"""A long run of `chunkstore serve` under load (issue 72, item 5): writers and readers for
a set time at a memory limit with `--persist`, then a SIGKILL and a restart.

    HOME=$(mktemp -d) python benches/server_soak.py target/release/chunkstore \
        [--seconds 3600] [--writers 8] [--readers 4] [--limit-mib 256]

Writers are Rerun SDK processes, each logging to a recording of its own in streams of
about two seconds (connect, log, `disconnect()`, which returns once the server
acknowledged the stream), and writing the last frame of each acknowledged stream to a
ledger. Readers are ADBC Flight SQL connections querying in a loop. Sampled every 0.2 s:
the server's RSS and the log's size; every 10 s, its metrics. At the end the server is
killed (SIGKILL) and restarted on the same log: every writer's last acknowledged frame must
be there (garbage collection keeps the latest row of every column). Printed: one JSON line.
Needs `pip install rerun-sdk==0.41.0 adbc-driver-flightsql pyarrow numpy psutil`.
"""

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request

import psutil

WRITER = r"""
import sys, time, numpy as np, rerun as rr
url, rid, ledger, until = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
rng = np.random.default_rng(abs(hash(rid)) % 2**32)
frame = 0
while time.time() < until:
    rec = rr.RecordingStream("chunkstore_soak", recording_id=rid)
    rec.connect_grpc(url)
    stream_end = time.time() + 2
    while time.time() < stream_end:
        frames = np.arange(frame, frame + 500)
        rec.send_columns(
            "robot/joint",
            indexes=[rr.TimeColumn("frame", sequence=frames)],
            columns=rr.Scalars.columns(scalars=rng.random(500)),
        )
        rec.set_time("frame", sequence=int(frames[-1]))
        rec.log("robot/cloud", rr.Points3D(rng.random((1000, 3), dtype=np.float32)))
        frame += 500
        time.sleep(0.02)
    rec.disconnect()
    with open(ledger, "a") as f:
        f.write(f"{frame - 1}\n")
"""


def start(binary, *args):
    proc = subprocess.Popen([binary, "serve", "--addr", "127.0.0.1:0", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = proc.stdout.readline().strip()
    assert line.startswith("listening on rerun+http://"), (line, proc.stderr.read())
    return proc, line.removeprefix("listening on ")


def scrape(host):
    with urllib.request.urlopen(f"http://{host}/metrics", timeout=10) as answer:
        text = answer.read().decode()
    return {line.rsplit(" ", 1)[0]: float(line.rsplit(" ", 1)[1])
            for line in text.splitlines() if line and not line.startswith("#")}


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("chunkstore")
    parser.add_argument("--seconds", type=float, default=3600)
    parser.add_argument("--writers", type=int, default=8)
    parser.add_argument("--readers", type=int, default=4)
    parser.add_argument("--limit-mib", type=int, default=256)
    args = parser.parse_args()
    import adbc_driver_flightsql.dbapi as flight_sql

    binary = os.path.abspath(args.chunkstore)
    work = tempfile.mkdtemp(prefix="chunkstore-soak-")
    log = os.path.join(work, "live.rrd")
    metrics_port = "127.0.0.1:0"
    server, url = start(binary, "--memory-limit", f"{args.limit_mib}MiB", "--persist", log,
                        "--metrics-addr", metrics_port)
    flight = url.replace("rerun+http://", "grpc://").removesuffix("/proxy")
    # The metrics address is on stderr, before the stdout line.
    metrics = None
    stderr_lines = []

    def drain():
        nonlocal metrics
        for line in server.stderr:
            stderr_lines.append(line)
            if line.startswith("metrics on http://"):
                metrics = line.removeprefix("metrics on http://").split("/")[0]

    threading.Thread(target=drain, daemon=True).start()
    script = os.path.join(work, "writer.py")
    with open(script, "w") as f:
        f.write(WRITER)
    until = time.time() + args.seconds
    writers = []
    for i in range(args.writers):
        ledger = os.path.join(work, f"ledger-{i}.txt")
        writers.append((f"w{i}", ledger, subprocess.Popen(
            [sys.executable, script, url, f"w{i}", ledger, str(until)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)))

    proc = psutil.Process(server.pid)
    peak_rss = 0
    peak_log = 0
    latencies = []
    errors = []
    stop = threading.Event()

    started = time.time()
    # Peak RSS in each tenth of the run: a leak shows as a rising series.
    rss_by_tenth = [0] * 10

    def sample():
        nonlocal peak_rss, peak_log
        while not stop.is_set():
            rss = proc.memory_info().rss
            peak_rss = max(peak_rss, rss)
            tenth = min(9, int((time.time() - started) * 10 / args.seconds))
            rss_by_tenth[tenth] = max(rss_by_tenth[tenth], rss)
            if os.path.exists(log):
                peak_log = max(peak_log, os.path.getsize(log))
            time.sleep(0.2)

    queries = [
        "SELECT count(*) AS n FROM frame",
        'SELECT rerun_segment_id, max(frame) AS last FROM frame GROUP BY 1',
        "SELECT rerun_segment_id, rows, heap_bytes FROM recordings",
    ]

    def read(k):
        with flight_sql.connect(flight) as conn, conn.cursor() as cur:
            i = k
            while not stop.is_set():
                query = queries[i % len(queries)]
                i += 1
                t = time.perf_counter()
                try:
                    cur.execute(query)
                    cur.fetch_arrow_table()
                    latencies.append(time.perf_counter() - t)
                except Exception as e:  # a table absent before the first chunk
                    if "not found" not in str(e):
                        errors.append(str(e)[:200])
                time.sleep(0.05)

    threads = [threading.Thread(target=sample)] + [threading.Thread(target=read, args=(k,)) for k in range(args.readers)]
    for t in threads:
        t.start()
    samples = []
    while time.time() < until:
        time.sleep(10)
        if metrics:
            try:
                m = scrape(metrics)
                samples.append({k: m.get(k) for k in ("chunkstore_store_bytes", "chunkstore_log_bytes", "process_resident_memory_bytes", "chunkstore_gc_runs_total", "chunkstore_log_rewrites_total")})
            except OSError as e:
                errors.append(f"metrics: {e}")
    for _, _, writer in writers:
        writer.wait(timeout=120)
    final = scrape(metrics) if metrics else {}
    stop.set()
    for t in threads:
        t.join()
    server.send_signal(signal.SIGKILL)
    server.wait()

    # Every writer's last acknowledged frame is served again after the restart.
    again, url = start(binary, "--memory-limit", f"{args.limit_mib}MiB", "--persist", log)
    flight = url.replace("rerun+http://", "grpc://").removesuffix("/proxy")
    with flight_sql.connect(flight) as conn, conn.cursor() as cur:
        cur.execute("SELECT rerun_segment_id AS id, max(frame) AS last FROM frame GROUP BY 1")
        served = dict(zip(*cur.fetch_arrow_table().to_pydict().values()))
    lost = {}
    for rid, ledger, _ in writers:
        acked = [int(x) for x in open(ledger).read().split()] if os.path.exists(ledger) else []
        if acked and served.get(rid, -1) < acked[-1]:
            lost[rid] = (acked[-1], served.get(rid))
    again.send_signal(signal.SIGTERM)
    again.wait(timeout=30)
    rows = sum(v for k, v in final.items() if k.startswith("chunkstore_ingested_rows_total"))
    latencies.sort()
    pct = lambda p: round(latencies[min(len(latencies) - 1, int(p * len(latencies)))] * 1e3, 1) if latencies else None
    print(json.dumps({
        "bench": "soak", "seconds": args.seconds, "writers": args.writers, "readers": args.readers,
        "limit_mib": args.limit_mib, "rows_ingested": rows,
        "peak_rss_mib": round(peak_rss / 2**20, 1), "peak_over_limit": round(peak_rss / (args.limit_mib << 20), 2),
        "peak_rss_mib_by_tenth": [round(r / 2**20) for r in rss_by_tenth],
        "peak_log_mib": round(peak_log / 2**20, 1), "log_rewrites": final.get("chunkstore_log_rewrites_total"),
        "gc_runs": final.get("chunkstore_gc_runs_total"),
        "queries": len(latencies), "query_errors": len(errors), "first_errors": errors[:3],
        "query_p50_ms": pct(0.5), "query_p99_ms": pct(0.99),
        "acknowledged_lost_after_kill": lost,
        "last_samples": samples[-3:],
    }), flush=True)
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
