//! SQL over a dataset (`chunkstore::sql::register_dataset`, SEMANTICS.md section 15): each
//! timeline table is the dataset's dataframe on it, `chunks` each segment's chunk table,
//! with `rerun_segment_id` first; filters on the segment id and the index prune whole
//! files and chunks before anything is read.

use std::path::Path;
use std::sync::Arc;

use arrow_array::{Array, Int64Array, RecordBatch, StringArray};
use arrow_schema::SchemaRef;
use arrow_select::concat::concat_batches;
use chunkstore::DataframeQuery;
use chunkstore::dataset::{Dataset, DatasetOptions};
use chunkstore::sql::DatasetScanExec;
use datafusion::physical_plan::{ExecutionPlan, collect};
use datafusion::prelude::{SessionConfig, SessionContext};

use crate::common::{ScratchDir, scalars, write_recording};
use crate::{assert_same_table, runtime};

fn context(dataset: &Dataset, partitions: usize) -> SessionContext {
    let ctx =
        SessionContext::new_with_config(SessionConfig::new().with_target_partitions(partitions));
    chunkstore::sql::register_dataset(&ctx, dataset).unwrap();
    ctx
}

/// A query's answer as one batch, with its plan (as `EXPLAIN` shows it) and a metric of
/// its dataset scans.
struct Answer {
    batch: RecordBatch,
    plan: String,
    chunks_decoded: usize,
    segments_read: usize,
}

fn run(ctx: &SessionContext, sql: &str) -> Result<Answer, datafusion::error::DataFusionError> {
    runtime().block_on(async {
        let frame = ctx.sql(sql).await?;
        let schema: SchemaRef = frame.schema().inner().clone();
        let plan = frame.create_physical_plan().await?;
        let batches = collect(Arc::clone(&plan), ctx.task_ctx()).await?;
        Ok(Answer {
            batch: concat_batches(&schema, &batches)?,
            plan: datafusion::physical_plan::displayable(plan.as_ref())
                .indent(true)
                .to_string(),
            chunks_decoded: metric(plan.as_ref(), "chunks_decoded"),
            segments_read: metric(plan.as_ref(), "segments_read"),
        })
    })
}

fn metric(plan: &dyn ExecutionPlan, name: &str) -> usize {
    crate::metric_of::<DatasetScanExec>(plan, name)
}

fn read_all(table: impl arrow_array::RecordBatchReader) -> RecordBatch {
    let schema = table.schema();
    let batches: Vec<RecordBatch> = table.map(Result::unwrap).collect();
    concat_batches(&schema, &batches).unwrap()
}

/// `SELECT *` of a timeline table, in (segment, index) order, is the dataset's dataframe,
/// however many partitions read it.
#[test]
fn a_dataset_timeline_table_is_the_dataset_dataframe() {
    let dir = ScratchDir::new("sql-dataset-table");
    crate::common::episodes(&dir);
    let dataset = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    let expected = read_all(dataset.dataframe(&DataframeQuery::new("frame")).unwrap());
    assert_eq!(expected.num_rows(), 6);
    for partitions in [1, 2, 4] {
        let ctx = context(&dataset, partitions);
        let answer = run(&ctx, "SELECT * FROM frame ORDER BY rerun_segment_id, frame").unwrap();
        assert_same_table(
            &answer.batch,
            &expected,
            &format!("{partitions} partitions"),
        );
        assert!(
            !answer.plan.contains("SortExec"),
            "the scan's order needs no sort:\n{}",
            answer.plan
        );
    }
    let ctx = context(&dataset, 2);
    let count = run(
        &ctx,
        "SELECT rerun_segment_id, count(*) AS n FROM frame GROUP BY 1 ORDER BY 1",
    )
    .unwrap();
    let ids = count
        .batch
        .column(0)
        .as_any()
        .downcast_ref::<StringArray>()
        .unwrap();
    let counts = count
        .batch
        .column(1)
        .as_any()
        .downcast_ref::<Int64Array>()
        .unwrap();
    let segment_of = expected
        .column(0)
        .as_any()
        .downcast_ref::<StringArray>()
        .unwrap();
    let rows_of = |id: &str| segment_of.iter().filter(|s| *s == Some(id)).count() as i64;
    assert_eq!(
        ids.iter().zip(counts.iter()).collect::<Vec<_>>(),
        [
            (Some("rec-a"), Some(rows_of("rec-a"))),
            (Some("rec-b"), Some(rows_of("rec-b")))
        ],
        "rec-s has no frame data: no rows"
    );
}

