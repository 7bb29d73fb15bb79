"""Outputs to a bucket, interrupted (issue 71): the S3 test server (``CHUNKSTORE_TEST_S3``)
is asked with S3's own API (boto3) what an interrupted upload left.

- ``chunkstore REC.rrd convert s3://.../big.rrd`` of a 40 MB recording (a multipart upload
  of three 16 MiB parts), each request slowed by 300 ms so that the signal lands while
  parts are in flight: on SIGINT (Ctrl-C) and on SIGTERM the tool exits 130 with one
  line, no object is at the key, and ListMultipartUploads lists no upload under it (the
  upload was aborted, its parts deleted).
- ``hive s3://... --delta`` interrupted the same way while its files upload: nothing is
  committed and no object is left under the table's prefix.

Usage: python tests/clients/storage_faults.py path/to/chunkstore   (CHUNKSTORE_TEST_S3 set;
without it, outside CI, it says so and passes)
"""

import os
import signal
import subprocess
import sys
import tempfile
import time

from s3_env import s3_client, s3_endpoint, tool_env

BUCKET = "chunkstore-test"


def big_recording(path):
    """A recording of 40 random 1 MB images (random bytes do not compress): ~40 MB."""
    import numpy as np
    import rerun as rr

    rng = np.random.default_rng(3)
    rec = rr.RecordingStream("rerun_example_big", recording_id="big")
    rec.save(path)
    for frame in range(40):
        rec.set_time("frame", sequence=frame)
        rec.log("camera", rr.Image(rng.integers(0, 255, (512, 683, 3), dtype=np.uint8)))
    rec.flush()
    del rec


def uploads_under(s3, prefix):
    """The incomplete multipart uploads under `prefix`."""
    listed = s3.list_multipart_uploads(Bucket=BUCKET, Prefix=prefix)
    return [u["Key"] for u in listed.get("Uploads", [])]


def objects_under(s3, prefix):
    listed = s3.list_objects_v2(Bucket=BUCKET, Prefix=prefix)
    return [o["Key"] for o in listed.get("Contents", [])]


def interrupt_when(s3, process, ready, sig, timeout=60):
    """Sends `sig` to `process` once `ready()` holds (polled), then waits for its exit."""
    deadline = time.monotonic() + timeout
    while not ready():
        assert process.poll() is None, f"it ended before the signal: {process.communicate()}"
        assert time.monotonic() < deadline, "the upload never started"
        time.sleep(0.02)
    process.send_signal(sig)
    _, stderr = process.communicate(timeout=timeout)
    return process.returncode, stderr


def main():
    binary = os.path.abspath(sys.argv[1])
    endpoint = s3_endpoint("interrupted outputs to a bucket")
    if not endpoint:
        return
    env = tool_env(endpoint)
    s3 = s3_client(endpoint)
    slow = ["--storage-option", "chunkstore_added_latency_ms=300"]
    run = f"faults-{os.getpid()}-{int(time.time())}"
    with tempfile.TemporaryDirectory() as scratch:
        os.environ["HOME"] = scratch  # Rerun writes its settings under HOME
        source = os.path.join(scratch, "big.rrd")
        big_recording(source)
        assert os.path.getsize(source) > 32 << 20, os.path.getsize(source)
        for sig in (signal.SIGINT, signal.SIGTERM):
            key = f"{run}/{sig.name}/big.rrd"
            process = subprocess.Popen(
                [binary, *slow, source, "convert", f"s3://{BUCKET}/{key}"],
                env=env,
                stderr=subprocess.PIPE,
                text=True,
            )
            code, stderr = interrupt_when(s3, process, lambda: uploads_under(s3, key), sig)
            assert code == 130, (sig, code, stderr)
            assert stderr.count("\n") == 1 and "interrupted" in stderr, stderr
            assert uploads_under(s3, key) == [], f"{sig.name}: an upload was left"
            assert objects_under(s3, key) == [], f"{sig.name}: an object was left"
            print(f"convert to a bucket, {sig.name} mid-upload: exit 130, no object, no upload left")

        # A Delta table's write: interrupted once its first file is in the bucket.
        dataset = os.path.join(scratch, "dataset")
        os.makedirs(dataset)
        os.symlink(source, os.path.join(dataset, "big.rrd"))
        table = f"{run}/table/"
        process = subprocess.Popen(
            [binary, *slow, dataset, "hive", f"s3://{BUCKET}/{table}", "--delta"],
            env=env,
            stderr=subprocess.PIPE,
            text=True,
        )
        code, stderr = interrupt_when(
            s3, process, lambda: objects_under(s3, table) or uploads_under(s3, table), signal.SIGINT
        )
        assert code == 130, (code, stderr)
        assert stderr.count("\n") == 1 and "nothing was committed" in stderr, stderr
        assert objects_under(s3, table) == [], objects_under(s3, table)
        assert uploads_under(s3, table) == []
        print("hive --delta to a bucket, SIGINT mid-upload: exit 130, nothing committed or left")


if __name__ == "__main__":
    main()
