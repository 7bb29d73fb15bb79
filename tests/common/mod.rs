//! Helpers shared by the integration tests: terse chunk construction.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::float_cmp,
    reason = "tests fail loudly on unexpected values; test values are small integers, exact in f64"
)]
#![allow(dead_code, reason = "each test file uses a different subset")]

pub mod repo;

use std::sync::Arc;

use arrow_array::builder::{BooleanBuilder, Float64Builder, ListBuilder};
use arrow_array::{Array, ArrayRef, Float64Array, Int64Array};
use chunkstore::{Chunk, ChunkId, ComponentName, EntityPath, RowId, TimeInt, Timeline};

/// Writes `chunks` as recording `id` (application `app`) to `dir/name`, with a footer.
pub fn write_recording(
    dir: &std::path::Path,
    name: &str,
    id: &str,
    chunks: Vec<Chunk>,
) -> std::path::PathBuf {
    use chunkstore::rrd::{StoreId, StoreInfo, write_rrd_file};
    let path = dir.join(name);
    let info = StoreInfo::new(StoreId::recording("app", id));
    write_rrd_file(&path, &info, chunks.into_iter().map(Arc::new), |_| {}).unwrap();
    path
}

/// Three recordings of different shapes, each with a footer: entities and components only
/// some share, a Clear, static data, and one without the `frame` timeline's data (static
/// only). The datasets of the core, SQL and Parquet tests start from them.
pub fn episodes(dir: &std::path::Path) {
    write_recording(
        dir,
        "first.rrd",
        "rec-b",
        vec![
            scalars(
                "/robot/arm",
                "angle",
                &[(1, 1, Some(vec![0.5])), (3, 2, Some(vec![1.5]))],
            ),
            scalars("/robot/leg", "angle", &[(2, 3, Some(vec![2.5]))]),
            static_scalar("/robot", "mass", 4, 70.0),
        ],
    );
    write_recording(
        dir,
        "second.rrd",
        "rec-a",
        vec![
            scalars(
                "/robot/arm",
                "angle",
                &[(5, 10, Some(vec![9.0])), (2, 11, None)],
            ),
            scalars("/camera", "exposure", &[(4, 12, Some(vec![0.01]))]),
            clear("/robot", Some(6), 13, true),
        ],
    );
    write_recording(
        dir,
        "static_only.rrd",
        "rec-s",
        vec![static_scalar("/robot", "mass", 20, 80.0)],
    );
}

