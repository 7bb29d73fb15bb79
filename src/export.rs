//! [`StoreView::export_chunks`]: the chunks that rebuild a store answering as this one,
//! for writing it out (an `.rrd`, a directory of chunk files).

use std::sync::Arc;

use arrow_array::{ArrayRef, BooleanArray, ListArray};
use arrow_buffer::OffsetBuffer;
use arrow_schema::{DataType, Field};

use crate::{Chunk, ChunkId, ComponentDescriptor, ComponentName, EntityPath, RowId, StoreView};

impl StoreView {
    /// Every chunk a copy of this store needs to answer every query as this store does:
    /// first, for each chunk whose static Clears the store still applies although newer
    /// static data overwrote that chunk (SEMANTICS.md section 5: an overwritten static
    /// Clear keeps hiding what it hid), one static chunk of those Clear rows under its
    /// original chunk id (or a new id, if another chunk has taken that one since); then
    /// the chunks the store holds, by id. Inserting them, in this order or any other, into
    /// an empty store gives the same answers.
    ///
    /// ```
    /// # use std::sync::Arc;
    /// # use arrow_array::{ArrayRef, BooleanArray};
    /// # use chunkstore::*;
    /// let clear = |recursive: bool| {
    ///     ChunkBuilder::new(ChunkId::new(), EntityPath::parse("/a").unwrap())
    ///         .with_row(RowId::new(), [], [(ComponentName::CLEAR_IS_RECURSIVE,
    ///             Arc::new(BooleanArray::from(vec![recursive])) as ArrayRef)])
    ///         .build()
    ///         .unwrap()
    /// };
    /// let mut store = ChunkStore::new();
    /// store.insert(clear(true))?;
    /// store.insert(clear(false))?; // overwrites the first chunk; its Clear still counts
    /// assert_eq!(store.num_chunks(), 1);
    /// assert_eq!(store.export_chunks().len(), 2);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn export_chunks(&self) -> Vec<Arc<Chunk>> {
        let mut held = self.chunks();
        let by_id: ahash::HashMap<ChunkId, &Arc<Chunk>> =
            held.iter().map(|chunk| (chunk.id(), chunk)).collect();
        let mut taken_ids: ahash::HashSet<ChunkId> = by_id.keys().copied().collect();
        // A held chunk under the Clear's chunk id holds the Clear itself only if it is that
        // entity's static chunk with that row: the id may have been reused (by any chunk)
        // once the overwritten Clear's chunk left the store.
        let holds = |entity: &EntityPath, row_id: RowId, chunk_id: ChunkId| {
            by_id.get(&chunk_id).is_some_and(|chunk| {
                chunk.is_static()
                    && chunk.entity_path() == entity
                    && chunk.row_ids().contains(&row_id)
            })
        };
        // The retained Clears of one overwritten chunk go out as one chunk of their rows.
        let mut retained: std::collections::BTreeMap<(ChunkId, EntityPath), Vec<(RowId, bool)>> =
            std::collections::BTreeMap::new();
        for (entity, row_id, chunk_id, recursive) in self.clears.static_clears() {
            if !holds(&entity, row_id, chunk_id) {
                retained
                    .entry((chunk_id, entity))
                    .or_default()
                    .push((row_id, recursive));
            }
        }
        let mut retained: Vec<_> = retained.into_iter().collect();
        for (_, rows) in &mut retained {
            rows.sort_unstable();
        }
        retained.sort_by_key(|((chunk_id, _), rows)| (rows.first().map(|r| r.0), *chunk_id));
        let mut out: Vec<Arc<Chunk>> = Vec::with_capacity(retained.len() + held.len());
        for ((chunk_id, entity), rows) in retained {
            // The original id, unless a held chunk (or an earlier Clear chunk of the
            // export) took it since: then a new one, as two chunks under one id with other
            // contents would be refused when the export is read back.
            let chunk_id = if taken_ids.insert(chunk_id) {
                chunk_id
            } else {
                let fresh = ChunkId::new();
                taken_ids.insert(fresh);
                fresh
            };
            let flags = Arc::new(BooleanArray::from(
                rows.iter()
                    .map(|&(_, recursive)| recursive)
                    .collect::<Vec<_>>(),
            )) as ArrayRef;
            let list = ListArray::new(
                Arc::new(Field::new_list_field(DataType::Boolean, true)),
                OffsetBuffer::from_lengths(std::iter::repeat_n(1, rows.len())),
                flags,
                None,
            );
            let descriptor = ComponentDescriptor::new(ComponentName::CLEAR_IS_RECURSIVE);
            // Clears the store indexed make a valid static chunk.
            if let Ok(chunk) = Chunk::try_new(
                chunk_id,
                entity,
                rows.iter().map(|&(row_id, _)| row_id).collect(),
                Vec::new(),
                vec![(descriptor, Arc::new(list) as ArrayRef)],
            ) {
                out.push(Arc::new(chunk));
            }
        }
        held.sort_by_key(|chunk| chunk.id());
        out.extend(held);
        out
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::{ArrayRef, BooleanArray, Float64Array};

