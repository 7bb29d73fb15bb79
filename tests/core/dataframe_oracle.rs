//! Rerun 0.41's own dataframe answers on the robot recording (`testdata/rerun-0.41/a_robot/
//! oracle/`), reproduced through `ChunkStore::dataframe` column by column: every sampled
//! table (`latest_at__<timeline>`: index values = the probe times, filled) and every range
//! of the sparse view (`range__<timeline>`), on all three timelines, from the chunk files
//! and from the `.rrd`.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests fail loudly on unexpected values"
)]

use arrow_array::{Array, RecordBatch};
use arrow_select::concat::concat_batches;
use chunkstore::{ChunkStore, DataframeQuery, EntityPathFilter, TimeInt, TimeRange, ipc};

const TIMELINES: [&str; 3] = ["frame_id", "sim_time", "log_time"];

use crate::common;
use common::robot_recording as recording;

fn stores() -> Vec<ChunkStore> {
    let from_chunks = common::robot();
    let bytes = std::fs::read(recording().join("a_robot.rrd")).unwrap();
    let contents = chunkstore::rrd::read_rrd(arrow_buffer::Buffer::from_vec(bytes), false).unwrap();
    let mut from_rrd = ChunkStore::new();
    for (_, chunk) in contents.chunks {
        from_rrd.insert(chunk).unwrap();
    }
    let mut compacted = from_chunks.clone();
    compacted.compact();
    vec![from_chunks, from_rrd, compacted]
}

fn oracle(name: &str) -> Vec<RecordBatch> {
    let bytes = std::fs::read(recording().join("oracle").join(name)).unwrap();
    ipc::read_batches(&bytes).unwrap()
}

fn oracle_json(name: &str) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(recording().join("oracle").join(name)).unwrap()).unwrap()
}

fn time(value: i64) -> TimeInt {
    TimeInt::new(value).unwrap()
}

/// Our table for `query`, as one batch.
fn table(store: &ChunkStore, query: &DataframeQuery) -> RecordBatch {
    let stream = store.dataframe(query).unwrap();
    let schema = stream.schema();
    let batches: Vec<RecordBatch> = stream.map(Result::unwrap).collect();
    concat_batches(&schema, &batches).unwrap()
}

/// Same column names in the same order, the index column equal, and every data column
/// equal cell by cell (other index columns are Rerun's maxima: not compared, per the
/// oracle's README). Field metadata of data columns must match too.
fn assert_same_as_rerun(ours: &RecordBatch, theirs: &RecordBatch, index: &str, what: &str) {
    let names = |b: &RecordBatch| -> Vec<String> {
        b.schema()
            .fields()
            .iter()
            .map(|f| f.name().clone())
            .collect()
    };
    assert_eq!(names(ours), names(theirs), "{what}: column names and order");
    assert_eq!(ours.num_rows(), theirs.num_rows(), "{what}: rows");
    for (i, field) in theirs.schema().fields().iter().enumerate() {
        let meta = field.metadata();
        let is_index = meta.get("rerun:kind").is_some_and(|k| k == "index");
        if is_index && field.name() != index {
            continue;
        }
        let our_field = ours.schema().field(i).clone();
        assert_eq!(
            our_field.data_type(),
            field.data_type(),
            "{what}: type of {}",
            field.name()
        );
        for key in [
            "rerun:entity_path",
            "rerun:component",
            "rerun:archetype",
            "rerun:component_type",
            "rerun:kind",
            "rerun:is_static",
        ] {
            assert_eq!(
                our_field.metadata().get(key),
                meta.get(key),
                "{what}: {key} of {}",
                field.name()
            );
        }
        let (a, b) = (ours.column(i), theirs.column(i));
        for row in 0..theirs.num_rows() {
            assert_eq!(
                a.slice(row, 1).to_data(),
                b.slice(row, 1).to_data(),
                "{what}: column {} row {row}",
                field.name()
            );
        }
        assert_eq!(
            a.null_count(),
            b.null_count(),
            "{what}: nulls of {}",
            field.name()
        );
    }
}

