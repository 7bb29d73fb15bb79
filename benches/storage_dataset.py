"""A dataset in an S3 bucket against the same dataset on local disk (issue 71's targets).

    python benches/storage_dataset.py DIR ENDPOINT [RUNS] [--no-download] [--part-mib=N]

DIR is a dataset directory (`cargo run --release --example dataset_bench -- generate DIR
1000 10`), ENDPOINT an S3 server (`scripts/s3_test_server.sh start target/s3-venv /tmp/s3`;
keys `key`/`secret`). Needs boto3 (to upload and to download). Uploads DIR to
`s3://bench/<dir name>/` once, then runs `dataset_bench open` and `range` (each a process;
`cargo build --release --example dataset_bench --features object-store,parquet`) RUNS
times (default 3) each way:

- `local`: the directory;
- `bucket`: the prefix, through ranged GETs;
- `bucket +20ms`: the prefix, with 20 ms added to every request (`chunkstore_added_latency_ms`);
- `download`: the prefix downloaded (16 objects at a time), then the local run; its
  time includes the download (once: it needs the dataset's size again on disk);
- `duckdb delta`: DuckDB 1.5.5 (httpfs and delta from PyPI) answering the same question
  (rows and sum of `/robot/sensor0:scalar` on the same 1% of `frame`) with `delta_scan` on
  a Delta table of the dataset's telemetry (every sensor's scalar, not the point clouds;
  a partition per segment and per tenth of `frame`, each file's `frame` range in its
  `add` stats) in the same bucket, which
  `dataset_bench delta` writes once (its time, requests and bytes printed). Its requests
  and bytes are counted by a proxy between DuckDB and the server, in one more run.

`--part-mib=N` uploads each object in parts of N MiB (default 8, boto3's own) to
`s3://bench/<dir name>-<N>mib-parts/`. SeaweedFS stores an object in pieces of its
upload's parts and reads a whole piece for any ranged GET in it: on an object never read
before, a GET of 1 KiB costs it about 4 ms of CPU with 8 MiB parts and 1.5 ms with 1 MiB
parts, whatever the range's length (a server's own cost, which S3 does not charge per
part; `docs/performance-log.md`, 2026-12-07).

Prints one JSON line per run and, at the end, the medians.
"""

import concurrent.futures
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import http.client
import http.server
import threading

import boto3
from boto3.s3.transfer import TransferConfig

BENCH = "target/release/examples/dataset_bench"


def s3(endpoint):
    return boto3.client(
        "s3",
        endpoint_url=endpoint,
        aws_access_key_id="key",
        aws_secret_access_key="secret",
        region_name="us-east-1",
    )


def upload(client, directory, prefix, part_mib):
    names = sorted(n for n in os.listdir(directory) if n.endswith(".rrd"))
    listed = client.list_objects_v2(Bucket="bench", Prefix=prefix + "/", MaxKeys=2000).get("KeyCount", 0)
    if listed >= len(names):
        return
    parts = TransferConfig(multipart_threshold=part_mib << 20, multipart_chunksize=part_mib << 20)
    with concurrent.futures.ThreadPoolExecutor(16) as pool:
        list(pool.map(lambda n: client.upload_file(os.path.join(directory, n), "bench", f"{prefix}/{n}", Config=parts), names))


def download(client, prefix, into):
    keys = []
    for page in client.get_paginator("list_objects_v2").paginate(Bucket="bench", Prefix=prefix + "/", Delimiter="/"):
        keys += [o["Key"] for o in page.get("Contents", [])]
    with concurrent.futures.ThreadPoolExecutor(16) as pool:
        list(pool.map(lambda k: client.download_file("bench", k, os.path.join(into, os.path.basename(k))), keys))


class CountingProxy(http.server.ThreadingHTTPServer):
    """Forwards every request to `target` (host:port) as it came (its Host header too, which
    the signature covers), counting requests and response bytes."""

    def __init__(self, target):
        self.target, self.requests, self.bytes, self.lock = target, 0, 0, threading.Lock()
        super().__init__(("127.0.0.1", 0), ProxyHandler)


