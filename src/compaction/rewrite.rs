//! The rewrite both kinds of compaction share: rows of chunks of one layout, ordered by
//! `(time on the first timeline, row id)` and cut into balanced pieces within the
//! thresholds.

use std::sync::Arc;

use crate::ChunkError;
use crate::chunk::RowSource;
use crate::store::StoreConfig;
use crate::{Chunk, ChunkStore, StoreStats};

impl ChunkStore {
    /// [`rewrite`] of chunks the store holds (one layout), counted in its figures. Copying
    /// rows of valid chunks of one layout does not fail; if it ever did, a debug build
    /// says so (naming `what` was rewritten) and the caller, given `None`, leaves the
    /// chunks as they are, so no answer changes.
    pub(super) fn rewrite_held(&mut self, chunks: &[Arc<Chunk>], what: &str) -> Option<Vec<Chunk>> {
        let inputs: Vec<&Chunk> = chunks.iter().map(AsRef::as_ref).collect();
        match rewrite(&inputs, &self.config, &mut self.view.stats) {
            Ok(pieces) => Some(pieces),
            Err(error) => {
                debug_assert!(false, "{what}: {error}");
                None
            }
        }
    }
}

/// A chunk position or row of a rewrite's input, as a sort key's half.
#[expect(
    clippy::cast_possible_truncation,
    reason = "rows < 2^32 (checked in Chunk::from_raw); 2^32 input chunks would not fit in memory"
)]
fn source_u32(position: usize) -> u32 {
    debug_assert!(u32::try_from(position).is_ok());
    position as u32
}

/// Rewrites the rows of `inputs` (one layout) into as few chunks as the thresholds allow,
/// ordered by `(time on the first timeline, row id)`. Counts what it copies in `stats`.
pub(super) fn rewrite(
    inputs: &[&Chunk],
    config: &StoreConfig,
    stats: &mut StoreStats,
) -> Result<Vec<Chunk>, ChunkError> {
    let num_rows: usize = inputs.iter().map(|c| c.num_rows()).sum();
    let payload: u64 = inputs.iter().map(|c| c.payload_bytes()).sum();

    // Chunks whose rows are already in `(time, row id)` order on the first timeline,
    // each following the last, need no sort. (Times alone are not enough: rows of one
    // time would keep their input order.)
    let in_sequence = inputs
        .iter()
        .all(|c| c.time_columns()[0].index_order().is_none())
        && inputs.windows(2).all(|w| {
            let (last, first) = (
                w[0].time_columns()[0].time_range().max(),
                w[1].time_columns()[0].time_range().min(),
            );
            // Row ids only on a tie, as they live in another allocation.
            last < first
                || (last == first
                    && w[0].index_of_row(0, w[0].num_rows() - 1) <= w[1].index_of_row(0, 0))
        });
    let rows: Vec<RowSource> = if in_sequence {
        // Sized up front: a flattening collect knows no length and regrows.
        let mut rows = Vec::with_capacity(num_rows);
        for (c, chunk) in inputs.iter().enumerate() {
            rows.extend((0..chunk.num_rows()).map(|r| (c, r)));
        }
        rows
    } else {
        // Times read once into one array of 16-byte keys, then sorted: a sort calling
        // back into the chunks for every comparison cost a tenth of out-of-order
        // inserts, and keys carrying the row id were three times as large to move.
        // Row ids are read only to break a tie of times; the sort is stable, so equal
        // (time, row id) pairs keep input order.
        let mut keyed: Vec<(i64, u32, u32)> = Vec::with_capacity(num_rows);
        for (c, chunk) in inputs.iter().enumerate() {
            let times = chunk.time_columns()[0].times();
            for (r, &time) in times.iter().enumerate() {
                keyed.push((time, source_u32(c), source_u32(r)));
            }
        }
        let row_id = |&(_, c, r): &(i64, u32, u32)| inputs[c as usize].row_ids()[r as usize];
        keyed.sort_by(|a, b| a.0.cmp(&b.0).then_with(|| row_id(a).cmp(&row_id(b))));
        keyed
            .into_iter()
            .map(|(_, c, r)| (c as usize, r as usize))
            .collect()
    };
    // Rows are now in order on the first timeline; the others are checked.
    let sorted = (1..inputs[0].time_columns().len()).all(|t| {
        rows.windows(2).all(|w| {
            let time = |(c, r): RowSource| inputs[c].time_columns()[t].times()[r];
            time(w[0]) <= time(w[1])
        })
    });

    let max_rows = config.max_rows_for(sorted);
    let by_rows = num_rows.div_ceil(max_rows);
    let by_bytes = usize::try_from(payload.div_ceil(config.max_bytes)).unwrap_or(usize::MAX);
    let num_pieces = by_rows.max(by_bytes).clamp(1, num_rows.max(1));
    let pieces_rows = balanced_pieces(num_rows, num_pieces);

    let mut pieces = Vec::with_capacity(num_pieces);
    if let [single] = inputs
        && in_sequence
    {
        // Splitting a sorted chunk: slices share its buffers, nothing is copied.
        for piece in pieces_rows {
            pieces.push(single.slice(piece.start, piece.len())?);
        }
        return Ok(pieces);
    }
    for piece in pieces_rows {
        let piece = Chunk::gather(inputs, &rows[piece])?;
        stats.rows_copied_by_compaction += piece.num_rows() as u64;
        stats.payload_bytes_copied_by_compaction += piece.payload_bytes();
        pieces.push(piece);
    }
    Ok(pieces)
}

/// `0..num_rows` cut into `num_pieces` consecutive ranges whose lengths differ by at most
/// one (the longer first): exactly as many pieces as the thresholds ask for, none of them a
/// small remainder.
pub(crate) fn balanced_pieces(
    num_rows: usize,
    num_pieces: usize,
) -> impl Iterator<Item = std::ops::Range<usize>> {
    let (base, longer) = (num_rows / num_pieces, num_rows % num_pieces);
    (0..num_pieces).scan(0, move |start, piece| {
        let len = base + usize::from(piece < longer);
        let range = *start..*start + len;
        *start += len;
        Some(range)
    })
}
