//! The store side of every fuzz target, shared with the corpus replay test: chunks (decoded
//! or built from arbitrary input) go through a transport round trip, insertion into a
//! store without compaction and one compacting with tiny thresholds (a chunk repeated in
//! the input is inserted again: ingest is idempotent), every query, then the whole
//! lifecycle: on-demand compaction, a range drop, garbage collection and entity drops.
//! Nothing may panic, a chunk must round-trip losslessly, the stores must stay sane after
//! every mutation, and compaction must not change which rows answer.

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type, Int64Type};
use arrow_array::{Array, ArrowPrimitiveType};
use arrow_buffer::ToByteSlice;
use chunkstore::{
    Chunk, ChunkStore, ComponentColumn, GcOptions, InsertError, LatestAtQuery, RangeQuery, RowId,
    StoreConfig, TimeInt, TimeRange,
};

/// Query times worth probing: extremes, and around zero.
const PROBES: [i64; 5] = [i64::MIN + 1, -1, 0, 1, i64::MAX];

/// Runs `chunks`, in order, through everything a store does.
pub fn exercise(chunks: Vec<Chunk>) {
    let mut store = ChunkStore::with_config(StoreConfig::COMPACTION_OFF).expect("a valid config");
    // Tiny thresholds: nearly every chunk is split, merged or both.
    let mut compacting = ChunkStore::with_config(
        StoreConfig::DEFAULT
            .with_max_rows(2)
            .with_max_rows_unsorted(1)
            .with_max_bytes(64)
            .with_merge_fanout(2),
    )
    .expect("a valid config");
    let mut timelines = Vec::new();
    for chunk in chunks {
        let batch = chunk
            .to_record_batch()
            .expect("a valid chunk always encodes");
        let again = Chunk::from_record_batch(&batch).expect("a chunk's own batch decodes");
        assert_eq!(
            again.to_record_batch().expect("encodes"),
            batch,
            "transport round trip is lossless"
        );
        for column in chunk.time_columns() {
            timelines.push(column.timeline().name().to_owned());
        }
        // Conflicting chunks are rejected with an error; either way the store stays sane.
        let chunk = std::sync::Arc::new(chunk);
        let outcome = store.insert(std::sync::Arc::clone(&chunk));
        store
            .sanity_check()
            .expect("the store stays sane after any insert");
        // The same chunk again changes nothing in either store (its rows are held), but
        // another chunk under a held id is refused only while a store holds the first as
        // itself, which compaction may have merged away: the compacting store skips those.
        if let Err(InsertError::ChunkIdConflict { .. }) = outcome {
            continue;
        }
        let accepted = outcome.is_ok();
        assert_eq!(
            compacting.insert(chunk).is_ok(),
            accepted,
            "compaction does not change what is accepted"
        );
        compacting
            .sanity_check()
            .expect("the store stays sane after any compacting insert");
    }
    timelines.sort();
    timelines.dedup();
    query_everything(&store, &timelines);
    let answers = answer_keys(&store, &timelines);
    assert_eq!(
        answer_keys(&compacting, &timelines),
        answers,
        "compaction on insert changes no answer"
    );
    store.compact();
    store.sanity_check().expect("sane after compact()");
    assert_eq!(
        answer_keys(&store, &timelines),
        answers,
        "compact() changes no answer"
    );
    for store in [&mut store, &mut compacting] {
        if let Some(timeline) = timelines.first() {
            store.drop_time_range(
                timeline,
                TimeRange::new(TimeInt::saturating(-1), TimeInt::saturating(1)),
            );
            store.sanity_check().expect("sane after drop_time_range");
        }
        store.gc(&GcOptions::drop_at_least_fraction(0.5).expect("0.5 is a valid fraction"));
        store.sanity_check().expect("sane after gc");
        for entity in store.entity_paths() {
            store.drop_entity(&entity, false);
            store.sanity_check().expect("sane after drop_entity");
        }
        assert_eq!(
            store.stats().num_chunks(),
            0,
            "dropping every entity empties it"
        );
    }
}

/// Which rows answer every latest-at probe and every full range: `(time, row id)` keys
/// (cells are left out: duplicated row ids, legal but odd, make them ambiguous).
type AnswerKey = (Option<TimeInt>, RowId);

fn answer_keys(store: &ChunkStore, timelines: &[String]) -> Vec<Vec<AnswerKey>> {
    let mut answers = Vec::new();
    for entity in store.entity_paths() {
        for component in store.component_names(&entity) {
            for timeline in timelines {
                for at in PROBES {
                    let query = LatestAtQuery::new(timeline.as_str(), TimeInt::saturating(at));
                    let answer = store.latest_at(&query, &entity, component.as_str());
                    answers.push(answer.map(|a| (a.time(), a.row_id())).into_iter().collect());
                }
                let range = store.range(
                    &RangeQuery::everything(timeline.as_str()),
                    &entity,
                    component.as_str(),
                );
                answers.push(range.iter().map(|r| (r.time(), r.row_id())).collect());
            }
        }
    }
    answers
}

/// Runs every query and touches every cell: nothing may panic, ranges ascend.
fn query_everything(store: &ChunkStore, timelines: &[String]) {
    for entity in store.entity_paths() {
        for component in store.component_names(&entity) {
            for timeline in timelines {
                for at in PROBES {
                    let query = LatestAtQuery::new(timeline.as_str(), TimeInt::saturating(at));
                    if let Some(answer) = store.latest_at(&query, &entity, component.as_str()) {
                        let _ = answer.cell();
                        typed_reads_agree(answer.column(), answer.row());
                    }
                }
                let range = store.range(
                    &RangeQuery::everything(timeline.as_str()),
                    &entity,
                    component.as_str(),
                );
                let mut previous = None;
                for row in range.iter() {
                    let key = (row.time(), row.row_id());
                    assert!(previous <= Some(key), "range rows ascend");
                    previous = Some(key);
                    let _ = row.cell();
                    typed_reads_agree(row.column(), row.row());
                }
            }
        }
    }
}

/// The typed slice readers return exactly the values of the cell Arrow gives, and nothing
/// for a cell of another type.
fn typed_reads_agree(column: &ComponentColumn, row: usize) {
    let cell = column.cell(row);
    same_values::<Float64Type>(column.primitive_values::<Float64Type>(row), cell.as_deref());
    same_values::<Int64Type>(column.primitive_values::<Int64Type>(row), cell.as_deref());
    let points = column.fixed_size_values::<Float32Type, 3>(row);
    let cell_points = cell.as_deref().and_then(|c| c.as_fixed_size_list_opt());
    match (points, cell_points) {
        (Some(points), Some(fixed)) if fixed.value_length() == 3 => {
            same_values::<Float32Type>(Some(points.as_flattened()), Some(fixed.values().as_ref()));
        }
        (Some(_), _) => panic!("read as points, but the cell is not fixed-size lists of 3"),
        (None, _) => {}
    }
}

fn same_values<T: ArrowPrimitiveType>(read: Option<&[T::Native]>, cell: Option<&dyn Array>) {
    let Some(read) = read else {
        return;
    };
    let cell = cell
        .and_then(|c| c.as_primitive_opt::<T>())
        .expect("a cell read as values is an array of that type");
    assert_eq!(
        cell.values().inner().as_slice(),
        read.to_byte_slice(),
        "a typed read returns the cell's values (bit for bit: NaNs included)"
    );
}
