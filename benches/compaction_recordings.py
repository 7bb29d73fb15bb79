"""Writes the two recordings `docs/PERFORMANCE.md` measures on-demand compaction with,
using Rerun's own SDK (`send_columns`), so the chunks are as a real logger makes them.

    python benches/compaction_recordings.py OUT_DIR

`OUT_DIR/split.rrd`: 50 scalar entities of 3,000 rows in three 1,000-row chunks (every
other entity's rows shuffled within their chunks), and 50 point-cloud chunks of 20 rows
of 50 points. Under tiny thresholds (`--max-rows 3 --max-rows-unsorted 2 --max-bytes
4096`) a load splits every chunk into pieces that are already compact.

`OUT_DIR/ooo.rrd`: the same rows, but each scalar entity's three chunks take every third
time (chunk k holds times k, k + 3, k + 6, ...), so every chunk spans all of its entity's
times and `compact()` must move every row.
"""

import random
import sys
from pathlib import Path

import numpy as np
import rerun as rr

ENTITIES = 50
ROWS = 3_000
CHUNK_ROWS = 1_000
CLOUDS = 50
CLOUD_ROWS = 20
POINTS = 50


def write(path: Path, interleaved: bool) -> None:
    rng = random.Random(7)
    rec = rr.RecordingStream("rerun_example_compaction", recording_id=path.stem)
    rec.save(str(path))
    for e in range(ENTITIES):
        for k in range(ROWS // CHUNK_ROWS):
            if interleaved:
                times = list(range(k, ROWS, ROWS // CHUNK_ROWS))
            else:
                times = list(range(k * CHUNK_ROWS, (k + 1) * CHUNK_ROWS))
            if e % 2 == 1:
                rng.shuffle(times)
            frames = np.array(times, dtype=np.int64)
            rec.send_columns(
                f"scalars/s{e}",
                indexes=[rr.TimeColumn("frame", sequence=frames)],
                columns=rr.Scalars.columns(scalars=np.sin(frames / 50.0) + e),
            )
    for c in range(CLOUDS):
        frames = np.arange(CLOUD_ROWS, dtype=np.int64) + c * CLOUD_ROWS
        positions = np.array(
            [[rng.random(), rng.random(), rng.random()] for _ in range(CLOUD_ROWS * POINTS)],
            dtype=np.float32,
        )
        rec.send_columns(
            f"clouds/c{c % 10}",
            indexes=[rr.TimeColumn("frame", sequence=frames)],
            columns=rr.Points3D.columns(positions=positions).partition([POINTS] * CLOUD_ROWS),
        )
    rec.flush()


def main() -> None:
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    write(out / "split.rrd", interleaved=False)
    write(out / "ooo.rrd", interleaved=True)


if __name__ == "__main__":
    main()
