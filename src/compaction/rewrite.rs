//! The rewrite both kinds of compaction share: rows of chunks of one layout, ordered by
//! `(time on the first timeline, row id)` and cut into balanced pieces within the
//! thresholds.

use std::sync::Arc;

use crate::ChunkError;
use crate::chunk::{RowColumns, RowSource};
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

impl ChunkStore {
    /// The merge of a write buffer's full fan, built from the rows its group copied into
    /// `columns` as they arrived: one chunk, the same rows in the same order as
    /// [`rewrite`] gives, without reading the chunks again. `None` where the merge must
    /// gather instead: the result would exceed a threshold (`rewrite` then cuts pieces in
    /// bounded blocks), or, were the columns ever not the fan's rows, they are not used
    /// (a debug build says so).
    pub(super) fn merge_from_columns(
        &mut self,
        columns: RowColumns,
        fan: &[Arc<Chunk>],
    ) -> Option<Vec<Chunk>> {
        let rows: usize = fan.iter().map(|chunk| chunk.num_rows()).sum();
        let merged = match fan.first().and_then(|layout| columns.build(layout)) {
            Some(Ok(merged)) if merged.num_rows() == rows => merged,
            built => {
                debug_assert!(
                    false,
                    "a write buffer's columns are not its fan's rows: {built:?}"
                );
                return None;
            }
        };
        if self.config.is_oversized(&merged) {
            return None;
        }
        self.view.stats.rows_copied_by_compaction += merged.num_rows() as u64;
        self.view.stats.payload_bytes_copied_by_compaction += merged.payload_bytes();
        Some(vec![merged])
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
        // Each input's rows are one run in `(time, row id)` order (row order, or the
        // order its time column keeps), so the runs are merged rather than sorted: a
        // stable sort of concatenated short runs (a fan of 16 one-row merges) found too
        // few runs to use and quicksorted, a tenth of out-of-order inserts. Keys are
        // times read once into 16-byte entries; a row id is read only on a tie of times.
        let mut keyed: Vec<SortKey> = Vec::with_capacity(num_rows);
        let mut run_ends = Vec::with_capacity(inputs.len());
        for (c, chunk) in inputs.iter().enumerate() {
            let column = &chunk.time_columns()[0];
            let times = column.times();
            match column.index_order() {
                None => keyed.extend(
                    times
                        .iter()
                        .enumerate()
                        .map(|(r, &time)| (time, source_u32(c), source_u32(r))),
                ),
                Some(order) => {
                    keyed.extend(order.iter().map(|&r| (times[r as usize], source_u32(c), r)));
                }
            }
            run_ends.push(keyed.len());
        }
        let row_id = |&(_, c, r): &SortKey| inputs[c as usize].row_ids()[r as usize];
        let before = |a: &SortKey, b: &SortKey| a.0 < b.0 || (a.0 == b.0 && row_id(a) < row_id(b));
        merge_runs(keyed, &run_ends, before)
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
    // Small pieces are gathered a block at a time, each block then sliced into its
    // pieces: a gather has a cost per column and per call (arrays built, the chunk
    // validated), which pieces of a few rows paid once each. A block stays small, so a
    // piece that garbage collection drops frees its memory once its few block-mates go,
    // never only with a whole group.
    let pieces_per_block =
        usize::try_from(GATHER_BLOCK_BYTES / (payload / num_pieces as u64).max(1))
            .unwrap_or(usize::MAX)
            .max(1);
    let pieces_rows: Vec<std::ops::Range<usize>> = pieces_rows.collect();
    for block in pieces_rows.chunks(pieces_per_block) {
        let (Some(first), Some(last)) = (block.first(), block.last()) else {
            continue;
        };
        let gathered = Chunk::gather(inputs, &rows[first.start..last.end])?;
        stats.rows_copied_by_compaction += gathered.num_rows() as u64;
        stats.payload_bytes_copied_by_compaction += gathered.payload_bytes();
        if let [_] = block {
            pieces.push(gathered);
            continue;
        }
        for piece in block {
            pieces.push(gathered.slice(piece.start - first.start, piece.len())?);
        }
    }
    Ok(pieces)
}

/// A row of a rewrite's input as it is ordered: its time on the first timeline, its
/// chunk and its row.
type SortKey = (i64, u32, u32);

/// `keys`, runs each in order by `before` (run `i` ends at `run_ends[i]`), merged into one
/// order, stably: of keys neither before the other, an earlier run's comes first. Pairs
/// of neighbouring runs are merged a pass at a time, `log2(runs)` passes in all, between
/// `keys` and one scratch vector; a pair already in order is copied.
fn merge_runs(
    keys: Vec<SortKey>,
    run_ends: &[usize],
    before: impl Fn(&SortKey, &SortKey) -> bool,
) -> Vec<SortKey> {
    let mut ends = run_ends.to_vec();
    let mut to = vec![(0, 0, 0); keys.len()];
    let mut from = keys;
    while ends.len() > 1 {
        let mut start = 0;
        let mut merged_ends = Vec::with_capacity(ends.len().div_ceil(2));
        for pair in ends.chunks(2) {
            let (middle, end) = match *pair {
                [middle, end] => (middle, end),
                [end] => (end, end),
                _ => unreachable!("chunks(2) gives one or two"),
            };
            let (left, right) = (&from[start..middle], &from[middle..end]);
            let out = &mut to[start..end];
            match (left.last(), right.first()) {
                (Some(last), Some(first)) if before(first, last) => {
                    merge_two(left, right, out, &before);
                }
                _ => {
                    out[..left.len()].copy_from_slice(left);
                    out[left.len()..].copy_from_slice(right);
                }
            }
            merged_ends.push(end);
            start = end;
        }
        std::mem::swap(&mut from, &mut to);
        ends = merged_ends;
    }
    from
}

/// Writes the merge of the ordered `left` and `right` to `out` (as long as both),
/// `left`'s first on a tie.
fn merge_two(
    mut left: &[SortKey],
    mut right: &[SortKey],
    out: &mut [SortKey],
    before: &impl Fn(&SortKey, &SortKey) -> bool,
) {
    for slot in out {
        *slot = match (left.split_first(), right.split_first()) {
            (Some((l, left_rest)), Some((r, right_rest))) => {
                if before(r, l) {
                    right = right_rest;
                    *r
                } else {
                    left = left_rest;
                    *l
                }
            }
            (Some((l, rest)), None) => {
                left = rest;
                *l
            }
            (None, Some((r, rest))) => {
                right = rest;
                *r
            }
            (None, None) => return,
        };
    }
}

/// About the most payload one gather of a rewrite copies for pieces smaller than it (see
/// [`rewrite`]; blocks hold as many pieces of the average size as fit): enough to spread a
/// gather's fixed cost over pieces of a few rows, small enough that pieces sharing a
/// block's buffers pin little memory.
const GATHER_BLOCK_BYTES: u64 = 64 * 1024;

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

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;
    use std::sync::Arc;

