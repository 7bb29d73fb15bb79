"""A dataset in an S3 bucket against the same dataset on local disk (issue 71's targets).

    python benches/storage_dataset.py DIR ENDPOINT [RUNS] [--no-download]

DIR is a dataset directory (`cargo run --release --example dataset_bench -- generate DIR
1000 10`), ENDPOINT an S3 server (`scripts/s3_test_server.sh start target/s3-venv /tmp/s3`;
keys `key`/`secret`). Needs boto3 (to upload and to download). Uploads DIR to
`s3://bench/<dir name>/` once, then runs `dataset_bench open` and `range` (release build,
feature `object-store`, each a process) RUNS times (default 3) each way:

- `local`: the directory;
- `bucket`: the prefix, through ranged GETs;
- `bucket +20ms`: the prefix, with 20 ms added to every request (`chunkstore_added_latency_ms`);
- `download`: the prefix downloaded (16 objects at a time), then the local run; its
  time includes the download (once: it needs the dataset's size again on disk).

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

import boto3

BENCH = "target/release/examples/dataset_bench"


def s3(endpoint):
    return boto3.client(
        "s3",
        endpoint_url=endpoint,
        aws_access_key_id="key",
        aws_secret_access_key="secret",
        region_name="us-east-1",
    )


def upload(client, directory, prefix):
    names = sorted(n for n in os.listdir(directory) if n.endswith(".rrd"))
    listed = client.list_objects_v2(Bucket="bench", Prefix=prefix + "/", MaxKeys=2000).get("KeyCount", 0)
    if listed >= len(names):
        return
    with concurrent.futures.ThreadPoolExecutor(16) as pool:
        list(pool.map(lambda n: client.upload_file(os.path.join(directory, n), "bench", f"{prefix}/{n}"), names))


def download(client, prefix, into):
    keys = []
    for page in client.get_paginator("list_objects_v2").paginate(Bucket="bench", Prefix=prefix + "/", Delimiter="/"):
        keys += [o["Key"] for o in page.get("Contents", [])]
    with concurrent.futures.ThreadPoolExecutor(16) as pool:
        list(pool.map(lambda k: client.download_file("bench", k, os.path.join(into, os.path.basename(k))), keys))


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
    prefix = os.path.basename(os.path.normpath(directory))
    upload(client, directory, prefix)
    url = f"s3://bench/{prefix}/"
    base = dict(os.environ, AWS_ENDPOINT_URL=endpoint, AWS_ALLOW_HTTP="true", AWS_ACCESS_KEY_ID="key", AWS_SECRET_ACCESS_KEY="secret", AWS_REGION="us-east-1")
    slow = dict(base, STORAGE_OPTIONS="chunkstore_added_latency_ms=20")
    results = {}
    for run_number in range(runs):
        for name, source, env in [("local", directory, base), ("bucket", url, base), ("bucket +20ms", url, slow)]:
            for step in ["open", "range"]:
                line = run(step, source, env)
                line["way"] = name
                print(json.dumps(line), flush=True)
                results.setdefault((name, step), []).append(line)
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
    for (name, step), lines in results.items():
        keys = ["seconds", "open_seconds", "gets", "lists", "bytes_fetched", "bytes_read", "peak_rss"]
        median = {k: statistics.median(l[k] for l in lines) for k in keys if all(k in l for l in lines)}
        print(json.dumps({"median": f"{name} {step}", **median}))


if __name__ == "__main__":
    main()
