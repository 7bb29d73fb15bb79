"""Peak memory of SQL over a dataset of image recordings under `--memory-budget` (issue 69, item 9).

    HOME=$(mktemp -d) python benches/dataset_memory.py target/release/chunkstore [BUDGET] [DIR]

Writes (once, into DIR, default /tmp/chunkstore-image-dataset) 24 recordings with Rerun's SDK,
each 40 images of 640x480x3 random bytes (0.9 MB) on the `frame` timeline, about 880 MB in
all. Then runs, each as its own process under `--memory-budget BUDGET` (default 64MiB):
`SELECT count(*)`, a count of one column's non-null cells, and `SELECT *` written to Parquet,
and prints each one's peak RSS (the child's ru_maxrss) beside the budget. Needs Rerun's SDK
(`pip install rerun-sdk==0.41.0`).
"""

import os
import resource
import subprocess
import sys
import tempfile
import time

CHUNKSTORE = os.path.abspath(sys.argv[1])
BUDGET = sys.argv[2] if len(sys.argv) > 2 else "64MiB"
DATASET = sys.argv[3] if len(sys.argv) > 3 else "/tmp/chunkstore-image-dataset"
RECORDINGS = 24
FRAMES = 40

WRITER = r"""
import sys, numpy as np, rerun as rr
path, rec, frames = sys.argv[1], sys.argv[2], int(sys.argv[3])
rr.init("images", recording_id=rec)
rr.save(path)
rng = np.random.default_rng(int(rec.split("-")[-1]))
for f in range(frames):
    rr.set_time("frame", sequence=f)
    rr.log("camera/image", rr.Image(rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)))
rr.disconnect()
"""


def write_dataset():
    done = os.path.join(DATASET, ".complete")
    if os.path.exists(done):
        return
    os.makedirs(DATASET, exist_ok=True)
    script = os.path.join(DATASET, "..", "chunkstore-image-writer.py")
    with open(script, "w") as f:
        f.write(WRITER)
    for i in range(RECORDINGS):
        path = os.path.join(DATASET, f"episode-{i:02}.rrd")
        subprocess.run([sys.executable, script, path, f"episode-{i:02}", str(FRAMES)], check=True)
    open(done, "w").close()


def measured(label, args):
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    start = time.time()
    run = subprocess.run([CHUNKSTORE, "--memory-budget", BUDGET, DATASET, *args],
                         capture_output=True, text=True)
    seconds = time.time() - start
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    if run.returncode != 0:
        sys.exit(f"{label}: exit {run.returncode}: {run.stderr.strip()}")
    # ru_maxrss of RUSAGE_CHILDREN is the largest child so far: measure the larger runs last.
    note = "" if peak > before else " (not above an earlier run's peak)"
    print(f"{label}: {seconds:.1f} s, peak RSS {peak / 1024:.0f} MiB under --memory-budget "
          f"{BUDGET}{note}{answer(run.stdout)}")


def answer(stdout):
    """A printed table's one value, if it has one."""
    cells = [line.strip("| ") for line in stdout.splitlines() if line.startswith("|")]
    return f"; answer {cells[-1]}" if len(cells) == 2 else ""


def main():
    write_dataset()
    size = sum(os.path.getsize(os.path.join(DATASET, f)) for f in os.listdir(DATASET) if f.endswith(".rrd"))
    print(f"dataset: {RECORDINGS} recordings, {size / 2**20:.0f} MiB")
    measured("count(*)", ["sql", "SELECT count(*) FROM frame", "--full"])
    measured("count(image)", ["sql", 'SELECT count("/camera/image:Image:buffer") FROM frame', "--full"])
    out = os.path.join(tempfile.mkdtemp(prefix="chunkstore-dataset-memory-"), "all.parquet")
    measured("SELECT * to Parquet", ["sql", "SELECT * FROM frame", "--out", out])
    print(f"  Parquet output {os.path.getsize(out) / 2**20:.0f} MiB")


main()