/// `chunks` holds each segment's chunk table, its segment id first and null in the columns
/// only other segments have.
#[test]
fn the_dataset_chunk_table_is_each_segments_chunk_table() {
    let dir = ScratchDir::new("sql-dataset-chunks");
    crate::common::episodes(&dir);
    let dataset = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    let ctx = context(&dataset, 2);
    for segment in dataset.segments() {
        let store = chunkstore::recording::LoadedRecording::load(
            &segment.path,
            &chunkstore::recording::OpenOptions::default().with_lazy(false),
            &mut (),
        )
        .unwrap()
        .store;
        let own_ctx = crate::context(&store.snapshot());
        let own = run(&own_ctx, "SELECT * FROM chunks ORDER BY row_id")
            .unwrap()
            .batch;
        let answer = run(
            &ctx,
            &format!(
                "SELECT * FROM chunks WHERE rerun_segment_id = '{}' ORDER BY row_id",
                segment.id
            ),
        )
        .unwrap();
        assert!(
            answer
                .plan
                .contains("segments=1 of 3 (pruned: 2 by rerun_segment_id)"),
            "{}",
            answer.plan
        );
        assert_eq!(answer.segments_read, 1);
        let got = &answer.batch;
        assert_eq!(got.num_rows(), own.num_rows(), "{}", segment.id);
        let ids = got
            .column(0)
            .as_any()
            .downcast_ref::<StringArray>()
            .unwrap();
        assert!(ids.iter().all(|id| id == Some(segment.id.as_str())));
        for field in got.schema().fields().iter().skip(1) {
            let column = got.column_by_name(field.name()).unwrap();
            match own.column_by_name(field.name()) {
                Some(expected) => {
                    assert_eq!(column.to_data(), expected.to_data(), "{}", field.name());
                }
                None => assert_eq!(column.null_count(), got.num_rows(), "{}", field.name()),
            }
        }
    }
    let entity = run(
        &ctx,
        "SELECT count(*) FROM chunks WHERE entity_path = '/robot/arm'",
    )
    .unwrap();
    let n = entity
        .batch
        .column(0)
        .as_any()
        .downcast_ref::<Int64Array>()
        .unwrap();
    assert_eq!(n.value(0), 4);
    assert!(entity.plan.contains("entities=1 of"), "{}", entity.plan);
}

/// Many segments, each ten chunks of ten rows at times of its own: `segment k` holds
/// frames `100·k ..= 100·k + 99`.
fn grid(dir: &Path, segments: i64) -> Dataset {
    for k in 0..segments {
        let chunks = (0..10)
            .map(|c| {
                let rows: Vec<(i64, u128, Option<Vec<f64>>)> = (0..10)
                    .map(|r| {
                        let t = 100 * k + 10 * c + r;
                        (t, u128::try_from(t).unwrap() + 1, Some(vec![t as f64]))
                    })
                    .collect();
                scalars("/sensor", "value", &rows)
            })
            .collect();
        write_recording(dir, &format!("{k}.rrd"), &format!("seg-{k}"), chunks);
    }
    Dataset::open(dir, &DatasetOptions::default()).unwrap()
}

