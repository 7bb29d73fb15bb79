//! SQL over the store (feature `datafusion`): every table equals the dataframe API's
//! answer for the same view, each pushdown shape reads only the chunks that overlap it
//! (the scan's own `chunks_read` count), and bad SQL is DataFusion's error, never a panic.
//! The property test at the end holds SQL with pushdown, SQL without pushdown and the
//! dataframe API equal on random stores.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::cast_possible_wrap,
    clippy::cast_precision_loss,
    reason = "tests fail loudly on unexpected values; test values are small integers"
)]

use std::sync::Arc;

use arrow_array::{Array, ArrayRef, Float64Array, Int64Array, RecordBatch, StringArray};
use arrow_schema::SchemaRef;
use arrow_select::concat::concat_batches;
use chunkstore::sql::StoreScanExec;
use chunkstore::{
    ChunkBuilder, ChunkId, ChunkStore, ChunkTableQuery, DataframeQuery, EntityPath,
    EntityPathFilter, LatestAtQuery, RowId, Snapshot, StoreConfig, TimeInt, TimeRange, Timeline,
};
use datafusion::physical_plan::{ExecutionPlan, collect};
use datafusion::prelude::{SessionConfig, SessionContext};
use proptest::prelude::*;

#[path = "../common/mod.rs"]
mod common;
use common::assert_same_table;
mod dataset;
#[cfg(feature = "server")]
mod lifecycle;
#[cfg(feature = "server")]
mod observe;
mod segments;
#[cfg(feature = "server")]
mod server;
#[cfg(feature = "server")]
mod web;

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .build()
        .unwrap()
}

/// A query's result as one batch, the chunks its store scans read and the rows they
/// built.
struct Answer {
    batch: RecordBatch,
    chunks_read: usize,
    rows_built: usize,
    plan: String,
}

/// A session whose timeline scans build their range in one part, so that `chunks_read`
/// counts each chunk once.
fn context(snapshot: &Snapshot) -> SessionContext {
    context_with_parts(snapshot, 1)
}

/// A session whose timeline scans build their range in up to `parts` parts side by side.
fn context_with_parts(snapshot: &Snapshot, parts: usize) -> SessionContext {
    let ctx = SessionContext::new_with_config(SessionConfig::new().with_target_partitions(parts));
    chunkstore::sql::register(&ctx, snapshot).unwrap();
    ctx
}

fn run(ctx: &SessionContext, sql: &str) -> Result<Answer, datafusion::error::DataFusionError> {
    runtime().block_on(async {
        let frame = ctx.sql(sql).await?;
        let schema: SchemaRef = frame.schema().inner().clone();
        let plan = frame.create_physical_plan().await?;
        let batches = collect(Arc::clone(&plan), ctx.task_ctx()).await?;
        let batch = concat_batches(&schema, &batches)?;
        Ok(Answer {
            batch,
            chunks_read: scan_metric(plan.as_ref(), "chunks_read"),
            rows_built: scan_metric(plan.as_ref(), "rows_built"),
            plan: datafusion::physical_plan::displayable(plan.as_ref())
                .indent(true)
                .to_string(),
        })
    })
}

/// A metric summed over every store scan in the plan.
fn scan_metric(plan: &dyn ExecutionPlan, name: &str) -> usize {
    metric_of::<StoreScanExec>(plan, name)
}

/// A metric summed over every node of type `E` in the plan.
fn metric_of<E: ExecutionPlan + 'static>(plan: &dyn ExecutionPlan, name: &str) -> usize {
    let own = plan
        .downcast_ref::<E>()
        .and_then(ExecutionPlan::metrics)
        .and_then(|metrics| metrics.sum_by_name(name))
        .map_or(0, |value| value.as_usize());
    own + plan
        .children()
        .into_iter()
        .map(|child| metric_of::<E>(child.as_ref(), name))
        .sum::<usize>()
}

fn dataframe(snapshot: &Snapshot, query: &DataframeQuery) -> RecordBatch {
    let stream = snapshot.dataframe(query).unwrap();
    let schema = stream.schema();
    let batches: Vec<RecordBatch> = stream.map(Result::unwrap).collect();
    concat_batches(&schema, &batches).unwrap()
}