    use arrow_array::{Array, ArrayRef, Float64Array};

    use super::*;
    use crate::{ChunkBuilder, ChunkId, EntityPath, RowId, Timeline};

    /// `num_rows` one-row chunks in reverse time order (so the rewrite sorts and copies),
    /// each row a cell of `values_per_row` floats.
    fn reversed_rows(num_rows: i64, values_per_row: usize) -> Vec<Chunk> {
        (0..num_rows)
            .rev()
            .map(|frame| {
                let values = vec![1.0; values_per_row];
                ChunkBuilder::new(ChunkId::new(), EntityPath::parse("e").unwrap())
                    .with_row(
                        RowId::new(),
                        [(Timeline::sequence("frame"), frame)],
                        [("x", Arc::new(Float64Array::from(values)) as ArrayRef)],
                    )
                    .build()
                    .unwrap()
            })
            .collect()
    }

    /// How many pieces share each values allocation, by its address.
    fn pieces_per_allocation(pieces: &[Chunk]) -> Vec<usize> {
        let mut counts = BTreeMap::new();
        for piece in pieces {
            let values = piece.components()[0].list_array().values().to_data();
            *counts
                .entry(values.buffers()[0].as_ptr().addr())
                .or_insert(0) += 1;
        }
        counts.into_values().collect()
    }

    fn rewritten(chunks: &[Chunk], config: &StoreConfig) -> Vec<Chunk> {
        let inputs: Vec<&Chunk> = chunks.iter().collect();
        let pieces = rewrite(&inputs, config, &mut StoreStats::default()).unwrap();
        // Whatever the blocks, the rows come out in time order, cut as the thresholds say.
        let times: Vec<i64> = pieces
            .iter()
            .flat_map(|p| p.time_columns()[0].times().to_vec())
            .collect();
        let num_rows = i64::try_from(chunks.len()).unwrap();
        assert_eq!(times, (0..num_rows).collect::<Vec<_>>());
        assert!(pieces.iter().all(|p| !config.is_oversized(p)));
        pieces
    }

