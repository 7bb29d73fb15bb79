//! The Python package's read benchmark, Rust side: the same recording, the same three
//! steps as `python/bench/read_bench.py`, so the two can be compared (the Python layer's
//! cost) and set beside Rerun's own Python reader.
//!
//! ```text
//! cargo run --release --example read_bench -- generate /tmp/r1m.rrd 100 10000   # entities, times
//! cargo run --release --example read_bench -- measure /tmp/r1m.rrd
//! ```
//!
//! The recording is the dataframe workload's (`benches/common`: `/fleet/g<k>/r<e>`, each
//! row a scalar, a 3D point and a text on the `frame` timeline, chunks of 1,000 rows), so
//! rows = entities × times. `measure` prints one JSON line: seconds to open it (every
//! chunk into a store), to read one entity's scalar series whole (`range`), to stream the
//! whole dataframe on `frame` (every batch read, then dropped) and to collect it (every
//! batch kept, as Python's `read_all()` does), and the peak RSS (`VmHWM`).

#![allow(
    clippy::expect_used,
    clippy::cast_precision_loss,
    reason = "a benchmark: generated data is valid; a failure should stop it loudly"
)]

#[path = "../benches/common/mod.rs"]
mod common;

use std::time::Instant;

use chunkstore::rrd::{RrdItem, RrdReader, StoreId, StoreInfo};
use chunkstore::{ChunkStore, DataframeQuery, EntityPath, RangeQuery};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args
        .iter()
        .map(String::as_str)
        .collect::<Vec<_>>()
        .as_slice()
    {
        ["generate", path, entities, times] => {
            let chunks = common::dataframe_chunks(
                entities.parse().expect("entities"),
                times.parse().expect("times"),
                1_000,
            );
            let info = StoreInfo::new(StoreId::recording("read_bench", "generated"));
            let size = chunkstore::rrd::write_rrd_file(path.as_ref(), &info, chunks, |_| {})
                .expect("a writable path");
            println!("{{\"path\": {path:?}, \"bytes\": {size}}}");
        }
        ["measure", path] => measure(path),
        _ => {
            eprintln!("usage: read_bench generate PATH ENTITIES TIMES | read_bench measure PATH");
            std::process::exit(2);
        }
    }
}

fn measure(path: &str) {
    let start = Instant::now();
    let file = std::fs::File::open(path).expect("the recording");
    let mut store = ChunkStore::new();
    for item in RrdReader::new(std::io::BufReader::with_capacity(1 << 20, file)).expect("an rrd") {
        if let RrdItem::Chunk { chunk, .. } = item.expect("a valid message") {
            store.insert(chunk).expect("a valid chunk");
        }
    }
    let open_s = start.elapsed().as_secs_f64();

    // Each query step: the median of RUNS (default 5) runs, as the Python side does.
    let runs: usize = std::env::var("RUNS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(5);
    let median = |step: &mut dyn FnMut()| {
        let mut times: Vec<f64> = (0..runs.max(1))
            .map(|_| {
                let start = Instant::now();
                step();
                start.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(f64::total_cmp);
        times[times.len() / 2]
    };

    // `BATCH_ROWS` overrides the dataframe's default batch size.
    let query = match std::env::var("BATCH_ROWS")
        .ok()
        .and_then(|r| r.parse().ok())
    {
        Some(rows) => DataframeQuery::new(common::FRAME).with_batch_rows(rows),
        None => DataframeQuery::new(common::FRAME),
    };

    let entity = EntityPath::parse("/fleet/g0/r0").expect("a path");
    // `ONLY_COLLECT=1` runs the collecting step alone (instruction counts of it: the
    // difference between two values of RUNS, under `perf stat -e instructions:u`).
    let only_collect = std::env::var_os("ONLY_COLLECT").is_some();
    let mut series_rows = 0;
    let mut range_s = 0.0;
    let mut counts = (0, 0, 0);
    let mut dataframe_s = 0.0;
    if !only_collect {
        range_s = median(&mut || {
            let series = store.range(
                &RangeQuery::everything(common::FRAME),
                &entity,
                common::SCALAR,
            );
            series_rows = series.num_rows();
        });

        dataframe_s = median(&mut || {
            counts = common::stream_dataframe(&store, &query);
        });
    }
    let (rows, columns, non_null) = counts;

    // What Python's `read_all()` does: every batch kept, none looked at.
    let collect_s = median(&mut || {
        let batches: Vec<_> = store
            .dataframe(&query)
            .expect("a known index")
            .collect::<Result<_, _>>()
            .expect("batches");
        let kept_rows: usize = batches.iter().map(arrow_array::RecordBatch::num_rows).sum();
        assert!(only_collect || kept_rows as u64 == rows);
    });

    let peak = std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmHWM:"))
                .and_then(|v| v.trim().trim_end_matches(" kB").trim().parse::<u64>().ok())
        })
        .unwrap_or(0);
    println!(
        "{{\"engine\": \"chunkstore (Rust)\", \"rows_stored\": {}, \"open_s\": {open_s:.4}, \
         \"range_s\": {range_s:.6}, \"range_rows\": {series_rows}, \"dataframe_s\": {dataframe_s:.4}, \"dataframe_collect_s\": {collect_s:.4}, \
         \"dataframe_rows\": {rows}, \"dataframe_columns\": {columns}, \"non_null_cells\": {non_null}, \
         \"peak_rss_mib\": {:.1}}}",
        store.stats().num_rows(),
        peak as f64 / 1024.0
    );
}
