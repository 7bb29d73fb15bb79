//! Several recordings as one set of tables (`register_segments`, what the server's Flight
//! SQL answers from): each segment's rows, selected by `rerun_segment_id`, equal the same
//! query over that recording alone, with any filter on the index; a column a segment
//! lacks is null in its rows; the whole table has every segment's rows.

use proptest::prelude::*;

use super::{index_filter, random_store, run};
use crate::common::assert_same_table;
use chunkstore::sql::register_segments;
use datafusion::prelude::{SessionConfig, SessionContext};

fn one_part() -> SessionContext {
    SessionContext::new_with_config(SessionConfig::new().with_target_partitions(1))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, failure_persistence: crate::common::seed_file("sql/segments.txt"), ..ProptestConfig::default() })]

    #[test]
    fn each_segment_of_the_stacked_tables_answers_as_its_recording_alone(
        first in random_store(),
        second in random_store(),
        filter in index_filter(),
    ) {
        let stores = [("s0".to_owned(), first.snapshot()), ("s1".to_owned(), second.snapshot())];
        let stacked = one_part();
        register_segments(&stacked, &stores).unwrap();
        let mut total = 0;
        for (segment, snapshot) in &stores {
            let alone = one_part();
            chunkstore::sql::register(&alone, snapshot).unwrap();
            let own = run(&alone, "SELECT * FROM frame LIMIT 0").unwrap().batch.schema();
            let columns: Vec<String> =
                own.fields().iter().map(|f| format!("\"{}\"", f.name())).collect();
            let filter = filter.replace("{c}", "frame");
            let query = |extra: &str| format!(
                "SELECT {} FROM frame WHERE {extra}({filter})",
                columns.join(", ")
            );
            let expected = run(&alone, &query("")).unwrap().batch;
            let got = run(&stacked, &query(&format!("rerun_segment_id = '{segment}' AND "))).unwrap();
            assert_same_table(&got.batch, &expected, &format!("{segment}: {filter}"));
            total += expected.num_rows();
            // The other segment's own columns are null in this one's rows.
            let all = run(&stacked, &format!("SELECT * FROM frame WHERE rerun_segment_id = '{segment}'")).unwrap().batch;
            for (i, field) in all.schema().fields().iter().enumerate() {
                if field.name() != "rerun_segment_id" && own.field_with_name(field.name()).is_err() {
                    prop_assert_eq!(all.column(i).null_count(), all.num_rows(), "{} in {}", field.name(), segment);
                }
            }
        }
        let filter = filter.replace("{c}", "frame");
        let counted = run(&stacked, &format!("SELECT count(*) AS n FROM frame WHERE {filter}")).unwrap().batch;
        let counted = counted.column(0).as_any().downcast_ref::<arrow_array::Int64Array>().unwrap().value(0);
        prop_assert_eq!(usize::try_from(counted).unwrap(), total);
    }
}

/// The stacked chunk table takes entity filters into each segment's scan, and the
/// segment id is first.
#[test]
fn the_stacked_chunk_table_pushes_entity_filters_into_each_segment() {
    use chunkstore::{ChunkBuilder, ChunkId, ChunkStore, EntityPath, RowId, Timeline};
    use std::sync::Arc;

    let store_with = |entities: &[&str]| {
        let mut store = ChunkStore::new();
        for entity in entities {
            let value =
                Arc::new(arrow_array::Float64Array::from(vec![1.0])) as arrow_array::ArrayRef;
            let chunk = ChunkBuilder::new(ChunkId::new(), EntityPath::parse(entity).unwrap())
                .with_row(
                    RowId::new(),
                    [(Timeline::sequence("frame"), 1)],
                    [("x", value)],
                )
                .build()
                .unwrap();
            store.insert(chunk).unwrap();
        }
        store.snapshot()
    };
    let stores = [
        ("a".to_owned(), store_with(&["/robot", "/camera"])),
        ("b".to_owned(), store_with(&["/robot"])),
    ];
    let ctx = one_part();
    register_segments(&ctx, &stores).unwrap();
    let answer = run(
        &ctx,
        "SELECT rerun_segment_id, entity_path FROM chunks WHERE entity_path = '/robot' ORDER BY 1",
    )
    .unwrap();
    assert_eq!(answer.batch.num_rows(), 2);
    assert_eq!(answer.batch.schema().field(0).name(), "rerun_segment_id");
    assert_eq!(
        answer.plan.matches("entities=1 of").count(),
        2,
        "each segment's scan takes the filter:\n{}",
        answer.plan
    );
    assert!(!answer.plan.contains("FilterExec"), "{}", answer.plan);
}
