"""`chunkstore serve` against the real clients: Rerun 0.41's Python SDK and `rerun` CLI, and
ADBC's Flight SQL driver. Run by `.ci/run` (which installs them in a venv):

    python tests/clients/server_sdk.py path/to/chunkstore

Each check starts its own server on a free port and kills it (SIGKILL) at the end. The
`rerun` binary writes under $HOME: this script points HOME at a temporary directory.
"""

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request

import adbc_driver_flightsql.dbapi as flight_sql
import numpy as np
import pyarrow as pa
import pyarrow.ipc as ipc
import rerun as rr

CHUNKSTORE = os.path.abspath(sys.argv[1])
WORK = tempfile.mkdtemp(prefix="chunkstore-server-sdk-")
os.environ["HOME"] = os.path.join(WORK, "home")
os.makedirs(os.environ["HOME"], exist_ok=True)
RERUN = shutil.which("rerun") or os.path.join(os.path.dirname(sys.executable), "rerun")
# A test CA and a server certificate for localhost and 127.0.0.1 (tests/sql/tls/README.md).
TLS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "sql", "tls")
TLS_CA = os.path.join(TLS_DIR, "ca.pem")


SERVERS = []


class Server:
    """`chunkstore serve ARGS`, its URL read from the line it prints; killed at exit if a
    check failed before killing it."""

    def __init__(self, *args):
        SERVERS.append(self)
        self.stderr_path = os.path.join(WORK, f"server-{time.monotonic_ns()}.err")
        self.proc = subprocess.Popen(
            [CHUNKSTORE, "serve", "--addr", "127.0.0.1:0", *args],
            stdout=subprocess.PIPE,
            stderr=open(self.stderr_path, "w"),
            text=True,
        )
        line = self.proc.stdout.readline().strip()
        assert line.startswith("listening on rerun+http"), (line, self.stderr())
        self.proxy = line.removeprefix("listening on ")
        tls = self.proxy.startswith("rerun+https://")
        self.host = self.proxy.split("://", 1)[1].removesuffix("/proxy")
        self.flight = f"grpc+tls://{self.host}" if tls else f"grpc://{self.host}"
        self.db_kwargs = {}
        if tls:
            with open(TLS_CA) as f:
                self.db_kwargs["adbc.flight.sql.client_option.tls_root_certs"] = f.read()

    def stderr(self):
        with open(self.stderr_path) as f:
            return f.read()

    def kill(self):
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()

    def sql(self, query):
        with flight_sql.connect(self.flight, db_kwargs=self.db_kwargs) as conn, conn.cursor() as cur:
            cur.execute(query)
            return cur.fetch_arrow_table()


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def chunkstore_sql(source, query):
    """The same query on a file, through the crate's own CLI (as an Arrow IPC file)."""
    out = os.path.join(WORK, f"answer-{time.monotonic_ns()}.arrow")
    subprocess.run([CHUNKSTORE, source, "sql", query, "--out", out], check=True)
    with ipc.open_file(out) as reader:
        return reader.read_all()


def same(a: pa.Table, b: pa.Table, what):
    a = a.combine_chunks()
    b = b.combine_chunks()
    assert a.column_names == b.column_names, (what, a.column_names, b.column_names)
    assert a.num_rows == b.num_rows, (what, a.num_rows, b.num_rows)
    for name in a.column_names:
        assert a[name].equals(b[name]), (what, name, a[name].slice(0, 5), b[name].slice(0, 5))


def log_scene(rec):
    """Several entities and timelines, static data, a recursive Clear, frames out of
    order, and an image above tonic's 4 MiB default message limit."""
    rec.log("world/points", rr.Points3D(np.arange(30, dtype=np.float32).reshape(10, 3)), static=True)
    rec.log("robot/name", rr.TextDocument("arm"), static=True)
    frames = list(range(60)) + [10, 5, 70, 65]
    for i, frame in enumerate(frames):
        rec.set_time("frame", sequence=frame)
        rec.set_time("sim_time", duration=frame * 0.01)
        rec.log("robot/arm/torque", rr.Scalars(float(i)))
        rec.log("robot/leg", rr.Points2D([[i, frame]]))
    rec.set_time("frame", sequence=30)
    rec.log("robot", rr.Clear(recursive=True))
    rec.set_time("frame", sequence=80)
    rec.log("camera/image", rr.Image(np.full((1200, 1200, 4), 7, dtype=np.uint8)))


