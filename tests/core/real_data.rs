//! Chunks written by Rerun 0.41's own SDK, and Rerun's own answers for them
//! (`testdata/rerun-0.41/README.md`): every latest-at probe and every range of the oracle,
//! on all three timelines, must match cell by cell, whether the recording is loaded from
//! its chunk files or from its `.rrd`.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::float_cmp,
    reason = "tests fail loudly on unexpected values; test values are small integers, exact in f64"
)]

use std::collections::{BTreeMap, BTreeSet};

use arrow_array::{Array, ArrayRef, ListArray, RecordBatch};
use chunkstore::{
    Chunk, ChunkStore, EntityPath, LatestAtQuery, RangeQuery, TimeInt, TimeRange, ipc,
};

const TIMELINES: [&str; 3] = ["frame_id", "sim_time", "log_time"];
const PROPERTIES: &str = "/__properties";

use crate::common;
use common::robot_recording as recording;

fn load_chunks() -> Vec<Chunk> {
    assert_eq!(
        common::robot_chunk_files().len(),
        37,
        "the recording has 37 chunk files"
    );
    common::robot_chunks()
}

fn load_store() -> ChunkStore {
    let mut store = ChunkStore::new();
    for chunk in load_chunks() {
        store.insert(chunk).unwrap();
        store.sanity_check().unwrap();
    }
    store
}

/// The recording loaded from its chunk files, and from the `.rrd` Rerun wrote.
fn stores() -> [ChunkStore; 2] {
    let bytes = std::fs::read(recording().join("a_robot.rrd")).unwrap();
    let contents = chunkstore::rrd::read_rrd(arrow_buffer::Buffer::from_vec(bytes), false).unwrap();
    let mut from_rrd = ChunkStore::new();
    for (_, chunk) in contents.chunks {
        from_rrd.insert(chunk).unwrap();
    }
    from_rrd.sanity_check().unwrap();
    [load_store(), from_rrd]
}

fn oracle(name: &str) -> Vec<RecordBatch> {
    let bytes = std::fs::read(recording().join("oracle").join(name)).unwrap();
    ipc::read_batches(&bytes).unwrap()
}

/// A data column of an oracle table: its entity and component, from the field metadata.
struct OracleColumn {
    entity: EntityPath,
    component: String,
    cells: ListArray,
}

/// Splits a table into its index column (the timeline's values) and its data columns.
fn split_table(batch: &RecordBatch, timeline: Option<&str>) -> (Vec<i64>, Vec<OracleColumn>) {
    let mut times = Vec::new();
    let mut columns = Vec::new();
    for (field, array) in batch.schema().fields().iter().zip(batch.columns()) {
        let meta = field.metadata();
        match meta.get("rerun:kind").map(String::as_str) {
            Some("index") => {
                if Some(field.name().as_str()) == timeline {
                    let data = array.to_data();
                    let buffer = arrow_buffer::ScalarBuffer::<i64>::new(
                        data.buffers()[0].clone(),
                        data.offset(),
                        data.len(),
                    );
                    times = buffer.to_vec();
                }
            }
            Some("data") => columns.push(OracleColumn {
                entity: EntityPath::parse(&meta["rerun:entity_path"]).unwrap(),
                component: meta["rerun:component"].clone(),
                cells: array.as_any().downcast_ref::<ListArray>().unwrap().clone(),
            }),
            other => panic!("unexpected column kind {other:?} in oracle"),
        }
    }
    (times, columns)
}

fn oracle_cell(column: &OracleColumn, row: usize) -> Option<ArrayRef> {
    column.cells.is_valid(row).then(|| column.cells.value(row))
}

fn assert_same_cell(ours: Option<ArrayRef>, theirs: Option<ArrayRef>, what: &str) {
    match (ours, theirs) {
        (None, None) => {}
        (Some(ours), Some(theirs)) => {
            assert_eq!(ours.to_data(), theirs.to_data(), "{what}: cells differ");
        }
        (ours, theirs) => panic!("{what}: we answer {ours:?}, Rerun answers {theirs:?}"),
    }
}

/// Every (entity, component) of the store that Rerun's temporal views show.
fn temporal_view_columns(store: &ChunkStore) -> BTreeSet<(EntityPath, String)> {
    let properties = EntityPath::parse(PROPERTIES).unwrap();
    store
        .entity_paths()
        .into_iter()
        .filter(|e| *e != properties)
        .flat_map(|e| {
            store
                .component_names(&e)
                .into_iter()
                .map(move |c| (e.clone(), c.to_string()))
        })
        .collect()
}

#[test]
fn every_chunk_loads_and_round_trips_through_transport() {
    let files = load_chunks();
    assert_eq!(files.iter().map(Chunk::num_rows).sum::<usize>(), 261);
    for chunk in &files {
        let batch = chunk.to_record_batch().unwrap();
        let again = Chunk::from_record_batch(&batch).unwrap();
        assert_eq!(
            again.to_record_batch().unwrap(),
            batch,
            "{} round-trips",
            chunk.id()
        );
        assert_eq!(again.id(), chunk.id());
        assert_eq!(again.row_ids(), chunk.row_ids());
    }
}

