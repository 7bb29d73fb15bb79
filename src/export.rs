//! [`StoreView::export_chunks`]: the chunks that rebuild a store answering as this one,
//! for writing it out (an `.rrd`, a directory of chunk files).

use std::sync::Arc;

use arrow_array::{ArrayRef, BooleanArray, ListArray};
use arrow_buffer::OffsetBuffer;
use arrow_schema::{DataType, Field};

use crate::{Chunk, ChunkId, ComponentDescriptor, ComponentName, StoreView};

impl StoreView {
    /// Every chunk a copy of this store needs to answer every query as this store does:
    /// first one single-row static Clear chunk (under its original chunk id) for each
    /// static Clear the store still applies although newer static data overwrote the
    /// chunk that held it (SEMANTICS.md section 5: an overwritten static Clear keeps
    /// hiding what it hid), then the chunks the store holds, by id. Inserting them, in
    /// this order or any other, into an empty store gives the same answers.
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
        let held_ids: ahash::HashSet<ChunkId> = held.iter().map(|chunk| chunk.id()).collect();
        let mut retained: Vec<_> = self
            .clears
            .static_clears()
            .into_iter()
            .filter(|(_, _, chunk_id, _)| !held_ids.contains(chunk_id))
            .collect();
        retained.sort_by_key(|(_, row_id, chunk_id, _)| (*row_id, *chunk_id));
        let mut out: Vec<Arc<Chunk>> = Vec::with_capacity(retained.len() + held.len());
        for (entity, row_id, chunk_id, recursive) in retained {
            let flag = Arc::new(BooleanArray::from(vec![recursive])) as ArrayRef;
            let list = ListArray::new(
                Arc::new(Field::new_list_field(DataType::Boolean, true)),
                OffsetBuffer::from_lengths([1]),
                flag,
                None,
            );
            let descriptor = ComponentDescriptor::new(ComponentName::CLEAR_IS_RECURSIVE);
            // A Clear the store indexed is a valid one-row static chunk.
            if let Ok(chunk) = Chunk::try_new(
                chunk_id,
                entity,
                vec![row_id],
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