def check_tee_equals_server():
    log = os.path.join(WORK, "live.rrd")
    tee = os.path.join(WORK, "tee.rrd")
    server = Server("--persist", log, "--read-mode", "snapshot")
    rec = rr.RecordingStream("chunkstore_test", recording_id="tee")
    rec.set_sinks(rr.GrpcSink(server.proxy), rr.FileSink(tee))
    log_scene(rec)
    rec.disconnect()

    # The tee file is a good recording (Rerun's own check), and what the crate reads from
    # it equals what the server answers through ADBC, table by table.
    subprocess.run([RERUN, "rrd", "verify", tee], check=True, capture_output=True)
    queries = {
        "frame": "SELECT * FROM frame ORDER BY frame",
        "sim_time": "SELECT * FROM sim_time ORDER BY sim_time",
        "chunks": "SELECT entity_path, row_id, frame FROM chunks ORDER BY row_id",
    }
    for table, query in queries.items():
        served = server.sql(query)
        if table != "chunks":  # `*`: the segment column first
            assert served.column_names[0] == "rerun_segment_id", served.column_names
            assert set(served["rerun_segment_id"].to_pylist()) == {"tee"}, table
            served = served.drop_columns(["rerun_segment_id"])
        same(served, chunkstore_sql(tee, query), table)
    assert server.sql("SELECT count(*) AS n FROM frame")["n"][0].as_py() > 60
    # Bound parameters (what BI tools send): `?` and `$1`, each with two values, equal to
    # the same query with the values written in.
    with flight_sql.connect(server.flight) as conn, conn.cursor() as cur:
        for query in ["SELECT count(*) AS n FROM frame WHERE frame >= ?",
                      "SELECT count(*) AS n FROM frame WHERE frame >= $1"]:
            for low in (10, 55):
                cur.execute(query, parameters=(low,))
                bound = cur.fetch_arrow_table()["n"].to_pylist()
                written = server.sql(f"SELECT count(*) AS n FROM frame WHERE frame >= {low}")["n"].to_pylist()
                assert bound == written and written[0] > 0, (query, low, bound, written)
        cur.execute("SELECT DISTINCT rerun_segment_id AS s FROM chunks WHERE entity_path = ?",
                    parameters=("/robot/arm/torque",))
        assert cur.fetch_arrow_table()["s"].to_pylist() == ["tee"]

    # What a viewer reads back (`rerun --save` ends once the snapshot stream ends) is a
    # good recording with the same contents.
    saved = os.path.join(WORK, "saved.rrd")
    subprocess.run(
        [RERUN, "--save", saved, "--bind", "127.0.0.1", "--port", str(free_port()), "--connect", server.proxy],
        check=True,
        capture_output=True,
        timeout=120,
    )
    subprocess.run([RERUN, "rrd", "verify", saved], check=True, capture_output=True)
    for query in ["SELECT * FROM frame ORDER BY frame", "SELECT entity_path, row_id FROM chunks ORDER BY row_id"]:
        same(chunkstore_sql(saved, query), chunkstore_sql(tee, query), "saved: " + query)

    # Killed and restarted on its log: the same answers.
    before = server.sql("SELECT * FROM frame ORDER BY frame")
    server.kill()
    again = Server("--persist", log)
    same(again.sql("SELECT * FROM frame ORDER BY frame"), before, "after restart")
    again.kill()

    # `--persist` of a file Rerun wrote (the tee, with its footer): read back, appended to
    # in a new stream, and still a file Rerun reads.
    rerun_file = os.path.join(WORK, "rerun_written.rrd")
    shutil.copy(tee, rerun_file)
    on_rerun_file = Server("--persist", rerun_file)
    same(on_rerun_file.sql("SELECT * FROM frame ORDER BY frame"), before, "persist of Rerun's file")
    more = rr.RecordingStream("chunkstore_test", recording_id="more")
    more.set_sinks(rr.GrpcSink(on_rerun_file.proxy))
    more.set_time("frame", sequence=1)
    more.log("extra", rr.Scalars(1.0))
    more.disconnect()
    on_rerun_file.kill()
    subprocess.run([RERUN, "rrd", "verify", "--check-footers", "false", rerun_file], check=True, capture_output=True)
    reread = Server("--persist", rerun_file)
    segments = reread.sql("SELECT DISTINCT rerun_segment_id AS s FROM frame ORDER BY s")["s"].to_pylist()
    assert segments == ["more", "tee"], segments
    reread.kill()
    print("tee, ADBC, rerun --save, restart and --persist of Rerun's file agree")


CLIENT = r"""
import sys, rerun as rr
url, rid, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
rec = rr.RecordingStream("chunkstore_test", recording_id=rid)
rec.set_sinks(rr.GrpcSink(url))
for i in range(n):
    rec.set_time("frame", sequence=i)
    rec.log("value", rr.Scalars(float(i)))
rec.disconnect()
"""