/// The values of an `Int64` column of an answer.
fn int64s(answer: &Answer, column: usize) -> Vec<i64> {
    answer
        .batch
        .column(column)
        .as_any()
        .downcast_ref::<Int64Array>()
        .unwrap()
        .values()
        .to_vec()
}

/// The whole chunk table of `snapshot`, from the API.
fn chunk_table(snapshot: &Snapshot) -> RecordBatch {
    let stream = snapshot.chunk_table(&ChunkTableQuery::new()).unwrap();
    let schema = stream.schema();
    let batches: Vec<RecordBatch> = stream.map(Result::unwrap).collect();
    concat_batches(&schema, &batches).unwrap()
}

#[test]
fn every_timeline_table_of_the_robot_recording_equals_its_dataframe_view() {
    let store = common::robot();
    let snapshot = store.snapshot();
    let ctx = context(&snapshot);
    let timelines = snapshot.timelines();
    assert!(timelines.len() >= 2);
    for timeline in &timelines {
        let name = timeline.name();
        let sql = run(&ctx, &format!("SELECT * FROM \"{name}\"")).unwrap();
        let api = dataframe(&snapshot, &DataframeQuery::new(name));
        assert!(api.num_rows() > 0);
        assert_same_table(&sql.batch, &api, name);

        // A range on the index, pushed down, equals the view's range.
        let min: i64 = {
            let index = api.column_by_name(name).unwrap();
            let values =
                datafusion::arrow::compute::cast(index, &arrow_schema::DataType::Int64).unwrap();
            let values = values
                .as_any()
                .downcast_ref::<Int64Array>()
                .unwrap()
                .clone();
            values.value(values.len() / 3)
        };
        let filtered = run(
            &ctx,
            &format!("SELECT * FROM \"{name}\" WHERE \"{name}\" >= {min}"),
        );
        if timeline.time_type() == chunkstore::TimeType::Sequence {
            let filtered = filtered.unwrap();
            let api = dataframe(
                &snapshot,
                &DataframeQuery::new(name)
                    .with_range(TimeRange::new(TimeInt::new(min).unwrap(), TimeInt::MAX)),
            );
            assert_same_table(&filtered.batch, &api, &format!("{name} >= {min}"));
            assert!(
                filtered.plan.contains(&format!("{name} >= {min}")),
                "{}",
                filtered.plan
            );
        }
    }
    // The chunk table holds every stored row.
    let rows: usize = snapshot.chunks().iter().map(|c| c.num_rows()).sum();
    let count = run(&ctx, "SELECT count(*) AS n FROM chunks").unwrap();
    let n = int64s(&count, 0)[0];
    assert_eq!(usize::try_from(n).unwrap(), rows);
}

const ENTITIES: usize = 4;
const CHUNKS_PER_ENTITY: i64 = 10;
const ROWS_PER_CHUNK: i64 = 10;

/// `ENTITIES` entities `/e/{i}`, each with `CHUNKS_PER_ENTITY` chunks of
/// `ROWS_PER_CHUNK` rows at consecutive frames (chunk `c` holds frames `10c..10c+9`),
/// compaction off so that the chunks stay as inserted; entity `i` logs `x` = frame + i.
fn grid() -> ChunkStore {
    let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).unwrap();
    let frame = Timeline::sequence("frame");
    for c in 0..CHUNKS_PER_ENTITY {
        for i in 0..ENTITIES {
            let entity = EntityPath::parse(&format!("/e/{i}")).unwrap();
            let mut builder = ChunkBuilder::new(ChunkId::new(), entity);
            for r in 0..ROWS_PER_CHUNK {
                let t = c * ROWS_PER_CHUNK + r;
                let value = Arc::new(Float64Array::from(vec![(t + i as i64) as f64])) as ArrayRef;
                builder = builder.with_row(RowId::new(), [(frame.clone(), t)], [("x", value)]);
            }
            store.insert(builder.build().unwrap()).unwrap();
        }
    }
    store
}

fn total_chunks() -> usize {
    ENTITIES * usize::try_from(CHUNKS_PER_ENTITY).unwrap()
}