#[test]
fn latest_at_matches_rerun_on_every_probe_and_timeline() {
    for store in stores() {
        latest_at_matches(&store);
    }
}

pub(crate) fn latest_at_matches(store: &ChunkStore) {
    let expected_columns = temporal_view_columns(store);
    let mut num_checked = 0;
    for timeline in TIMELINES {
        let batches = oracle(&format!("latest_at__{timeline}.arrow"));
        assert_eq!(batches.len(), 1);
        let (probes, columns) = split_table(&batches[0], Some(timeline));
        assert_eq!(probes.len(), batches[0].num_rows());
        let oracle_columns: BTreeSet<_> = columns
            .iter()
            .map(|c| (c.entity.clone(), c.component.clone()))
            .collect();
        assert_eq!(
            oracle_columns, expected_columns,
            "same columns on {timeline}"
        );
        for (row, &t) in probes.iter().enumerate() {
            let query = LatestAtQuery::new(timeline, TimeInt::new(t).unwrap());
            for column in &columns {
                let ours = store
                    .latest_at(&query, &column.entity, &column.component)
                    .map(|a| a.cell());
                let what = format!(
                    "latest-at {timeline}={t} {}:{}",
                    column.entity, column.component
                );
                assert_same_cell(ours, oracle_cell(column, row), &what);
                num_checked += 1;
            }
        }
    }
    assert!(num_checked > 1000, "checked {num_checked} cells");
}

#[test]
fn range_matches_rerun_on_every_range_and_timeline() {
    for store in stores() {
        range_matches(&store);
    }
}

pub(crate) fn range_matches(store: &ChunkStore) {
    let mut num_checked = 0;
    for timeline in TIMELINES {
        let json: serde_json::Value = serde_json::from_slice(
            &std::fs::read(recording().join(format!("oracle/range__{timeline}.json"))).unwrap(),
        )
        .unwrap();
        let ranges = json["ranges"].as_array().unwrap();
        let batches = oracle(&format!("range__{timeline}.arrow"));
        assert_eq!(batches.len(), ranges.len(), "one batch per range");
        for (spec, batch) in ranges.iter().zip(&batches) {
            let (lo, hi) = (spec["lo"].as_i64().unwrap(), spec["hi"].as_i64().unwrap());
            let query = RangeQuery::new(
                timeline,
                TimeRange::new(TimeInt::new(lo).unwrap(), TimeInt::new(hi).unwrap()),
            );
            let (times, columns) = split_table(batch, Some(timeline));
            for column in &columns {
                let what = format!(
                    "range {timeline} [{lo}, {hi}] {}:{}",
                    column.entity, column.component
                );
                let result = store.range(&query, &column.entity, &column.component);
                let rows: Vec<_> = result.iter().collect();
                if rows.first().is_some_and(|r| r.time().is_none()) {
                    // Static data: Rerun repeats the static cell on every row of the view.
                    assert_eq!(rows.len(), 1, "{what}: static range is one row");
                    for row in 0..batch.num_rows() {
                        assert_same_cell(Some(rows[0].cell()), oracle_cell(column, row), &what);
                    }
                    continue;
                }
                // Rerun's view keeps one row per time: the greatest row id.
                let mut ours: BTreeMap<i64, (chunkstore::RowId, ArrayRef)> = BTreeMap::new();
                let mut previous = None;
                for row in &rows {
                    let key = (row.time().unwrap(), row.row_id());
                    assert!(
                        previous < Some(key),
                        "{what}: rows ascend by (time, row id)"
                    );
                    previous = Some(key);
                    ours.insert(key.0.as_i64(), (key.1, row.cell()));
                }
                let theirs: BTreeMap<i64, ArrayRef> = times
                    .iter()
                    .enumerate()
                    .filter_map(|(row, &t)| oracle_cell(column, row).map(|cell| (t, cell)))
                    .collect();
                assert_eq!(
                    ours.keys().collect::<Vec<_>>(),
                    theirs.keys().collect::<Vec<_>>(),
                    "{what}: same times"
                );
                for (t, cell) in theirs {
                    assert_same_cell(
                        Some(ours[&t].1.clone()),
                        Some(cell),
                        &format!("{what} t={t}"),
                    );
                    num_checked += 1;
                }
            }
        }
    }
    assert!(num_checked > 200, "checked {num_checked} cells");
}

#[test]
fn static_answers_match_rerun() {
    for store in stores() {
        static_answers_match(&store);
    }
}

pub(crate) fn static_answers_match(store: &ChunkStore) {
    let batches = oracle("static.arrow");
    let (_, columns) = split_table(&batches[0], None);
    assert_eq!(columns.len(), 2);
    for timeline in TIMELINES.iter().chain(&["never_used_timeline"]) {
        let query = LatestAtQuery::new(*timeline, TimeInt::new(0).unwrap());
        for column in &columns {
            let answer = store
                .latest_at(&query, &column.entity, &column.component)
                .unwrap();
            assert!(answer.is_static());
            assert_same_cell(
                Some(answer.cell()),
                oracle_cell(column, 0),
                &column.component,
            );
        }
    }
}