def check_many_writers_and_readers():
    server = Server()
    script = os.path.join(WORK, "client.py")
    with open(script, "w") as f:
        f.write(CLIENT)
    rows = 3000
    clients = [
        subprocess.Popen([sys.executable, script, server.proxy, f"client-{i}", str(rows)])
        for i in range(4)
    ]
    queries = 0
    while any(c.poll() is None for c in clients):
        # Readers query throughout; no query may fail (a table may not exist yet).
        try:
            server.sql("SELECT rerun_segment_id, count(*) FROM frame GROUP BY 1")
        except Exception as e:  # noqa: BLE001 - only "no such table yet" is allowed
            assert "frame" in str(e) and "not found" in str(e), e
        queries += 1
    for c in clients:
        assert c.wait() == 0
    counts = server.sql("SELECT rerun_segment_id AS s, count(*) AS n FROM frame GROUP BY 1 ORDER BY 1")
    assert counts["s"].to_pylist() == [f"client-{i}" for i in range(4)], counts
    assert counts["n"].to_pylist() == [rows] * 4, counts
    server.kill()
    print(f"4 writers x {rows} rows all arrived; {queries} queries meanwhile, none failed")


KILLED_CLIENT = r"""
import sys, time, rerun as rr
url, acked = sys.argv[1], sys.argv[2]
for batch in range(1000):
    rec = rr.RecordingStream("chunkstore_test", recording_id="killed")
    rec.set_sinks(rr.GrpcSink(url))
    for i in range(100):
        rec.set_time("frame", sequence=batch * 100 + i)
        rec.log("value", rr.Scalars(float(i)))
    # Returns once the server answered the stream, but also (logging an error, raising
    # nothing) once the connection broke: the time it returned tells the two apart.
    rec.disconnect()
    returned = time.monotonic()
    with open(acked, "a") as f:
        f.write(f"{batch} {returned}\n")
"""


def check_kill_during_ingest():
    log = os.path.join(WORK, "killed.rrd")
    acked = os.path.join(WORK, "acked.txt")
    server = Server("--persist", log)
    script = os.path.join(WORK, "killed_client.py")
    with open(script, "w") as f:
        f.write(KILLED_CLIENT)
    client = subprocess.Popen([sys.executable, script, server.proxy, acked], stderr=subprocess.DEVNULL)
    deadline = time.time() + 60
    while time.time() < deadline:
        if os.path.exists(acked) and len(open(acked).read().split()) >= 5:
            break
        time.sleep(0.05)
    # A `disconnect()` that returned before the kill was answered by the living server; one
    # that returned after it may have returned on the broken connection (the SDK does not
    # say which), so it proves nothing. CLOCK_MONOTONIC is one clock for both processes.
    killed_at = time.monotonic()
    server.kill()  # mid-stream, most likely
    client.kill()
    client.wait()
    lines = [line.split() for line in open(acked).read().splitlines()]
    batches = [int(batch) for batch, returned in lines if float(returned) < killed_at]
    assert batches, "no stream was acknowledged"
    restarted = Server("--persist", log)
    frames = set(restarted.sql("SELECT frame FROM frame")["frame"].to_pylist())
    for batch in batches:
        missing = [f for f in range(batch * 100, batch * 100 + 100) if f not in frames]
        assert not missing, f"acknowledged batch {batch} lost frames {missing[:5]}"
    restarted.kill()
    print(f"killed mid-ingest: all {len(batches)} acknowledged streams were back after restart")

WIDENING_CLIENT = r"""
import sys, time, rerun as rr
url, n = sys.argv[1], int(sys.argv[2])
rec = rr.RecordingStream("chunkstore_test", recording_id="widening")
rec.set_sinks(rr.GrpcSink(url))
for i in range(n):
    rec.set_time("frame", sequence=i)
    rec.log(f"entity/{i}", rr.Scalars(float(i)))   # a new column with every row
    rec.flush()
    time.sleep(0.01)
rec.disconnect()
"""