#[test]
fn each_index_filter_reads_only_the_chunks_it_overlaps() {
    let store = grid();
    let snapshot = store.snapshot();
    let ctx = context(&snapshot);
    let full = run(&ctx, "SELECT * FROM frame").unwrap();
    assert_eq!(full.chunks_read, total_chunks());
    assert_eq!(full.rows_built, 100);
    assert_eq!(full.batch.num_rows(), 100);

    // (filter, rows, chunks per entity read, pushed down as)
    let cases: [(&str, usize, usize, &str); 8] = [
        ("frame = 42", 1, 1, "frame in [42, 42]"),
        ("frame < 15", 15, 2, "frame <= 14"),
        ("frame <= 15", 16, 2, "frame <= 15"),
        ("frame > 84", 15, 2, "frame >= 85"),
        ("frame >= 85", 15, 2, "frame >= 85"),
        ("frame BETWEEN 30 AND 49", 20, 2, "frame in [30, 49]"),
        ("frame >= 30 AND frame <= 49", 20, 2, "frame in [30, 49]"),
        ("frame IN (31, 35, 39)", 3, 1, "frame in [31, 39]"),
    ];
    for (filter, rows, chunks, pushed) in cases {
        let answer = run(&ctx, &format!("SELECT * FROM frame WHERE {filter}")).unwrap();
        assert_eq!(answer.batch.num_rows(), rows, "{filter}");
        assert_eq!(
            answer.chunks_read,
            chunks * ENTITIES,
            "{filter}: chunks read"
        );
        assert!(answer.plan.contains(pushed), "{filter}: {}", answer.plan);
        // Without pushdown (an expression the index cannot answer): the same rows, every
        // chunk read.
        let unpushed = filter.replace("frame", "(frame + 0)");
        let slow = run(&ctx, &format!("SELECT * FROM frame WHERE {unpushed}")).unwrap();
        assert_same_table(&answer.batch, &slow.batch, filter);
        assert_eq!(slow.chunks_read, total_chunks(), "{unpushed}");
    }
    // An exact filter leaves no FilterExec above the scan; IN does (DataFusion checks it).
    let exact = run(
        &ctx,
        "EXPLAIN SELECT * FROM frame WHERE frame BETWEEN 1 AND 2",
    )
    .unwrap();
    let text = datafusion::arrow::util::pretty::pretty_format_batches(&[exact.batch])
        .unwrap()
        .to_string();
    assert!(
        text.contains("StoreScanExec: table=frame, frame in [1, 2]"),
        "{text}"
    );
    assert!(!text.contains("FilterExec"), "{text}");
    let inexact = run(&ctx, "SELECT * FROM frame WHERE frame IN (1, 2)").unwrap();
    assert!(inexact.plan.contains("FilterExec"), "{}", inexact.plan);
}

#[test]
fn projections_build_only_the_selected_columns_and_keep_the_rows() {
    let store = grid();
    let snapshot = store.snapshot();
    let ctx = context(&snapshot);
    let answer = run(
        &ctx,
        r#"SELECT "/e/2:x", frame FROM frame WHERE frame < 30"#,
    )
    .unwrap();
    assert!(answer.plan.contains("columns=2 of 5"), "{}", answer.plan);
    let api = dataframe(
        &snapshot,
        &DataframeQuery::new("frame")
            .with_range(TimeRange::new(TimeInt::MIN, TimeInt::new(29).unwrap()))
            .with_columns(["/e/2:x", "frame"]),
    );
    // The API keeps the view's order (frame first); SQL asked for the other.
    assert_eq!(answer.batch.column(0).to_data(), api.column(1).to_data());
    assert_eq!(answer.batch.column(1).to_data(), api.column(0).to_data());
    // count(*) needs no column at all, and still counts the view's rows.
    let count = run(&ctx, "SELECT count(*) FROM frame").unwrap();
    let n = int64s(&count, 0)[0];
    assert_eq!(n, 100);
    // The chunk table builds only its selected columns too, in the order SQL asks for.
    let chunks = run(&ctx, "SELECT x, frame, entity_path FROM chunks").unwrap();
    assert!(chunks.plan.contains("columns=3 of 5"), "{}", chunks.plan);
    let whole = chunk_table(&snapshot);
    for (i, name) in ["x", "frame", "entity_path"].into_iter().enumerate() {
        assert_eq!(
            chunks.batch.column(i).to_data(),
            whole.column_by_name(name).unwrap().to_data(),
            "{name}"
        );
    }
    let count = run(&ctx, "SELECT count(*) FROM chunks").unwrap();
    assert!(count.plan.contains("columns=0 of 5"), "{}", count.plan);
    let n = int64s(&count, 0)[0];
    assert_eq!(usize::try_from(n).unwrap(), whole.num_rows());
}

