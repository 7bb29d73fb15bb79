"""Small recordings written by Rerun 0.41's SDK for the identity and export tests
(issue 32): run with `rerun-sdk==0.41.0` installed, from this directory.

- `blueprint_first.rrd`: `RecordingStream.save(path, default_blueprint=...)`, which writes
  the blueprint's store (its store info and chunks) before the recording's.
- `out_of_order.rrd`: rows logged at frames 2, then 1, then 3 (row ids follow the logging
  order, not time), on `/plot/a`, plus a static `/meta` value.
Both have fixed recording ids, so tests can concatenate them (`cat a.rrd b.rrd`).
"""

import rerun as rr
import rerun.blueprint as rrb

rec = rr.RecordingStream("chunkstore_identity", recording_id="blueprint-first-rec")
rec.save(
    "blueprint_first.rrd",
    default_blueprint=rrb.Blueprint(rrb.TimeSeriesView(origin="/plot")),
)
for frame in range(5):
    rec.set_time("frame", sequence=frame)
    rec.log("/plot/a", rr.Scalars(float(frame)))
rec.flush()
rec.disconnect()

rec = rr.RecordingStream("chunkstore_identity", recording_id="out-of-order-rec")
rec.save("out_of_order.rrd")
rec.log("/meta", rr.TextDocument("static note"), static=True)
for frame in [2, 1, 3]:
    rec.set_time("frame", sequence=frame)
    rec.log("/plot/a", rr.Scalars(float(frame * 10)))
rec.flush()
rec.disconnect()
