//! The body of the `ipc_insert` fuzz target, shared with the corpus replay test
//! (`tests/fuzz_corpus.rs`): arbitrary bytes go through Arrow IPC decoding, chunk
//! validation, a transport round trip, insertion and queries. Nothing may panic, a
//! decoded chunk must round-trip losslessly, and the store must stay sane.

use chunkstore::{Chunk, ChunkStore, LatestAtQuery, RangeQuery, TimeInt};

/// Query times worth probing: extremes, and around zero.
const PROBES: [i64; 5] = [i64::MIN + 1, -1, 0, 1, i64::MAX];

pub fn ipc_insert(bytes: &[u8]) {
    let Ok(chunks) = chunkstore::io::read_chunks_from_bytes(bytes) else {
        return;
    };
    let mut store = ChunkStore::new();
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
        let _ = store.insert(chunk);
        store
            .sanity_check()
            .expect("the store stays sane after any insert");
    }
    timelines.sort();
    timelines.dedup();
    for entity in store.entity_paths() {
        for component in store.component_names(&entity) {
            for timeline in &timelines {
                for at in PROBES {
                    let query = LatestAtQuery::new(timeline.as_str(), TimeInt::saturating(at));
                    if let Some(answer) = store.latest_at(&query, &entity, component.as_str()) {
                        let _ = answer.cell();
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
                }
            }
        }
    }
}