/// The sparse view's rows ascend on the index, and the scan says so: `ORDER BY` the index
/// costs no sort. Sampled rows keep the order asked for, so they are sorted.
#[test]
fn a_timeline_table_needs_no_sort_to_be_ordered_by_its_index() {
    let store = grid();
    let snapshot = store.snapshot();
    let ctx = context(&snapshot);
    let query = r#"SELECT frame, "/e/1:x" FROM frame WHERE frame < 50"#;
    let sorted = run(&ctx, &format!("{query} ORDER BY frame")).unwrap();
    assert!(!sorted.plan.contains("SortExec"), "{}", sorted.plan);
    assert_eq!(int64s(&sorted, 0), (0..50).collect::<Vec<i64>>());
    let unsorted = run(&ctx, query).unwrap();
    assert_same_table(&sorted.batch, &unsorted.batch, "ORDER BY the index");
    let descending = run(&ctx, &format!("{query} ORDER BY frame DESC")).unwrap();
    assert!(descending.plan.contains("SortExec"), "{}", descending.plan);
    assert_eq!(int64s(&descending, 0), (0..50).rev().collect::<Vec<i64>>());
    let sampled = run(
        &ctx,
        "SELECT frame FROM latest_at('frame', [5, 1, 3]) ORDER BY frame",
    )
    .unwrap();
    assert!(sampled.plan.contains("SortExec"), "{}", sampled.plan);
    assert_eq!(int64s(&sampled, 0), vec![1, 3, 5]);
}

/// A timeline table's range is built in `target_partitions` parts side by side, read in
/// order: the same rows in the same order as one part, aggregates included, and `EXPLAIN`
/// says so. A limit or a sample is built in one part.
#[test]
fn a_range_built_in_parts_side_by_side_answers_as_one() {
    let store = grid();
    let snapshot = store.snapshot();
    let whole = context(&snapshot);
    for parts in [2, 4, 200] {
        let split = context_with_parts(&snapshot, parts);
        for sql in [
            "SELECT * FROM frame",
            "SELECT * FROM frame WHERE frame BETWEEN 3 AND 60",
            "SELECT * FROM frame WHERE frame >= 97",
            "SELECT * FROM frame WHERE frame BETWEEN -1000 AND 1000000",
            "SELECT frame FROM frame WHERE frame = 42",
            r#"SELECT count(*) AS n, sum("/e/1:x"[1]) AS s FROM frame WHERE frame < 77"#,
            "SELECT frame FROM frame ORDER BY frame DESC",
        ] {
            let one = run(&whole, sql).unwrap();
            let many = run(&split, sql).unwrap();
            assert_same_table(&many.batch, &one.batch, &format!("{sql} in {parts} parts"));
            assert!(many.chunks_read >= one.chunks_read, "{sql}");
        }
        let plan = run(&split, "SELECT * FROM frame WHERE frame < 50")
            .unwrap()
            .plan;
        assert!(
            plan.contains("ranges of frame built side by side"),
            "{plan}"
        );
        let limited = run(&split, "SELECT frame FROM frame LIMIT 7").unwrap();
        assert!(!limited.plan.contains("side by side"), "{}", limited.plan);
        assert_eq!(int64s(&limited, 0), (0..7).collect::<Vec<i64>>());
    }
    // One frame cannot be cut.
    let split = context_with_parts(&snapshot, 4);
    let one_frame = run(&split, "SELECT * FROM frame WHERE frame = 42").unwrap();
    assert!(
        !one_frame.plan.contains("side by side"),
        "{}",
        one_frame.plan
    );
}

