"""Ingest into `chunkstore serve` beside Rerun's own gRPC server, with the same SDK script.

    python benches/server_ingest.py target/release/chunkstore [--mb 64] [--rounds 3]

Needs `pip install rerun-sdk==0.41.0 adbc-driver-flightsql pyarrow numpy psutil`. Each
client process logs its share of the data with Rerun's Python SDK (`send_columns`, so that
the SDK's own encoding is not what is measured) and calls `disconnect()`, which returns
once the server acknowledged the stream; the time is from starting the clients to the last
acknowledgement. Printed, as JSON lines:

- `ingest`: rows/s and MB/s (bytes of the `.rrd` the same data makes) for 1 and 8 clients
  into `chunkstore serve`, `chunkstore serve --persist`, and `rerun --serve-grpc`, with the
  server's CPU seconds (all threads) beside the CPU seconds of `chunkstore --eager FILE.rrd
  stats` loading the same data from a file (`server_cpu_over_load_cpu`);
- `sql_latency`: a Flight SQL query's p50/p99 idle and while 8 clients ingest. The server
  and this script's reader run on one core and the clients on the others (as when they are
  other machines); the clients first log a history the query reads (frames 1,000 to
  50,000), then, all starting at once after their imports, newer frames, in waves until as
  many queries ran during their sending as idle, then idle again over the data the waves
  added (`idle_after_*`); every query does the same work. p99 of the default 200 busy
  queries is the third slowest and moves run to run; `--queries 1000` is steadier;
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
path = sys.argv[4] if len(sys.argv) > 4 and sys.argv[4] else None
first_chunk = int(sys.argv[5]) if len(sys.argv) > 5 else 0
rec = rr.RecordingStream("chunkstore_bench", recording_id=rid)
rec.set_sinks(rr.FileSink(path)) if path else rec.set_sinks(rr.GrpcSink(url))
rows_per_chunk = 2000
# Per chunk: 2000 scalars on 2 timelines, and one 2000-point cloud: about 60 kB.
chunks = max(1, int(mb * 1e6 / 60_000))
rng = np.random.default_rng(0)
if len(sys.argv) > 6 and sys.argv[6] == "together":
    # Started, imported and connected: wait for the others.
    print("ready", flush=True)
    sys.stdin.readline()
for c in range(first_chunk, first_chunk + chunks):
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


def run_clients(script, url, clients, mb_each, first_chunk=0, cpus=None):
    """Runs `clients` SDK processes (on `cpus` only, if given), each logging `mb_each` MB
    from chunk `first_chunk` on; returns the seconds to the last acknowledgement and the
    rows sent."""
    pin = ["taskset", "-c", cpus] if cpus else []
    start = time.perf_counter()
    procs = [
        subprocess.Popen([*pin, sys.executable, script, url, f"bench-{i}", str(mb_each), "", str(first_chunk)], stdout=subprocess.PIPE, text=True)
        for i in range(clients)
    ]
    rows = sum(int(p.communicate()[0].strip() or 0) for p in procs)
    return time.perf_counter() - start, rows


def run_clients_together(script, url, clients, mb_each, first_chunk, cpus):
    """As `run_clients`, but every client starts sending at once, after all of them have
    started (eight Python processes take seconds to import the SDK): returns when they
    began and when the last one's stream was acknowledged."""
    pin = ["taskset", "-c", cpus] if cpus else []
    procs = [
        subprocess.Popen([*pin, sys.executable, script, url, f"bench-{i}", str(mb_each), "", str(first_chunk), "together"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        for i in range(clients)
    ]
    for p in procs:
        assert p.stdout.readline().strip() == "ready"
    began = time.perf_counter()
    for p in procs:
        p.stdin.write("go\n")
        p.stdin.flush()
    for p in procs:
        p.communicate()
    return began, time.perf_counter()


def cpu_seconds_of(args):
    """Runs `args` to its end; the CPU seconds (user and system, all threads) it took."""
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0, args
    return usage.ru_utime + usage.ru_stime


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("chunkstore")
    parser.add_argument("--mb", type=float, default=64.0, help="MB per run, shared by the clients")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--soak-limit-mib", type=int, default=256)
    parser.add_argument("--soak-factor", type=float, default=6.0, help="data sent, in multiples of the limit")
    parser.add_argument("--only", default="ingest,sql,soak")
    parser.add_argument("--queries", type=int, default=200, help="Flight SQL queries timed idle, and at least as many busy")
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
            load_cpu = []
            for _ in range(args.rounds):
                t = time.perf_counter()
                subprocess.run([binary, data_file, "stats"], check=True, stdout=subprocess.DEVNULL)
                loads.append(time.perf_counter() - t)
                load_cpu.append(cpu_seconds_of([binary, "--eager", data_file, "stats"]))
            load_s = min(loads)
            load_cpu_s = min(load_cpu)
            print(json.dumps({"bench": "ingest", "target": "chunkstore load .rrd", "mb": round(size_mb, 1), "seconds": round(load_s, 3), "mb_per_s": round(size_mb / load_s, 1), "cpu_s": round(load_cpu_s, 3)}), flush=True)
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
                        "server_cpu_over_load_cpu": round(min(cpu) / load_cpu_s, 2),
                    }), flush=True)

        if "sql" in only:
            import adbc_driver_flightsql.dbapi as flight_sql

            # The server (and this process's reader) on one core, the writers on the others,
            # as when they are other machines: what is measured is what ingest costs the
            # server's queries, not what eight SDK processes take from a shared machine.
            cpus = os.cpu_count() or 1
            server_cpus = "0" if cpus > 1 else None
            client_cpus = f"1-{cpus - 1}" if cpus > 1 else None
            if server_cpus:
                os.sched_setaffinity(0, {0})
            pin = ["taskset", "-c", server_cpus] if server_cpus else []
            server = Proc([*pin, binary, "serve", "--addr", "127.0.0.1:0"], ready_line="listening on ")
            flight = server.url.replace("rerun+http://", "grpc://").removesuffix("/proxy")
            # A range of history: the writers first log it, then, while the queries run,
            # what comes after it (new times, as a robot streams): every query does the same
            # work, busy or idle.
            query = "SELECT count(*), avg(\"/robot/joint:Scalars:scalars\"[1]) FROM frame WHERE frame BETWEEN 1000 AND 50000"
            mb_each = args.mb / 8
            chunks_each = max(1, int(mb_each * 1e6 / 60_000))
            run_clients(script, server.url, 8, mb_each, 0, client_cpus)

            def latencies(stop, out, enough):
                """Times queries into `out` (as `(began, seconds)` if `enough` is huge)."""
                with flight_sql.connect(flight) as conn, conn.cursor() as cur:
                    while not stop.is_set() and len(out) < enough:
                        t = time.perf_counter()
                        cur.execute(query)
                        cur.fetch_arrow_table()
                        seconds = time.perf_counter() - t
                        out.append((t, seconds) if enough == 10**9 else seconds)

            idle = []
            latencies(threading.Event(), idle, args.queries)
            # Busy: the queries that began while all eight writers were sending, over
            # waves of them, until there are as many as idle.
            timed = []
            stop = threading.Event()
            reader = threading.Thread(target=latencies, args=(stop, timed, 10**9))
            reader.start()
            windows = []
            while sum(1 for began, _ in timed if any(a <= began <= b for a, b in windows)) < args.queries and len(windows) < 50:
                windows.append(run_clients_together(script, server.url, 8, mb_each, (len(windows) + 1) * chunks_each, client_cpus))
            stop.set()
            reader.join()
            # Idle again, over all the data the waves added: a query whose cost grows with
            # the data outside its range shows here, not as the writers' doing.
            idle_after = []
            latencies(threading.Event(), idle_after, args.queries)
            server.stop()
            os.sched_setaffinity(0, range(cpus))
            busy = [seconds for began, seconds in timed if any(a <= began <= b for a, b in windows)]
            sending = sum(b - a for a, b in windows)
            busy_rows = len(windows) * 8 * chunks_each * 2001

            def pct(xs, p):
                xs = sorted(xs)
                return xs[min(len(xs) - 1, int(p * len(xs)))] if xs else float("nan")

            print(json.dumps({
                "bench": "sql_latency", "pinned": bool(server_cpus), "queries_busy": len(busy), "queries_idle": len(idle),
                "busy_waves": len(windows), "busy_rows_per_s": round(busy_rows / sending),
                "busy_p50_ms": round(pct(busy, 0.5) * 1e3, 2), "busy_p99_ms": round(pct(busy, 0.99) * 1e3, 2),
                "idle_p50_ms": round(pct(idle, 0.5) * 1e3, 2), "idle_p99_ms": round(pct(idle, 0.99) * 1e3, 2),
                "idle_after_p50_ms": round(pct(idle_after, 0.5) * 1e3, 2), "idle_after_p99_ms": round(pct(idle_after, 0.99) * 1e3, 2),
                "p99_busy_over_idle": round(pct(busy, 0.99) / pct(idle, 0.99), 2),
                "p99_busy_over_idle_after": round(pct(busy, 0.99) / pct(idle_after, 0.99), 2),
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