/// A range on the index keeps only the segments it overlaps, and of them only the chunks
/// it overlaps; a filter on the segment id keeps only those segments; `EXPLAIN` says so
/// before reading, and only those are read.
#[test]
fn filters_prune_whole_files_and_chunks_before_anything_is_read() {
    let dir = ScratchDir::new("sql-dataset-prune");
    let dataset = grid(&dir, 6);
    let ctx = context(&dataset, 2);
    let planned = dataset.read_stats();
    assert_eq!(
        (planned.segment_reads, planned.chunks_decoded),
        (1, 1),
        "six segments of one shape: the tables' columns are the first's, from one chunk"
    );

    let answer = run(
        &ctx,
        r#"SELECT count(*), sum("/sensor:value"[1]) FROM frame WHERE frame BETWEEN 205 AND 214"#,
    )
    .unwrap();
    let n = answer
        .batch
        .column(0)
        .as_any()
        .downcast_ref::<Int64Array>()
        .unwrap();
    assert_eq!(n.value(0), 10);
    assert!(
        answer
            .plan
            .contains("segments=1 of 6 (pruned: 5 outside frame in [205, 214])"),
        "{}",
        answer.plan
    );
    assert!(answer.plan.contains("chunks=2 of 60"), "{}", answer.plan);
    assert_eq!((answer.segments_read, answer.chunks_decoded), (1, 2));

    let answer = run(
        &ctx,
        "SELECT count(*) FROM frame WHERE rerun_segment_id IN ('seg-1', 'seg-4') AND frame >= 150",
    )
    .unwrap();
    let n = answer
        .batch
        .column(0)
        .as_any()
        .downcast_ref::<Int64Array>()
        .unwrap();
    assert_eq!(n.value(0), 50 + 100);
    assert!(
        answer
            .plan
            .contains("segments=2 of 6 (pruned: 4 by rerun_segment_id, 0 outside frame >= 150)"),
        "{}",
        answer.plan
    );
    assert!(answer.plan.contains("chunks=15 of 60"), "{}", answer.plan);
    assert_eq!((answer.segments_read, answer.chunks_decoded), (2, 15));

    let answer = run(
        &ctx,
        "SELECT count(*) FROM frame WHERE rerun_segment_id LIKE 'nope%'",
    )
    .unwrap();
    let n = answer
        .batch
        .column(0)
        .as_any()
        .downcast_ref::<Int64Array>()
        .unwrap();
    assert_eq!(n.value(0), 0);
    assert_eq!(answer.segments_read, 0, "no segment is read");

    // A limit reads the first segment's first rows, not the dataset.
    let answer = run(&ctx, "SELECT rerun_segment_id, frame FROM frame LIMIT 3").unwrap();
    assert_eq!(answer.batch.num_rows(), 3);
    assert_eq!(answer.segments_read, 1, "{}", answer.plan);
}

#[test]
fn latest_at_over_a_dataset_says_what_answers_it() {
    let dir = ScratchDir::new("sql-dataset-latest-at");
    crate::common::episodes(&dir);
    let dataset = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    let ctx = context(&dataset, 1);
    let error = run(&ctx, "SELECT * FROM latest_at('frame', 3)")
        .err()
        .unwrap()
        .to_string();
    assert!(error.contains("--segment"), "{error}");
}

mod pruning_model {
    use std::sync::atomic::{AtomicUsize, Ordering};

    use arrow_array::{BooleanArray, StringArray};
    use arrow_select::filter::filter_record_batch;
    use proptest::prelude::*;

    use super::{Answer, context, read_all, run};
    use crate::assert_same_table;
    use crate::common::{ScratchDir, clear, scalars, static_scalar, write_recording};
    use chunkstore::dataset::{Dataset, DatasetOptions};
    use chunkstore::{DataframeQuery, TimeInt, TimeRange};

    const ENTITIES: [&str; 3] = ["/e", "/e/child", "/f"];