#[test]
fn a_limit_stops_the_scan_early() {
    let store = grid();
    let snapshot = store.snapshot();
    let ctx = context(&snapshot);
    let answer = run(&ctx, "SELECT frame FROM frame LIMIT 7").unwrap();
    assert_eq!(answer.batch.num_rows(), 7);
    assert!(answer.plan.contains("limit=7"), "{}", answer.plan);
    assert_eq!(
        answer.rows_built, 7,
        "the store built no row past the limit"
    );
    let all = run(&ctx, "SELECT frame FROM frame").unwrap();
    assert_eq!(all.rows_built, 100);
    assert_eq!(int64s(&answer, 0), (0..7).collect::<Vec<i64>>());
}

#[test]
fn entity_filters_on_the_chunk_table_read_only_those_entities() {
    let store = grid();
    let snapshot = store.snapshot();
    let ctx = context(&snapshot);
    let per_entity = usize::try_from(CHUNKS_PER_ENTITY).unwrap();
    let cases: [(&str, usize); 5] = [
        ("entity_path = '/e/1'", 1),
        ("entity_path IN ('/e/1', '/e/3', '/nowhere')", 2),
        ("entity_path LIKE '/e/%'", 4),
        ("entity_path LIKE '%3'", 1),
        ("starts_with(entity_path, '/e/2')", 1),
    ];
    for (filter, entities) in cases {
        let sql = format!(
            "SELECT entity_path, frame, x FROM chunks WHERE {filter} ORDER BY entity_path, frame"
        );
        let answer = run(&ctx, &sql).unwrap();
        assert_eq!(answer.chunks_read, entities * per_entity, "{filter}");
        assert!(
            answer
                .plan
                .contains(&format!("entities={entities} of {ENTITIES}")),
            "{filter}: {}",
            answer.plan
        );
        let unpushed = filter.replace("entity_path", "concat(entity_path, '')");
        let slow = run(&ctx, &sql.replace(filter, &unpushed)).unwrap();
        assert_eq!(slow.chunks_read, total_chunks(), "{unpushed}");
        assert_same_table(&answer.batch, &slow.batch, filter);
        assert_eq!(answer.batch.num_rows(), entities * 100, "{filter}");
    }
    // A time filter on the chunk table reads the overlapping chunks; DataFusion keeps
    // only the rows in range.
    let answer = run(
        &ctx,
        "SELECT frame FROM chunks WHERE frame BETWEEN 20 AND 29",
    )
    .unwrap();
    assert!(
        answer.plan.contains("chunks overlapping frame in [20, 29]"),
        "{}",
        answer.plan
    );
    assert_eq!(answer.chunks_read, ENTITIES);
    assert_eq!(answer.batch.num_rows(), 10 * ENTITIES);
}

#[test]
fn latest_at_as_a_table_function_equals_the_store_latest_at() {
    let store = grid();
    let snapshot = store.snapshot();
    let ctx = context(&snapshot);
    let answer = run(&ctx, "SELECT * FROM latest_at('frame', 57)").unwrap();
    assert_eq!(answer.batch.num_rows(), 1);
    for i in 0..ENTITIES {
        let entity = EntityPath::parse(&format!("/e/{i}")).unwrap();
        let cell = snapshot
            .latest_at(
                &LatestAtQuery::new("frame", TimeInt::new(57).unwrap()),
                &entity,
                "x",
            )
            .unwrap();
        let column = answer.batch.column_by_name(&format!("/e/{i}:x")).unwrap();
        let list = column
            .as_any()
            .downcast_ref::<arrow_array::ListArray>()
            .unwrap();
        assert_eq!(list.value(0).to_data(), cell.cell().to_data(), "/e/{i}");
    }
    // Several times, one entity.
    let answer = run(
        &ctx,
        r#"SELECT frame, "/e/1:x" FROM latest_at('frame', [5, 500, -1], '/e/1')"#,
    )
    .unwrap();
    assert_eq!(answer.batch.num_columns(), 2);
    assert_eq!(int64s(&answer, 0), vec![5, 500, -1]);
    let x = answer
        .batch
        .column(1)
        .as_any()
        .downcast_ref::<arrow_array::ListArray>()
        .unwrap();
    assert!(
        x.is_valid(0) && x.is_valid(1) && x.is_null(2),
        "nothing before frame 0"
    );
}