    use crate::{
        Chunk, ChunkBuilder, ChunkId, ChunkStore, ComponentName, EntityPath, LatestAtQuery, RowId,
        TimeInt, Timeline,
    };

    fn path(text: &str) -> EntityPath {
        EntityPath::parse(text).unwrap()
    }

    /// A static chunk of `/` with one Clear row per flag, in that order.
    fn static_clears(id: ChunkId, flags: &[bool]) -> Chunk {
        let mut builder = ChunkBuilder::new(id, path("/"));
        for &recursive in flags {
            let flag = Arc::new(BooleanArray::from(vec![recursive])) as ArrayRef;
            builder = builder.with_row(
                RowId::new(),
                [],
                [(ComponentName::CLEAR_IS_RECURSIVE, flag)],
            );
        }
        builder.build().unwrap()
    }

    fn value_at(id: ChunkId, entity: &str, frame: i64) -> Chunk {
        let value = Arc::new(Float64Array::from(vec![1.0])) as ArrayRef;
        ChunkBuilder::new(id, path(entity))
            .with_row(
                RowId::new(),
                [(Timeline::sequence("frame"), frame)],
                [("x", value)],
            )
            .build()
            .unwrap()
    }

    /// The store rebuilt from its export, checked for every chunk id used once.
    fn rebuilt(store: &ChunkStore) -> ChunkStore {
        let exported = store.export_chunks();
        let mut ids: Vec<ChunkId> = exported.iter().map(|c| c.id()).collect();
        ids.sort_unstable();
        assert!(ids.windows(2).all(|w| w[0] != w[1]), "one chunk per id");
        let mut copy = ChunkStore::new();
        for chunk in exported {
            copy.insert(chunk).unwrap();
        }
        copy.sanity_check().unwrap();
        copy
    }

    fn answers_x(store: &ChunkStore, entity: &str) -> bool {
        let query = LatestAtQuery::new("frame", TimeInt::new(5).unwrap());
        store.latest_at(&query, &path(entity), "x").is_some()
    }

    #[test]
    fn an_overwritten_clear_whose_id_was_reused_is_exported_under_a_new_id() {
        let mut store = ChunkStore::new();
        let reused = ChunkId::new();
        store.insert(value_at(ChunkId::new(), "a", 1)).unwrap();
        store.insert(static_clears(reused, &[true])).unwrap();
        store
            .insert(static_clears(ChunkId::new(), &[false]))
            .unwrap();
        assert!(store.chunk(reused).is_none(), "overwritten");
        // The freed id now names a temporal chunk of another entity.
        store.insert(value_at(reused, "b", 2)).unwrap();
        assert!(!answers_x(&store, "a") && !answers_x(&store, "b"));

        let copy = rebuilt(&store);
        assert!(!answers_x(&copy, "a"), "the recursive Clear still hides /a");
        assert!(!answers_x(&copy, "b"), "and /b");
        assert_eq!(
            copy.chunk(reused).map(|c| c.entity_path().clone()),
            Some(path("b"))
        );
        assert_eq!(copy.num_chunks(), store.num_chunks());
    }

    #[test]
    fn the_clears_of_one_overwritten_chunk_are_exported_as_one_chunk() {
        let mut store = ChunkStore::new();
        store.insert(value_at(ChunkId::new(), "a", 1)).unwrap();
        // Two Clear rows in one static chunk (the later one flat), then a newer flat one.
        let both = ChunkId::new();
        store.insert(static_clears(both, &[true, false])).unwrap();
        store
            .insert(static_clears(ChunkId::new(), &[false]))
            .unwrap();
        assert!(store.chunk(both).is_none(), "overwritten");
        assert!(!answers_x(&store, "a"));

        let exported = store.export_chunks();
        let retained: Vec<_> = exported.iter().filter(|c| c.id() == both).collect();
        assert_eq!(retained.len(), 1);
        assert_eq!(retained[0].num_rows(), 2);
        let copy = rebuilt(&store);
        assert!(!answers_x(&copy, "a"), "the recursive row still hides /a");
    }
}