class ProxyHandler(http.server.BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"

    def log_message(self, *args):
        pass

    def forward(self):
        length = int(self.headers.get("Content-Length", 0))
        body = self.rfile.read(length) if length else None
        upstream = http.client.HTTPConnection(self.server.target)
        upstream.putrequest(self.command, self.path, skip_host=True, skip_accept_encoding=True)
        for key, value in self.headers.items():
            upstream.putheader(key, value)
        upstream.endheaders(body)
        response = upstream.getresponse()
        data = response.read()
        with self.server.lock:
            self.server.requests += 1
            self.server.bytes += len(data)
        self.send_response_only(response.status, response.reason)
        for key, value in response.getheaders():
            if key.lower() not in ("transfer-encoding", "connection"):
                self.send_header(key, value)
        if response.getheader("Content-Length") is None and self.command != "HEAD":
            self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(data)
        upstream.close()

    do_GET = do_HEAD = do_PUT = do_POST = do_DELETE = forward


def duckdb_run(endpoint, table, frames):
    """DuckDB's answer to the range question over the Delta table, timed from a fresh
    connection (so its reading of the log counts, as our open does)."""
    import duckdb
    import duckdb_extension_delta
    import duckdb_extension_httpfs

    started = time.time()
    con = duckdb.connect()
    for package in (duckdb_extension_httpfs, duckdb_extension_delta):
        folder = os.path.join(os.path.dirname(package.__file__), "extensions", f"v{duckdb.__version__}")
        con.execute(f"LOAD '{os.path.join(folder, os.listdir(folder)[0])}'")
    con.execute(
        f"CREATE SECRET (TYPE s3, KEY_ID 'key', SECRET 'secret', ENDPOINT '{endpoint.split('://')[1]}', "
        "URL_STYLE 'path', USE_SSL false, REGION 'us-east-1')"
    )
    lo, hi = frames
    rows, total = con.execute(
        f"SELECT count(*), sum(list_sum(\"/robot/sensor0:scalar\")) FROM delta_scan('{table}') "
        f"WHERE frame BETWEEN {lo} AND {hi} AND \"/robot/sensor0:scalar\" IS NOT NULL"
    ).fetchone()
    return {"way": "duckdb delta", "rows": rows, "sum": round(total or 0.0, 3), "seconds": round(time.time() - started, 3)}


def run(step, source, env):
    out = subprocess.run([BENCH, step, source] + (["256"] if step == "range" else []), env=env, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    directory, endpoint = sys.argv[1], sys.argv[2]
    runs = int(sys.argv[3]) if len(sys.argv) > 3 and sys.argv[3].isdigit() else 3
    client = s3(endpoint)
    try:
        client.create_bucket(Bucket="bench")
    except Exception:
        pass
    name = os.path.basename(os.path.normpath(directory))
    part_mib = next((int(a.split("=")[1]) for a in sys.argv if a.startswith("--part-mib=")), 8)
    prefix = name if part_mib == 8 else f"{name}-{part_mib}mib-parts"
    upload(client, directory, prefix, part_mib)
    url = f"s3://bench/{prefix}/"
    base = dict(os.environ, AWS_ENDPOINT_URL=endpoint, AWS_ALLOW_HTTP="true", AWS_ACCESS_KEY_ID="key", AWS_SECRET_ACCESS_KEY="secret", AWS_REGION="us-east-1")
    slow = dict(base, STORAGE_OPTIONS="chunkstore_added_latency_ms=20")
    explicit = dict(base, STORAGE_OPTIONS=f"aws_endpoint={endpoint},aws_allow_http=true")
    table = f"s3://bench/{name}_telemetry_by_tenth"
    if client.list_objects_v2(Bucket="bench", Prefix=f"{name}_telemetry_by_tenth/_delta_log/").get("KeyCount", 0) == 0:
        made = subprocess.run([BENCH, "delta", directory, table + "/"], env=explicit, check=True, capture_output=True, text=True)
        print(made.stdout.strip(), flush=True)
    results = {}
    for run_number in range(runs):
        for name, source, env in [("local", directory, base), ("bucket", url, base), ("bucket +20ms", url, slow)]:
            for step in ["open", "range"]:
                line = run(step, source, env)
                line["way"] = name
                print(json.dumps(line), flush=True)
                results.setdefault((name, step), []).append(line)
        frames = results[("bucket", "range")][-1]["range"]
        line = duckdb_run(endpoint, table, frames)
        print(json.dumps(line), flush=True)
        results.setdefault(("duckdb delta", "range"), []).append(line)
        if run_number > 0 or "--no-download" in sys.argv:
            continue
        scratch = tempfile.mkdtemp(prefix="storage-bench-")
        try:
            started = time.time()
            download(client, prefix, scratch)
            fetched = time.time() - started
            line = run("range", scratch, base)
            line["way"] = "download"
            line["download_seconds"] = round(fetched, 3)
            line["seconds"] = round(fetched + line["open_seconds"] + line["seconds"], 3)
            print(json.dumps(line), flush=True)
            results.setdefault(("download", "range"), []).append(line)
        finally:
            shutil.rmtree(scratch)
    # DuckDB's requests and bytes, through the counting proxy (one more run, not timed).
    proxy = CountingProxy(endpoint.split("://")[1])
    threading.Thread(target=proxy.serve_forever, daemon=True).start()
    counted = duckdb_run(f"http://127.0.0.1:{proxy.server_address[1]}", table, frames)
    proxy.shutdown()
    print(json.dumps({"way": "duckdb delta (counted)", "rows": counted["rows"], "requests": proxy.requests, "bytes_fetched": proxy.bytes}))
    for (name, step), lines in results.items():
        keys = ["seconds", "open_seconds", "gets", "lists", "bytes_fetched", "bytes_read", "peak_rss"]
        median = {k: statistics.median(l[k] for l in lines) for k in keys if all(k in l for l in lines)}
        print(json.dumps({"median": f"{name} {step}", **median}))


if __name__ == "__main__":
    main()