#[test]
fn an_asof_join_attaches_the_latest_values_to_each_query_time() {
    let store = grid();
    let snapshot = store.snapshot();
    let ctx = context(&snapshot);
    let detections = RecordBatch::try_from_iter([
        (
            "at",
            Arc::new(Int64Array::from(vec![3, 99, 3, -5])) as ArrayRef,
        ),
        (
            "label",
            Arc::new(StringArray::from(vec!["a", "b", "c", "d"])) as ArrayRef,
        ),
    ])
    .unwrap();
    let rt = runtime();
    let batches = rt
        .block_on(async {
            let left = ctx.read_batch(detections)?;
            let joined = chunkstore::sql::asof_join(
                &ctx,
                &snapshot,
                left,
                "at",
                "frame",
                EntityPathFilter::parse(["/e/0"]).unwrap(),
            )
            .await?;
            joined
                .sort_by(vec![datafusion::prelude::col("label")])?
                .collect()
                .await
        })
        .unwrap();
    let schema = batches[0].schema();
    let batch = concat_batches(&schema, &batches).unwrap();
    assert_eq!(batch.num_rows(), 4);
    let x = batch.column_by_name("/e/0:x").unwrap();
    let x = x.as_any().downcast_ref::<arrow_array::ListArray>().unwrap();
    let value = |row: usize| {
        x.value(row)
            .as_any()
            .downcast_ref::<Float64Array>()
            .unwrap()
            .value(0)
    };
    assert_eq!((value(0), value(1), value(2)), (3.0, 99.0, 3.0));
    assert!(x.is_null(3), "no value before frame 0");
}

#[test]
fn bad_sql_is_an_error_never_a_panic() {
    let store = grid();
    let snapshot = store.snapshot();
    let ctx = context(&snapshot);
    for sql in [
        "SELEC * FROM frame",
        "SELECT nope FROM frame",
        "SELECT * FROM no_such_table",
        "SELECT * FROM frame WHERE frame > 'text'",
        "SELECT * FROM latest_at()",
        "SELECT * FROM latest_at('nope', 1)",
        "SELECT * FROM latest_at('frame', 'x')",
        "SELECT * FROM latest_at('frame', 1, 5)",
        "SELECT * FROM latest_at('frame', 1, '/a/**/b')",
        "SELECT \"/e/0:x\" + 1 FROM frame",
    ] {
        assert!(run(&ctx, sql).is_err(), "{sql} should fail");
    }
}

#[test]
fn registering_again_replaces_the_tables_with_a_newer_snapshot() {
    let mut store = grid();
    let ctx = context(&store.snapshot());
    let old = store.snapshot();
    store.drop_entity(&EntityPath::parse("/e/0").unwrap(), false);
    chunkstore::sql::register(&ctx, &store.snapshot()).unwrap();
    let answer = run(&ctx, "SELECT * FROM frame LIMIT 1").unwrap();
    assert_eq!(answer.batch.num_columns(), 1 + ENTITIES - 1);
    // The old snapshot still answers as it was.
    let ctx_old = context(&old);
    let answer = run(&ctx_old, "SELECT * FROM frame LIMIT 1").unwrap();
    assert_eq!(answer.batch.num_columns(), 1 + ENTITIES);
}

/// A random store: entities `/p/{e}` with up to two components, rows at random frames in
/// `0..40`, in chunks of one to five rows, compaction on or off, sometimes a Clear.
fn random_store() -> impl Strategy<Value = ChunkStore> {
    let row = (0usize..3, 0i64..40, 0usize..2, -100i64..100);
    (
        prop::collection::vec(prop::collection::vec(row, 1..5), 1..25),
        any::<bool>(),
        prop::option::of((0usize..3, 0i64..40)),
    )
        .prop_map(|(chunks, compaction, clear)| {
            let config = if compaction {
                StoreConfig::DEFAULT
            } else {
                StoreConfig::COMPACTION_OFF
            };
            let mut store = ChunkStore::with_config(config).unwrap();
            let frame = Timeline::sequence("frame");
            for rows in chunks {
                // One entity and component set per chunk: the first row's.
                let (entity, _, component, _) = rows[0];
                let path = EntityPath::parse(&format!("/p/{entity}")).unwrap();
                let name = ["a", "b"][component];
                let mut builder = ChunkBuilder::new(ChunkId::new(), path);
                for (_, t, _, v) in rows {
                    let value = Arc::new(Float64Array::from(vec![v as f64])) as ArrayRef;
                    builder = builder.with_row(RowId::new(), [(frame.clone(), t)], [(name, value)]);
                }
                store.insert(builder.build().unwrap()).unwrap();
            }
            if let Some((entity, t)) = clear {
                let row_id = RowId::new().as_u128();
                store
                    .insert(common::clear(
                        &format!("/p/{entity}"),
                        Some(t),
                        row_id,
                        false,
                    ))
                    .unwrap();
            }
            store
        })
}

