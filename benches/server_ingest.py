"""Ingest into `chunkstore serve` beside Rerun's own gRPC server, with the same SDK script.

    python benches/server_ingest.py target/release/chunkstore [--mb 64] [--rounds 3]

Needs `pip install rerun-sdk==0.41.0 adbc-driver-flightsql pyarrow numpy psutil`. Each
client process logs its share of the data with Rerun's Python SDK (`send_columns`, so that
the SDK's own encoding is not what is measured) and calls `disconnect()`, which returns
once the server acknowledged the stream; the time is from starting the clients to the last
acknowledgement. Printed, as JSON lines:

- `ingest`: rows/s and MB/s (bytes of the `.rrd` the same data makes) for 1 and 8 clients
  into `chunkstore serve`, `chunkstore serve --persist`, and `rerun --serve-grpc`, and the
  time `chunkstore FILE.rrd stats` takes to load the same data from a file;
- `sql_latency`: a Flight SQL query's p50/p99 while 8 clients ingest, and idle;
- `soak`: peak RSS of `chunkstore serve --memory-limit` while 8 clients send several times
  the limit.

Numbers are ratios on a shared machine: compare within one run.
"""

import argparse
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import psutil

CLIENT = r"""
import sys, numpy as np, rerun as rr
url, rid, mb = sys.argv[1], sys.argv[2], float(sys.argv[3])
path = sys.argv[4] if len(sys.argv) > 4 else None
rec = rr.RecordingStream("chunkstore_bench", recording_id=rid)
rec.set_sinks(rr.FileSink(path)) if path else rec.set_sinks(rr.GrpcSink(url))
rows_per_chunk = 2000
# Per chunk: 2000 scalars on 2 timelines, and one 2000-point cloud: about 60 kB.
chunks = max(1, int(mb * 1e6 / 60_000))
rng = np.random.default_rng(0)
for c in range(chunks):
    frames = np.arange(c * rows_per_chunk, (c + 1) * rows_per_chunk)
    rec.send_columns(
        "robot/joint",
        indexes=[rr.TimeColumn("frame", sequence=frames), rr.TimeColumn("t", duration=frames * 1e-3)],
        columns=rr.Scalars.columns(scalars=rng.random(rows_per_chunk)),
    )
    rec.set_time("frame", sequence=int(frames[-1]))
    rec.log("lidar", rr.Points3D(rng.random((2000, 3), dtype=np.float32)))
rec.disconnect()
print(chunks * (rows_per_chunk + 1))
"""


class Proc:
    def __init__(self, args, ready_line=None, env=None):
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
        self.url = None
        if ready_line:
            line = self.proc.stdout.readline().strip()
            assert line.startswith(ready_line), line
            self.url = line.removeprefix("listening on ")

    def stop(self):
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()


def free_port():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_chunkstore(binary, *args):
    return Proc([binary, "serve", "--addr", "127.0.0.1:0", *args], ready_line="listening on ")


def start_rerun(env):
    port = free_port()
    # The `rerun` on PATH is a Python launcher; the server is the binary it starts. Run
    # that binary directly, so that its CPU time is measured and a kill reaches it.
    import importlib.util

    binary = os.path.join(os.path.dirname(importlib.util.find_spec("rerun_cli").origin), "rerun")
    proc = Proc([binary, "--serve-grpc", "--port", str(port), "--server-memory-limit", "16GB"], env=env)
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    # Wait until it accepts connections.
    import socket

    for _ in range(200):
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.1).close()
            break
        except OSError:
            time.sleep(0.05)
    proc.url = url
    return proc


