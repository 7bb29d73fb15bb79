"""Peak memory of `chunkstore serve --memory-limit` under image loggers (issue 69, item 9).

    HOME=$(mktemp -d) python benches/server_memory.py target/release/chunkstore [LIMIT]

Starts the server with `--memory-limit LIMIT --persist` (default 64MiB), then two Rerun SDK
processes at once, each logging 300 images of 640x480x3 bytes (0.9 MB), then one process
sending a single 400 MiB image. Prints the server's peak RSS (VmHWM) after each phase and
what the big message got. Needs Rerun's SDK (`pip install rerun-sdk==0.41.0`).
"""

import os
import subprocess
import sys
import tempfile
import time

CHUNKSTORE = os.path.abspath(sys.argv[1])
LIMIT = sys.argv[2] if len(sys.argv) > 2 else "64MiB"
WORK = tempfile.mkdtemp(prefix="chunkstore-server-memory-")

LOGGER = r"""
import sys, numpy as np, rerun as rr
url, rec, frames, side = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
rr.init("memory", recording_id=rec)
rr.connect_grpc(url)
rng = np.random.default_rng(int(rec[-1]) if rec[-1].isdigit() else 0)
for f in range(frames):
    rr.set_time("frame", sequence=f)
    rr.log("camera/image", rr.Image(rng.integers(0, 255, (side, side * 4 // 3, 3), dtype=np.uint8)))
rr.disconnect()
"""


def peak_kib(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    return 0


def main():
    log = os.path.join(WORK, "live.rrd")
    err = open(os.path.join(WORK, "server.err"), "w")
    server = subprocess.Popen(
        [CHUNKSTORE, "serve", "--addr", "127.0.0.1:0", "--memory-limit", LIMIT, "--persist", log],
        stdout=subprocess.PIPE, stderr=err, text=True)
    url = server.stdout.readline().strip().removeprefix("listening on ")
    script = os.path.join(WORK, "logger.py")
    with open(script, "w") as f:
        f.write(LOGGER)
    start = time.time()
    loggers = [subprocess.Popen([sys.executable, script, url, f"camera-{i}", "300", "480"]) for i in range(2)]
    for p in loggers:
        p.wait()
    time.sleep(1.5)
    print(f"two image loggers ({time.time() - start:.1f} s): peak RSS {peak_kib(server.pid) / 1024:.0f} MiB "
          f"under --memory-limit {LIMIT}; log {os.path.getsize(log) / 2**20:.0f} MiB")
    # One 400 MB image: 10,000 x 13,333 x 3 bytes.
    big = subprocess.run([sys.executable, script, url, "big-0", "1", "10000"], capture_output=True, text=True)
    time.sleep(1.5)
    print(f"one 400 MB message: peak RSS {peak_kib(server.pid) / 1024:.0f} MiB; the SDK "
          f"exited {big.returncode}; the server said: "
          + " | ".join(l for l in open(os.path.join(WORK, "server.err")).read().splitlines() if "big" in l or "message" in l)[-300:])
    server.kill()
    server.wait()


main()