/// A random filter on `frame` (`{c}` stands for the column): every shape the pushdown
/// reads, with literals at the edges of `i64` and of the data.
fn index_filter() -> impl Strategy<Value = String> {
    let value = prop_oneof![
        12 => 0i64..40,
        1 => Just(i64::MAX),
        1 => Just(i64::MIN + 1),
        1 => Just(-1),
        1 => Just(45),
    ];
    let comparison = (
        prop::sample::select(vec!["=", "<", "<=", ">", ">=", "<>"]),
        value.clone(),
    )
        .prop_map(|(op, v)| format!("{{c}} {op} {v}"));
    let between =
        (value.clone(), value.clone()).prop_map(|(a, b)| format!("{{c}} BETWEEN {a} AND {b}"));
    let in_list = prop::collection::vec(value, 1..5).prop_map(|vs| {
        let vs: Vec<String> = vs.iter().map(ToString::to_string).collect();
        format!("{{c}} IN ({})", vs.join(", "))
    });
    let leaf = prop_oneof![comparison, between, in_list];
    prop_oneof![
        3 => leaf.clone(),
        1 => (leaf.clone(), leaf.clone()).prop_map(|(a, b)| format!("({a}) OR ({b})")),
        1 => (leaf.clone(), leaf).prop_map(|(a, b)| format!("{a} AND {b}")),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 200, failure_persistence: common::seed_file("sql/main.txt"), ..ProptestConfig::default() })]

    /// Any filter on the index answers the same pushed down (as far as the store can) and
    /// not pushed down at all, on the timeline table and on the chunk table.
    #[test]
    fn any_index_filter_answers_the_same_with_and_without_pushdown(
        store in random_store(),
        filter in index_filter(),
    ) {
        let snapshot = store.snapshot();
        let ctx = context(&snapshot);
        for (table, columns, order) in [("frame", "*", "frame"), ("chunks", "row_id, frame", "frame, row_id")] {
            let sql = |c: &str| format!(
                "SELECT {columns} FROM {table} WHERE {} ORDER BY {order}",
                filter.replace("{c}", c)
            );
            let pushed = run(&ctx, &sql("frame")).unwrap();
            let unpushed = run(&ctx, &sql("(frame + 0)")).unwrap();
            assert_same_table(&pushed.batch, &unpushed.batch, &sql("frame"));
            prop_assert!(pushed.chunks_read <= unpushed.chunks_read);
        }
    }

}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, failure_persistence: common::seed_file("sql/main.txt"), ..ProptestConfig::default() })]

    /// SQL with pushdown == SQL without pushdown == the dataframe API, for random stores,
    /// ranges and entity filters.
    #[test]
    fn sql_with_pushdown_equals_sql_without_and_the_dataframe_api(
        store in random_store(),
        lo in -5i64..45,
        len in 0i64..30,
        entity in 0usize..3,
    ) {
        let snapshot = store.snapshot();
        let ctx = context(&snapshot);
        let hi = lo + len;
        let pushed = run(&ctx, &format!("SELECT * FROM frame WHERE frame BETWEEN {lo} AND {hi}")).unwrap();
        let unpushed = run(&ctx, &format!("SELECT * FROM frame WHERE frame + 0 BETWEEN {lo} AND {hi}")).unwrap();
        let api = dataframe(
            &snapshot,
            &DataframeQuery::new("frame").with_range(TimeRange::new(TimeInt::new(lo).unwrap(), TimeInt::new(hi).unwrap())),
        );
        assert_same_table(&pushed.batch, &api, "pushed");
        assert_same_table(&unpushed.batch, &api, "unpushed");
        prop_assert!(pushed.chunks_read <= unpushed.chunks_read);
        // Built in parts side by side, the rows come in the same order, no ORDER BY asked
        // (a filter DataFusion applies itself may spread the batches over its partitions,
        // so that query asks for the order).
        for parts in [2, 3, 7] {
            let split = context_with_parts(&snapshot, parts);
            for sql in [
                format!("SELECT * FROM frame WHERE frame BETWEEN {lo} AND {hi}"),
                format!("SELECT * FROM frame WHERE frame + 0 BETWEEN {lo} AND {hi} ORDER BY frame"),
            ] {
                let answer = run(&split, &sql).unwrap();
                assert_same_table(&answer.batch, &api, &format!("{sql} in {parts} parts"));
            }
        }

        // The chunk table, narrowed to one entity, equals the whole table filtered.
        let path = format!("/p/{entity}");
        let sql = |filter: &str| format!(
            "SELECT entity_path, row_id, frame FROM chunks WHERE {filter} ORDER BY row_id"
        );
        let narrowed = run(&ctx, &sql(&format!("entity_path = '{path}'"))).unwrap();
        let whole = run(&ctx, &sql(&format!("concat(entity_path, '') = '{path}'"))).unwrap();
        assert_same_table(&narrowed.batch, &whole.batch, "chunks by entity");
        let by_time = run(&ctx, &sql(&format!("frame BETWEEN {lo} AND {hi}"))).unwrap();
        let by_time_whole = run(&ctx, &sql(&format!("frame + 0 BETWEEN {lo} AND {hi}"))).unwrap();
        assert_same_table(&by_time.batch, &by_time_whole.batch, "chunks by time");
    }
}