def run_clients(script, url, clients, mb_each):
    start = time.perf_counter()
    procs = [
        subprocess.Popen([sys.executable, script, url, f"bench-{i}", str(mb_each)], stdout=subprocess.PIPE, text=True)
        for i in range(clients)
    ]
    rows = sum(int(p.communicate()[0].strip() or 0) for p in procs)
    return time.perf_counter() - start, rows


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("chunkstore")
    parser.add_argument("--mb", type=float, default=64.0, help="MB per run, shared by the clients")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--soak-limit-mib", type=int, default=256)
    parser.add_argument("--soak-factor", type=float, default=6.0, help="data sent, in multiples of the limit")
    parser.add_argument("--only", default="ingest,sql,soak")
    args = parser.parse_args()
    binary = os.path.abspath(args.chunkstore)
    work = tempfile.mkdtemp(prefix="chunkstore-bench-")
    env = dict(os.environ, HOME=os.path.join(work, "home"))
    os.makedirs(env["HOME"])
    os.environ["HOME"] = env["HOME"]
    script = os.path.join(work, "client.py")
    with open(script, "w") as f:
        f.write(CLIENT)
    only = set(args.only.split(","))
    try:
        # The same data as a file, for its size and its load time.
        data_file = os.path.join(work, "data.rrd")
        floors = []
        for _ in range(args.rounds):
            t = time.perf_counter()
            subprocess.run([sys.executable, script, "", "bench-file", str(args.mb), data_file], check=True, stdout=subprocess.DEVNULL)
            floors.append(time.perf_counter() - t)
        size_mb = os.path.getsize(data_file) / 1e6
        # The client's own floor: the same script writing to a file, no server.
        print(json.dumps({"bench": "ingest", "target": "SDK to a FileSink (no server)", "clients": 1, "mb": round(size_mb, 1), "seconds": round(min(floors), 3), "mb_per_s": round(size_mb / min(floors), 1)}), flush=True)

        if "ingest" in only:
            loads = []
            for _ in range(args.rounds):
                t = time.perf_counter()
                subprocess.run([binary, data_file, "stats"], check=True, stdout=subprocess.DEVNULL)
                loads.append(time.perf_counter() - t)
            load_s = min(loads)
            print(json.dumps({"bench": "ingest", "target": "chunkstore load .rrd", "mb": round(size_mb, 1), "seconds": round(load_s, 3), "mb_per_s": round(size_mb / load_s, 1)}), flush=True)
            for clients in (1, 8):
                for name in ("chunkstore serve", "chunkstore serve --persist", "rerun --serve-grpc"):
                    times = []
                    cpu = []
                    rows = 0
                    for r in range(args.rounds):
                        if name == "rerun --serve-grpc":
                            server = start_rerun(env)
                        elif name.endswith("--persist"):
                            server = start_chunkstore(binary, "--persist", os.path.join(work, f"log-{clients}-{r}.rrd"))
                        else:
                            server = start_chunkstore(binary)
                        try:
                            seconds, rows = run_clients(script, server.url, clients, args.mb / clients)
                            times.append(seconds)
                            # The server's own CPU time (all its threads): what ingest costs it,
                            # whatever bounds the wall time.
                            used = psutil.Process(server.proc.pid).cpu_times()
                            cpu.append(used.user + used.system)
                        finally:
                            server.stop()
                    best = min(times)
                    print(json.dumps({
                        "bench": "ingest", "target": name, "clients": clients, "rows": rows,
                        "mb": round(size_mb, 1), "seconds": round(best, 3),
                        "rows_per_s": round(rows / best), "mb_per_s": round(size_mb / best, 1),
                        "server_cpu_s": round(min(cpu), 3),
                    }), flush=True)

        if "sql" in only:
            import adbc_driver_flightsql.dbapi as flight_sql

            server = start_chunkstore(binary)
            flight = server.url.replace("rerun+http://", "grpc://").removesuffix("/proxy")
            query = "SELECT count(*), avg(\"/robot/joint:Scalars:scalars\"[1]) FROM frame WHERE frame BETWEEN 1000 AND 50000"

            def latencies(stop, out):
                with flight_sql.connect(flight) as conn, conn.cursor() as cur:
                    while not stop.is_set():
                        t = time.perf_counter()
                        try:
                            cur.execute(query)
                            cur.fetch_arrow_table()
                        except Exception:  # the table may not exist in the first moments
                            continue
                        out.append(time.perf_counter() - t)

            busy = []
            stop = threading.Event()
            reader = threading.Thread(target=latencies, args=(stop, busy))
            reader.start()
            run_clients(script, server.url, 8, args.mb * 2 / 8)
            stop.set()
            reader.join()
            idle = []
            stop = threading.Event()
            reader = threading.Thread(target=latencies, args=(stop, idle))
            reader.start()
            time.sleep(5)
            stop.set()
            reader.join()
            server.stop()

            def pct(xs, p):
                xs = sorted(xs)
                return xs[min(len(xs) - 1, int(p * len(xs)))] if xs else float("nan")

            print(json.dumps({
                "bench": "sql_latency", "queries_busy": len(busy), "queries_idle": len(idle),
                "busy_p50_ms": round(pct(busy, 0.5) * 1e3, 2), "busy_p99_ms": round(pct(busy, 0.99) * 1e3, 2),
                "idle_p50_ms": round(pct(idle, 0.5) * 1e3, 2), "idle_p99_ms": round(pct(idle, 0.99) * 1e3, 2),
            }), flush=True)

        if "soak" in only:
            limit = args.soak_limit_mib << 20
            server = start_chunkstore(binary, "--memory-limit", f"{args.soak_limit_mib}MiB")
            proc = psutil.Process(server.proc.pid)
            peak = 0
            stop = threading.Event()

            def sample():
                nonlocal peak
                while not stop.is_set():
                    peak = max(peak, proc.memory_info().rss)
                    time.sleep(0.1)

            sampler = threading.Thread(target=sample)
            sampler.start()
            # The SDK's chunks are about 4x larger in memory than on the wire (LZ4):
            # send soak_factor x the limit in memory terms.
            sent_mb = args.soak_factor * limit / 1e6 / 4
            seconds, rows = run_clients(script, server.url, 8, sent_mb / 8)
            stop.set()
            sampler.join()
            server.stop()
            print(json.dumps({
                "bench": "soak", "limit_mib": args.soak_limit_mib, "sent_wire_mb": round(sent_mb, 1),
                "rows": rows, "seconds": round(seconds, 1), "peak_rss_mib": round(peak / 2**20, 1),
                "peak_over_limit": round(peak / limit, 2),
            }), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