#[test]
fn sampled_tables_equal_rerun_latest_at() {
    for store in stores() {
        sampled_tables_equal(&store);
    }
}

/// `store`'s dataframes at Rerun's latest-at probes are Rerun's tables.
pub(crate) fn sampled_tables_equal(store: &ChunkStore) {
    for timeline in TIMELINES {
        let theirs = oracle(&format!("latest_at__{timeline}.arrow"));
        assert_eq!(theirs.len(), 1);
        let theirs = &theirs[0];
        let probes = theirs.column_by_name(timeline).unwrap().to_data();
        let probes: Vec<TimeInt> = arrow_array::Int64Array::from(
            probes
                .into_builder()
                .data_type(arrow_schema::DataType::Int64)
                .build()
                .unwrap(),
        )
        .values()
        .iter()
        .map(|&t| time(t))
        .collect();
        for fill in [false, true] {
            let query = DataframeQuery::new(timeline)
                .with_index_values(probes.iter().copied())
                .with_fill_latest_at(fill)
                .with_batch_rows(7);
            let ours = table(store, &query);
            assert_same_as_rerun(&ours, theirs, timeline, &format!("latest_at {timeline}"));
        }
    }
}

#[test]
fn range_tables_equal_rerun_ranges() {
    for store in stores() {
        range_tables_equal(&store);
    }
}

/// `store`'s dataframes over Rerun's ranges are Rerun's tables.
pub(crate) fn range_tables_equal(store: &ChunkStore) {
    for timeline in TIMELINES {
        let theirs = oracle(&format!("range__{timeline}.arrow"));
        let json = oracle_json(&format!("range__{timeline}.json"));
        let ranges = json["ranges"].as_array().unwrap();
        assert_eq!(ranges.len(), theirs.len());
        for (range, theirs) in ranges.iter().zip(&theirs) {
            let lo = time(range["lo"].as_i64().unwrap());
            let hi = time(range["hi"].as_i64().unwrap());
            for batch_rows in [1, 5, 1000] {
                let query = DataframeQuery::new(timeline)
                    .with_range(TimeRange::new(lo, hi))
                    .with_batch_rows(batch_rows);
                let ours = table(store, &query);
                assert_same_as_rerun(
                    &ours,
                    theirs,
                    timeline,
                    &format!("range {timeline} [{lo}, {hi}]"),
                );
            }
        }
    }
}

#[test]
fn static_columns_equal_rerun_static_table() {
    let theirs = &oracle("static.arrow")[0];
    for store in stores() {
        // `/__properties` included: Rerun's static table has the recording's properties
        // (which it names `property:<component>`; we name every column
        // `<entity>:<component>`, so columns are matched by their metadata).
        // `/**` leaves `/__properties` out unless named (issue 32, item 11).
        let everything = EntityPathFilter::parse(["/**", "/__properties/**"]).unwrap();
        let query = DataframeQuery::new("frame_id")
            .with_contents(everything)
            .with_index_values([time(0)]);
        let ours = table(&store, &query);
        let mut matched = 0;
        for (field, column) in theirs.schema().fields().iter().zip(theirs.columns()) {
            let meta = field.metadata();
            if meta.get("rerun:kind").is_some_and(|k| k == "index") {
                continue;
            }
            let name = format!("{}:{}", meta["rerun:entity_path"], meta["rerun:component"]);
            let mine = ours
                .column_by_name(&name)
                .unwrap_or_else(|| panic!("{name}"));
            assert_eq!(mine.to_data(), column.to_data(), "static {name}");
            let our_field = ours.schema().field_with_name(&name).unwrap().clone();
            assert_eq!(
                our_field
                    .metadata()
                    .get("rerun:is_static")
                    .map(String::as_str),
                Some("true")
            );
            matched += 1;
        }
        assert_eq!(
            matched, 2,
            "the recording's static columns: its properties and the view coordinates"
        );
    }
}