/// Writes `chunks` as recording `id` without a footer (a stream cut before its end).
pub fn write_without_footer(
    dir: &std::path::Path,
    name: &str,
    id: &str,
    chunks: Vec<Chunk>,
) -> std::path::PathBuf {
    let mut bytes = Vec::new();
    {
        let info = chunkstore::rrd::StoreInfo::new(chunkstore::rrd::StoreId::recording("app", id));
        let mut writer =
            chunkstore::rrd::RrdWriter::with_store_info(&mut bytes, &info, true).unwrap();
        for chunk in chunks {
            writer.write_chunk(&Arc::new(chunk)).unwrap();
        }
    }
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

/// `answer` has `expected`'s fields and rows, and each column its cells.
pub fn assert_same_cells(
    answer: &arrow_array::RecordBatch,
    expected: &arrow_array::RecordBatch,
    context: &str,
) {
    assert_eq!(
        answer.schema().fields(),
        expected.schema().fields(),
        "{context}"
    );
    assert_eq!(answer.num_rows(), expected.num_rows(), "{context}");
    for i in 0..expected.num_columns() {
        assert_eq!(
            answer.column(i).to_data(),
            expected.column(i).to_data(),
            "{context}: column {}",
            expected.schema().field(i).name()
        );
    }
}

pub fn path(text: &str) -> EntityPath {
    EntityPath::parse(text).unwrap()
}

pub fn t(value: i64) -> TimeInt {
    TimeInt::new(value).unwrap()
}

pub fn rid(value: u128) -> RowId {
    RowId::from_u128(value)
}

/// A `List<Float64>` column: `None` is a null cell, `Some(vec![])` an empty list.
pub fn f64_list(cells: &[Option<Vec<f64>>]) -> ArrayRef {
    let mut builder = ListBuilder::new(Float64Builder::new());
    for cell in cells {
        match cell {
            Some(values) => {
                builder.values().append_slice(values);
                builder.append(true);
            }
            None => builder.append(false),
        }
    }
    Arc::new(builder.finish())
}

/// A `List<Boolean>` column of one-instance cells (`Clear:is_recursive`).
pub fn bool_list(cells: &[Option<bool>]) -> ArrayRef {
    let mut builder = ListBuilder::new(BooleanBuilder::new());
    for cell in cells {
        match cell {
            Some(value) => {
                builder.values().append_value(*value);
                builder.append(true);
            }
            None => builder.append(false),
        }
    }
    Arc::new(builder.finish())
}

/// A temporal chunk on one sequence timeline `frame` with one `List<Float64>` component.
/// Rows: `(time, row id, cell)`.
pub fn scalars(entity: &str, component: &str, rows: &[(i64, u128, Option<Vec<f64>>)]) -> Chunk {
    Chunk::try_new(
        ChunkId::new(),
        path(entity),
        rows.iter().map(|r| rid(r.1)).collect(),
        vec![(
            Timeline::sequence("frame"),
            Arc::new(Int64Array::from(
                rows.iter().map(|r| r.0).collect::<Vec<_>>(),
            )) as ArrayRef,
        )],
        vec![(
            component.into(),
            f64_list(&rows.iter().map(|r| r.2.clone()).collect::<Vec<_>>()),
        )],
    )
    .unwrap()
}

/// A one-row chunk at `frame = time` of one `List<Boolean>` component holding `value`
/// (a column of another type than [`scalars`]' floats).
pub fn boolean(entity: &str, component: &str, time: i64, row_id: u128, value: bool) -> Chunk {
    Chunk::try_new(
        ChunkId::new(),
        path(entity),
        vec![rid(row_id)],
        vec![(
            Timeline::sequence("frame"),
            Arc::new(Int64Array::from(vec![time])) as ArrayRef,
        )],
        vec![(component.into(), bool_list(&[Some(value)]))],
    )
    .unwrap()
}

/// A one-row scalar chunk at `frame = time`.
pub fn scalar(entity: &str, component: &str, time: i64, row_id: u128, value: f64) -> Chunk {
    scalars(entity, component, &[(time, row_id, Some(vec![value]))])
}

/// A static chunk with one row of one `List<Float64>` component.
pub fn static_scalar(entity: &str, component: &str, row_id: u128, value: f64) -> Chunk {
    Chunk::try_new(
        ChunkId::new(),
        path(entity),
        vec![rid(row_id)],
        vec![],
        vec![(component.into(), f64_list(&[Some(vec![value])]))],
    )
    .unwrap()
}

/// A one-row Clear at `frame = time`, or static when `time` is `None`.
pub fn clear(entity: &str, time: Option<i64>, row_id: u128, recursive: bool) -> Chunk {
    let times = time
        .map(|time| {
            vec![(
                Timeline::sequence("frame"),
                Arc::new(Int64Array::from(vec![time])) as ArrayRef,
            )]
        })
        .unwrap_or_default();
    Chunk::try_new(
        ChunkId::new(),
        path(entity),
        vec![rid(row_id)],
        times,
        vec![(
            ComponentName::CLEAR_IS_RECURSIVE.into(),
            bool_list(&[Some(recursive)]),
        )],
    )
    .unwrap()
}

/// The first `f64` of a cell.
pub fn first_f64(cell: &ArrayRef) -> f64 {
    cell.as_any()
        .downcast_ref::<Float64Array>()
        .unwrap()
        .value(0)
}

/// Length of a cell (number of instances).
pub fn cell_len(cell: &ArrayRef) -> usize {
    cell.len()
}

/// The robot recording that Rerun 0.41's SDK wrote: its directory (the `.rrd` file and
/// the `chunks/` it was written from).
pub fn robot_recording() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("testdata/rerun-0.41/a_robot")
}

