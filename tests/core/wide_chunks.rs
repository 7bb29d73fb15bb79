//! Chunks of very many components, as a generated schema or a wide table makes them:
//! built from columns and row by row, inserted, queried, sent through transport and
//! compacted. Issue 12 found construction quadratic in the number of components (over ten
//! minutes for 100,000); these shapes now take well under a second, and the `chunk` bench
//! measures how the cost grows.
#![allow(
    clippy::unwrap_used,
    clippy::float_cmp,
    clippy::cast_precision_loss,
    reason = "tests fail loudly on unexpected values; test values are small integers, exact in f64"
)]

use crate::common;

use std::sync::Arc;

use arrow_array::{ArrayRef, Float64Array, Int64Array};
use chunkstore::{
    Chunk, ChunkBuilder, ChunkId, ChunkStore, ComponentDescriptor, LatestAtQuery, RowId,
    StoreConfig, Timeline,
};
use common::{f64_list, first_f64, path, t};

const NUM_COMPONENTS: usize = 100_000;

#[test]
fn a_chunk_of_100k_components_builds_inserts_and_answers() {
    let columns: Vec<(ComponentDescriptor, ArrayRef)> = (0..NUM_COMPONENTS)
        .map(|i| {
            let name = format!("c{i}");
            (
                ComponentDescriptor::new(name.as_str()),
                f64_list(&[Some(vec![i as f64])]),
            )
        })
        .collect();
    let from_columns = Chunk::try_new(
        ChunkId::new(),
        path("wide"),
        vec![RowId::from_u128(1)],
        vec![(
            Timeline::sequence("frame"),
            Arc::new(Int64Array::from(vec![1])) as ArrayRef,
        )],
        columns,
    )
    .unwrap();
    from_columns.sanity_check().unwrap();
    let back = Chunk::from_record_batch(&from_columns.to_record_batch().unwrap()).unwrap();
    assert_eq!(back.components().len(), NUM_COMPONENTS);

    let cells: Vec<(String, ArrayRef)> = (0..NUM_COMPONENTS)
        .map(|i| {
            let cell = Arc::new(Float64Array::from(vec![-(i as f64)])) as ArrayRef;
            (format!("c{i}"), cell)
        })
        .collect();
    let from_rows = ChunkBuilder::new(ChunkId::new(), path("wide"))
        .with_row(
            RowId::from_u128(2),
            [(Timeline::sequence("frame"), 2)],
            cells
                .iter()
                .map(|(name, cell)| (name.as_str(), Arc::clone(cell))),
        )
        .build()
        .unwrap();

    let mut store = ChunkStore::with_config(StoreConfig::DEFAULT).unwrap();
    store.insert(from_columns).unwrap();
    store.insert(from_rows).unwrap();
    store.compact();
    store.sanity_check().unwrap();
    assert_eq!(store.component_names(&path("wide")).len(), NUM_COMPONENTS);
    for (at, expected) in [(1, 77_777.0), (2, -77_777.0)] {
        let answer = store
            .latest_at(&LatestAtQuery::new("frame", t(at)), &path("wide"), "c77777")
            .unwrap();
        assert_eq!(first_f64(&answer.cell()), expected);
    }
}