    static CASE: AtomicUsize = AtomicUsize::new(0);

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, failure_persistence: crate::common::seed_file("sql/dataset.txt"), ..ProptestConfig::default() })]

        /// Whatever the segments, the range and the segments named, a filtered timeline
        /// table is the dataset's dataframe on that range, of those segments: pruning
        /// files and chunks never changes an answer.
        #[test]
        fn a_filtered_table_is_the_dataframe_of_its_range_and_segments(
            // Per segment: chunks (entity, times), a Clear (entity, time), a static.
            segments in prop::collection::vec(
                (
                    prop::collection::vec((0..3usize, prop::collection::vec(0i64..40, 1..4)), 1..5),
                    prop::option::of((0..3usize, 0i64..40, any::<bool>())),
                    any::<bool>(),
                ),
                1..4,
            ),
            lo in -2i64..40,
            len in 0i64..15,
            named in prop::collection::vec(any::<bool>(), 4),
            partitions in 1usize..3,
        ) {
            let case = CASE.fetch_add(1, Ordering::Relaxed);
            let dir = ScratchDir::new(&format!("sql-dataset-model-{case}"));
            let mut row = 0u128;
            for (k, (chunks, cleared, with_static)) in segments.iter().enumerate() {
                let mut written = Vec::new();
                for (entity, times) in chunks {
                    let rows: Vec<_> = times
                        .iter()
                        .map(|&t| {
                            row += 1;
                            (t, row, Some(vec![t as f64]))
                        })
                        .collect();
                    written.push(scalars(ENTITIES[*entity], "x", &rows));
                }
                if let Some((entity, time, recursive)) = cleared {
                    row += 1;
                    written.push(clear(ENTITIES[*entity], Some(*time), row, *recursive));
                }
                if *with_static {
                    row += 1;
                    written.push(static_scalar("/e", "s", row, -1.0));
                }
                write_recording(&dir, &format!("{k}.rrd"), &format!("s{k}"), written);
            }
            let dataset = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
            let ctx = context(&dataset, partitions);
            let ids: Vec<String> = (0..segments.len())
                .filter(|&k| named[k])
                .map(|k| format!("'s{k}'"))
                .collect();
            let mut sql = format!(
                "SELECT * FROM frame WHERE frame BETWEEN {lo} AND {}",
                lo + len
            );
            if !ids.is_empty() {
                sql = format!("{sql} AND rerun_segment_id IN ({})", ids.join(", "));
            }
            sql.push_str(" ORDER BY rerun_segment_id, frame");
            let Answer { batch, .. } = run(&ctx, &sql).unwrap();

            let query = DataframeQuery::new("frame").with_range(TimeRange::new(
                TimeInt::new(lo).unwrap(),
                TimeInt::new(lo + len).unwrap(),
            ));
            let whole = read_all(dataset.dataframe(&query).unwrap());
            let segment = whole.column(0).as_any().downcast_ref::<StringArray>().unwrap();
            let keep: BooleanArray = segment
                .iter()
                .map(|id| Some(ids.is_empty() || ids.contains(&format!("'{}'", id.unwrap()))))
                .collect();
            let expected = filter_record_batch(&whole, &keep).unwrap();
            assert_same_table(&batch, &expected, &sql);
        }
    }
}

/// A column a later segment gives another type than the first: the tables' columns are
/// planned from the segments that add columns, so the query that reaches it fails, naming
/// the column and the segment.
#[test]
fn a_column_of_two_types_is_the_error_of_the_query_that_meets_it() {
    let dir = ScratchDir::new("sql-dataset-type-conflict");
    write_recording(
        &dir,
        "a.rrd",
        "first",
        vec![scalars("/e", "x", &[(1, 1, Some(vec![1.0]))])],
    );
    let booleans = crate::common::boolean("/e", "x", 2, 2, true);
    write_recording(&dir, "b.rrd", "second", vec![booleans]);
    let dataset = Dataset::open(&dir, &DatasetOptions::default()).unwrap();
    let ctx = context(&dataset, 1);
    let first = run(&ctx, "SELECT * FROM frame WHERE rerun_segment_id = 'first'").unwrap();
    assert_eq!(first.batch.num_rows(), 1);
    let error = run(&ctx, "SELECT * FROM frame").err().unwrap().to_string();
    assert!(
        error.contains("\"/e:x\"") && error.contains("\"second\""),
        "{error}"
    );
}