/// The robot recording's chunk files (`.arrow`), sorted by name.
pub fn robot_chunk_files() -> Vec<std::path::PathBuf> {
    let mut files: Vec<std::path::PathBuf> = std::fs::read_dir(robot_recording().join("chunks"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "arrow"))
        .collect();
    files.sort();
    files
}

/// The chunks of the robot recording's chunk files, in file name order.
pub fn robot_chunks() -> Vec<Chunk> {
    robot_chunk_files()
        .iter()
        .flat_map(|f| chunkstore::ipc::read_chunks_from_path(f).unwrap())
        .collect()
}

/// The robot recording, loaded from its chunk files in name order into a store of the
/// default configuration.
pub fn robot() -> chunkstore::ChunkStore {
    let mut store = chunkstore::ChunkStore::new();
    for chunk in robot_chunks() {
        store.insert(chunk).unwrap();
    }
    store
}

/// A fresh, empty directory under the system's temporary directory, removed with everything
/// in it when dropped (when the test ends, passing or failing), so test runs leave nothing
/// behind. Named by `name` and the process id: tests of one run that run at once need
/// different names.
pub struct ScratchDir(std::path::PathBuf);

impl ScratchDir {
    pub fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("chunkstore-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }
}

impl std::ops::Deref for ScratchDir {
    type Target = std::path::Path;

    fn deref(&self) -> &std::path::Path {
        &self.0
    }
}

impl AsRef<std::path::Path> for ScratchDir {
    fn as_ref(&self) -> &std::path::Path {
        &self.0
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// What Rerun 0.41 checks of a chunk before it loads it (`ChunkStore::insert_chunk`:
/// "Chunks must be sorted before insertion"): its row ids in ascending order. Every chunk
/// of every file we write must pass, or Rerun's SDK and viewer refuse the file.
pub fn assert_rerun_loads(chunk: &Chunk) {
    assert!(
        chunk.row_ids().is_sorted(),
        "chunk {} has its row ids out of order: Rerun refuses it",
        chunk.id()
    );
}

/// Every chunk of an `.rrd` file's bytes (recordings only), each checked with
/// [`assert_rerun_loads`].
pub fn rrd_chunks_rerun_loads(bytes: Vec<u8>) -> Vec<Chunk> {
    let contents = chunkstore::rrd::read_rrd(arrow_buffer::Buffer::from_vec(bytes), false).unwrap();
    let chunks: Vec<Chunk> = contents.chunks.into_iter().map(|(_, c)| c).collect();
    chunks.iter().for_each(assert_rerun_loads);
    chunks
}

/// Where a property test keeps its failing seeds: `tests/proptest-regressions/{file}`
/// (`binary/module.txt`, one file per test binary and module), read before any new case
/// and added to on a failure. proptest's default derives the file from the source's path:
/// when the tests moved into folders, 16 seeds stayed where nothing read them.
/// `tests/core/seeds.rs` fails on a seed file that no test names.
#[allow(
    clippy::unnecessary_wraps,
    reason = "the value of `ProptestConfig::failure_persistence`, an `Option`"
)]
pub fn seed_file(file: &str) -> Option<Box<dyn proptest::test_runner::FailurePersistence>> {
    let path: &'static str =
        Box::leak(format!("tests/proptest-regressions/{file}").into_boxed_str());
    Some(Box::new(
        proptest::test_runner::FileFailurePersistence::Direct(path),
    ))
}

/// The same table: equal column names in order, rows, and every column's values, where the
/// schemas may differ in metadata (DataFusion's, a Parquet file's read back).
pub fn assert_same_table(
    ours: &arrow_array::RecordBatch,
    expected: &arrow_array::RecordBatch,
    what: &str,
) {
    let names = |b: &arrow_array::RecordBatch| -> Vec<String> {
        b.schema()
            .fields()
            .iter()
            .map(|f| f.name().clone())
            .collect()
    };
    assert_eq!(names(ours), names(expected), "{what}: columns");
    assert_eq!(ours.num_rows(), expected.num_rows(), "{what}: rows");
    for (i, name) in names(expected).iter().enumerate() {
        assert_eq!(
            ours.column(i).to_data(),
            expected.column(i).to_data(),
            "{what}: column {name}"
        );
    }
}