    #[test]
    fn rows_of_unsorted_chunks_merge_in_time_then_row_id_order() {
        // Three chunks, two with rows out of time order, sharing times: the rewrite must
        // order by time, then row id, across chunks (a stable sort of keys made in row order).
        let ids: Vec<RowId> = (0..9).map(|_| RowId::new()).collect();
        let chunk = |rows: &[(i64, u8)]| {
            let mut builder = ChunkBuilder::new(ChunkId::new(), EntityPath::parse("e").unwrap());
            for &(frame, id) in rows {
                builder = builder.with_row(
                    ids[usize::from(id)],
                    [(Timeline::sequence("frame"), frame)],
                    [(
                        "x",
                        Arc::new(Float64Array::from(vec![f64::from(id)])) as ArrayRef,
                    )],
                );
            }
            builder.build().unwrap()
        };
        let chunks = [
            chunk(&[(3, 0), (1, 4), (2, 2)]),
            chunk(&[(1, 1), (2, 3), (3, 5)]),
            chunk(&[(2, 8), (1, 6), (3, 7)]),
        ];
        let inputs: Vec<&Chunk> = chunks.iter().collect();
        let pieces = rewrite(&inputs, &StoreConfig::DEFAULT, &mut StoreStats::default()).unwrap();
        assert_eq!(pieces.len(), 1);
        let values = pieces[0].components()[0].list_array().values().clone();
        let values = values.as_any().downcast_ref::<Float64Array>().unwrap();
        assert_eq!(
            values.values().to_vec(),
            [1.0, 4.0, 6.0, 2.0, 3.0, 8.0, 0.0, 5.0, 7.0]
        );
        assert_eq!(
            pieces[0].time_columns()[0].times(),
            [1, 1, 1, 2, 2, 2, 3, 3, 3]
        );
    }

    /// Runs of every length (empty ones too, and an odd number of them), with ties of
    /// the first key half across and within runs, merge into what a stable sort of the
    /// same keys gives.
    #[test]
    fn merging_runs_equals_a_stable_sort() {
        let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = |bound: u64| {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            (seed >> 33) % bound
        };
        for case in 0..500 {
            let num_runs = next(9) + 1;
            let (mut keys, mut ends) = (Vec::new(), Vec::new());
            for run in 0..num_runs {
                let mut times: Vec<i64> = (0..next(7))
                    .map(|_| i64::try_from(next(5)).unwrap())
                    .collect();
                times.sort_unstable();
                for (row, time) in times.into_iter().enumerate() {
                    keys.push((
                        time,
                        source_u32(usize::try_from(run).unwrap()),
                        source_u32(row),
                    ));
                }
                ends.push(keys.len());
            }
            // Ordered by time alone, so ties fall to the runs' order.
            let before = |a: &SortKey, b: &SortKey| a.0 < b.0;
            let mut expected = keys.clone();
            expected.sort_by_key(|key| key.0);
            assert_eq!(merge_runs(keys, &ends, before), expected, "case {case}");
        }
    }

    #[test]
    fn small_pieces_share_a_bounded_block_and_large_ones_stand_alone() {
        let config = StoreConfig::COMPACTION_OFF.with_max_rows(3);
        // 3,000 rows of one float: 1,000 pieces of about 80 payload bytes, gathered a block
        // of GATHER_BLOCK_BYTES at a time.
        let pieces = rewritten(&reversed_rows(3000, 1), &config);
        assert_eq!(pieces.len(), 1000);
        let shares = pieces_per_allocation(&pieces);
        assert!(shares.len() > 1, "blocks are bounded: {shares:?}");
        assert!(
            shares.iter().all(|&n| n > 1),
            "small pieces share: {shares:?}"
        );
        let block_bytes: u64 = pieces[..shares[0]].iter().map(Chunk::payload_bytes).sum();
        assert!(block_bytes <= GATHER_BLOCK_BYTES, "{block_bytes}");

        // Rows of 10,000 floats: each piece outweighs a block, so each is its own gather.
        let pieces = rewritten(&reversed_rows(9, 10_000), &config);
        assert_eq!(pieces.len(), 3);
        assert_eq!(pieces_per_allocation(&pieces), [1, 1, 1]);
    }
}