def refused(*args):
    """`chunkstore serve ARGS` that must exit 2 with one line on stderr; returns it."""
    done = subprocess.run([CHUNKSTORE, "serve", "--addr", "127.0.0.1:0", *args],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 2, (args, done.returncode, done.stderr)
    assert len(done.stderr.splitlines()) == 1, done.stderr
    return done.stderr


def check_what_a_newcomer_broke():
    """Issue 69 with the real clients: a damaged log refuses to start, one server per log,
    an empty server has `chunks`, `SELECT *` while ingest adds columns, a query whose
    client dies is stopped, SIGTERM with a follow reader connected, a recording of static
    data alone."""
    script = os.path.join(WORK, "client.py")
    with open(script, "w") as f:
        f.write(CLIENT)
    # An empty server: `chunks` is there; an unknown table names the tables.
    server = Server()
    assert server.sql("SELECT count(*) AS n FROM chunks")["n"].to_pylist() == [0]
    try:
        server.sql("SELECT * FROM frame")
        raise AssertionError("an unknown table answered")
    except Exception as e:  # noqa: BLE001 - ADBC's error type varies with the driver
        assert "the tables are: chunks" in str(e), e
    # `SELECT *` while a logger adds a column with every row: each statement gets the
    # schema it was planned with.
    script_wide = os.path.join(WORK, "widening.py")
    with open(script_wide, "w") as f:
        f.write(WIDENING_CLIENT)
    logger = subprocess.Popen([sys.executable, script_wide, server.proxy, "400"])
    answered = 0
    while logger.poll() is None:
        try:
            server.sql("SELECT * FROM frame")
            answered += 1
        except Exception as e:  # noqa: BLE001
            assert "not found" in str(e), e  # before the first row only
    assert logger.wait() == 0 and answered >= 5, answered
    # A query whose ADBC client dies is stopped and logged (a four-way cross join runs
    # for hours otherwise), and the server still answers.
    heavy = subprocess.Popen([sys.executable, "-c",
        "import sys, adbc_driver_flightsql.dbapi as f\n"
        "with f.connect(sys.argv[1]) as c, c.cursor() as cur:\n"
        "    cur.execute('SELECT sum(a.frame + b.frame + c.frame + d.frame) "
        "FROM chunks a, chunks b, chunks c, chunks d')\n"
        "    cur.fetchall()\n",
        server.flight], stderr=subprocess.PIPE, text=True)
    time.sleep(3)
    assert heavy.poll() is None, ("the query ended by itself", heavy.communicate()[1][-500:])
    heavy.kill()
    heavy.wait()
    deadline = time.time() + 20
    while "query stopped: its client left" not in server.stderr():
        assert time.time() < deadline, server.stderr()[-500:]
        time.sleep(0.2)
    assert server.sql("SELECT count(*) AS n FROM chunks")["n"][0].as_py() > 0
    server.kill()

    # One server per log; the second names the first's pid.
    log = os.path.join(WORK, "newcomer.rrd")
    first = Server("--persist", log)
    for i in range(3):
        assert subprocess.run([sys.executable, script, first.proxy, f"rec-{i}", "50"]).returncode == 0
    line = refused("--persist", log)
    assert "in use by another server" in line and f"pid {first.proc.pid}" in line, line
    # SIGTERM stops it while `rerun --save --connect` follows it.
    saved = os.path.join(WORK, "followed.rrd")
    follower = subprocess.Popen([RERUN, "--save", saved, "--connect", first.proxy],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(2)
    first.proc.send_signal(signal.SIGTERM)
    assert first.proc.wait(timeout=10) == 0, first.stderr()
    follower.wait(timeout=30)

    # A damaged byte in the middle (the high byte of message 5's length) refuses to start
    # and leaves the log as it is.
    data = bytearray(open(log, "rb").read())
    at = 12
    for _ in range(5):
        at += 16 + int.from_bytes(data[at + 8:at + 16], "little")
    data[at + 15] = 1
    open(log, "wb").write(data)
    line = refused("--persist", log)
    assert f"damaged after byte {at}" in line, line
    assert open(log, "rb").read() == bytes(data)

    # A recording of static data alone answers on any timeline.
    static = os.path.join(WORK, "static.rrd")
    rec = rr.RecordingStream("chunkstore_test", recording_id="static")
    rec.save(static)
    rec.log("config", rr.TextDocument("gain 2.5"), static=True)
    rec.disconnect()
    done = subprocess.run([CHUNKSTORE, static, "latest-at", "frame", "0"],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 0 and "gain 2.5" in done.stdout, (done.stdout, done.stderr)
    print(f"a newcomer's faults: {answered} SELECT * while columns were added, an abandoned query stopped, a damaged log "
          "refused, one server per log, SIGTERM with a follower, static data on any timeline")


def scrape(host):
    """`GET /metrics` as {series: value}."""
    with urllib.request.urlopen(f"http://{host}/metrics", timeout=10) as answer:
        text = answer.read().decode()
    return {line.rsplit(" ", 1)[0]: float(line.rsplit(" ", 1)[1])
            for line in text.splitlines() if line and not line.startswith("#")}


def check_tls_and_metrics():
    """Issue 72: over TLS (`grpc+tls://`, the test CA given to ADBC), a recording Rerun's SDK
    wrote, served from the file, answers as the file does; `rerun --save --connect`
    over `rerun+https://` is not tried (Rerun 0.41's gRPC client trusts only the public
    web roots: a private CA was refused through SSL_CERT_FILE, SSL_CERT_DIR and the
    system store alike). A plain server takes the SDK's logging, and its metrics count
    the rows the SDK sent; gRPC health and the HTTP probe answer."""
    recorded = os.path.join(WORK, "for-tls.rrd")
    rec = rr.RecordingStream("chunkstore_test", recording_id="for-tls")
    rec.save(recorded)
    log_scene(rec)
    rec.disconnect()
    server = Server(recorded, "--tls-cert", os.path.join(TLS_DIR, "server.pem"),
                    "--tls-key", os.path.join(TLS_DIR, "server-key.pem"))
    assert server.proxy.startswith("rerun+https://") and server.flight.startswith("grpc+tls://"), server.proxy
    for table in ["frame", "sim_time"]:
        query = f"SELECT * FROM {table} ORDER BY {table}, rerun_segment_id"
        served = server.sql(query).drop_columns(["rerun_segment_id"])
        same(served, chunkstore_sql(recorded, f"SELECT * FROM {table} ORDER BY {table}"), table)
    # Without the CA, ADBC refuses the server's certificate.
    try:
        with flight_sql.connect(server.flight) as conn, conn.cursor() as cur:
            cur.execute("SELECT 1")
        raise AssertionError("ADBC connected without trusting the test CA")
    except flight_sql.Error:
        pass
    server.proc.send_signal(signal.SIGTERM)
    assert server.proc.wait(timeout=15) == 0, server.stderr()[-2000:]

    server = Server("--metrics-addr", "127.0.0.1:0", "--read-mode", "snapshot")
    metrics = next(line for line in server.stderr().splitlines() if line.startswith("metrics on http://"))
    metrics = metrics.removeprefix("metrics on http://").split("/")[0]
    script = os.path.join(WORK, "log_counted.py")
    with open(script, "w") as f:
        f.write(
            "import sys, rerun as rr\n"
            "rec = rr.RecordingStream('chunkstore_test', recording_id='counted')\n"
            "rec.connect_grpc(sys.argv[1])\n"
            "for i in range(500):\n"
            "    rec.set_time('frame', sequence=i)\n"
            "    rec.log('robot/torque', rr.Scalars(float(i)))\n"
            "rec.disconnect()\n")
    done = subprocess.run([sys.executable, script, server.proxy], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-2000:]
    assert server.sql("SELECT count(*) AS n FROM frame")["n"][0].as_py() == 500
    scraped = scrape(metrics)
    counted = scraped['chunkstore_ingested_rows_total{recording="counted"}']
    # Every row the SDK sent: the 500 scalars and its recording's properties.
    held = server.sql("SELECT rows FROM recordings")["rows"].to_pylist()
    assert held == [counted] and counted > 500, (held, scraped)
    assert scraped["chunkstore_recordings"] == 1, scraped
    assert scraped["chunkstore_query_seconds_count"] >= 1, scraped
    with urllib.request.urlopen(f"http://{metrics}/health", timeout=10) as answer:
        assert answer.status == 200 and answer.read() == b"serving\n"
    # pyarrow's own Flight client drops the recording (docs/SERVER.md's example).
    import pyarrow.flight as fl
    client = fl.connect(server.flight)
    said = [r.body.to_pybytes() for r in client.do_action(fl.Action("chunkstore.drop_recording", b"counted"))]
    assert b'dropped recording "counted"' in said[0], said
    assert server.sql("SELECT count(*) AS n FROM recordings")["n"].to_pylist() == [0]
    server.proc.send_signal(signal.SIGTERM)
    assert server.proc.wait(timeout=15) == 0, server.stderr()[-2000:]
    print(f"TLS: ADBC over grpc+tls answered as the file for 2 tables and refused the server without "
          f"the CA; metrics counted {counted:.0f} rows the SDK logged; pyarrow.flight dropped the recording")


if __name__ == "__main__":
    try:
        check_tls_and_metrics()
        check_tee_equals_server()
        check_many_writers_and_readers()
        check_kill_during_ingest()
        check_what_a_newcomer_broke()
    finally:
        for server in SERVERS:
            if server.proc.poll() is None:
                server.kill()
        shutil.rmtree(WORK, ignore_errors=True)