/// Issue 32, item 14: a duration timeline compares with integer nanoseconds, as it is
/// written everywhere else (the CLI, Python, `latest_at`), and with `INTERVAL`s; the
/// comparison is still pushed down to the store. Text times work in `latest_at`.
#[test]
fn durations_compare_with_integers_and_text_times_work() {
    let snapshot = common::robot().snapshot();
    let ctx = context(&snapshot);
    let count = |sql: &str| int64s(&run(&ctx, sql).unwrap(), 0)[0];
    // sim_time is 0.1 s per frame, frames 0 to 59.
    let by_integer = count("SELECT count(*) FROM sim_time WHERE sim_time > 1000000000");
    assert_eq!(by_integer, 49);
    assert_eq!(
        count("SELECT count(*) FROM sim_time WHERE 1000000000 < sim_time"),
        by_integer
    );
    assert_eq!(
        count("SELECT count(*) FROM sim_time WHERE sim_time > INTERVAL '1 second'"),
        by_integer
    );
    let answer = run(
        &ctx,
        "SELECT count(*) FROM sim_time WHERE sim_time > 1000000000",
    )
    .unwrap();
    assert!(
        answer.chunks_read < total_chunks_of(&snapshot),
        "pushed down: {}",
        answer.plan
    );
    // Registering again adds no second planner (the answer is the same).
    chunkstore::sql::register(&ctx, &snapshot).unwrap();
    assert_eq!(
        count("SELECT count(*) FROM sim_time WHERE sim_time >= 1000000000"),
        50
    );
    assert_eq!(
        count("SELECT count(*) FROM latest_at('sim_time', '1.5s')"),
        count("SELECT count(*) FROM latest_at('sim_time', 1500000000)")
    );
    assert_eq!(
        count("SELECT count(*) FROM log_time WHERE log_time >= '2026-11-21T12:55:49Z'"),
        count("SELECT count(*) FROM log_time WHERE log_time >= 1795265749000000000")
    );
    let Err(error) = run(&ctx, "SELECT * FROM latest_at('frame_id', '1.5s')") else {
        panic!("'1.5s' is no time of a sequence");
    };
    assert!(error.to_string().contains("sequence"), "{error}");
}

fn total_chunks_of(snapshot: &Snapshot) -> usize {
    usize::try_from(snapshot.stats().num_chunks()).unwrap()
}
