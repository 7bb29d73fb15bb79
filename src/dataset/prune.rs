//! Which chunks of a segment a dataframe needs, read from its footer's manifest, so that a
//! query over a range or a few entities decodes those and not the whole file.
//!
//! The store built from them answers the query exactly as the whole segment would:
//! - its **columns** (and index columns) are planned from every (entity, component,
//!   timeline) of the selected entities, so one chunk of each is taken;
//! - its **rows and cells** in the range come from the selected entities' chunks whose
//!   rows on the index overlap it, and their static chunks;
//! - a **filled** cell is a latest-at answer at a row's time `t` in the range: one at the
//!   range's start (section 3's rule, as the lazy reader applies it: of the chunks whose
//!   cells start by then, those reaching the greatest such start), or a cell inside the
//!   range, which the range's own chunks hold;
//! - **Clears** anywhere (every chunk with a `Clear:is_recursive` column: they are few,
//!   and an ancestor's may hide or mark a selected entity's cells).
//!
//! A chunk a query does not need cannot change its answer (it holds no cell in the range,
//! and cannot be the latest-at answer at its start), so extra chunks are harmless.
//! Sampled values and dropping semantically empty columns are not pruned: the first asks
//! latest-at at every value, the second reads every cell of a column.

use std::collections::{HashMap, HashSet};

use crate::rrd::Manifest;
use crate::{ChunkId, ComponentName, DataframeQuery, EntityPath, TimeInt, TimeRange};

/// A column's chunks whose cells on the index start by the range's start: each chunk's id
/// and its cells' least and greatest time there.
type StartingBefore = Vec<(ChunkId, TimeInt, TimeInt)>;

/// Can `query` be answered from the chunks [`needed`] picks?
pub(super) fn prunable(query: &DataframeQuery) -> bool {
    query.index_values().is_none() && query.keeps_semantically_empty_columns()
}

/// The chunks that give every column of every table of the manifest's recording: its
/// Clears, its static chunks, and one chunk of each (entity, component, timeline).
pub(super) fn columns(manifest: &Manifest) -> HashSet<ChunkId> {
    // Without rows, the index and the range choose nothing.
    needed(manifest, &DataframeQuery::new(""), Needs::Columns)
}

/// What a read is for: a query's planning (its columns), its rows, or both (planning that
/// keeps what it read for the rows).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Needs {
    Columns,
    Rows,
    Both,
}

/// The chunks of the manifest `query` needs: see the module docs. Its columns need the
/// Clears, the static chunks and one chunk of each (entity, component, timeline); its rows
/// the Clears, the static chunks, the range's chunks, with fill the candidates at the
/// range's start, and the columns of every entity a Clear may mark: a column none of those
/// holds has no cell in the range, and is null there.
pub(super) fn needed(
    manifest: &Manifest,
    query: &DataframeQuery,
    needs: Needs,
) -> HashSet<ChunkId> {
    let rows = needs != Needs::Columns;
    let columns = needs != Needs::Rows;
    // A Clear marks its time in every column of its entity (and, recursive, of those
    // below): those columns are needed for the rows too, whatever their chunks hold.
    let cleared: HashSet<&EntityPath> = manifest
        .entries
        .iter()
        .filter(|e| e.components.iter().any(|c| c.name.is_clear()))
        .map(|e| &e.entity_path)
        .collect();
    let under_clear = |entity: &EntityPath| {
        cleared.contains(entity) || entity.ancestors().any(|a| cleared.contains(&a))
    };
    let (index, range) = (query.index(), query.range());
    let mut needed = HashSet::new();
    let mut planned: HashSet<(&EntityPath, &ComponentName, &str)> = HashSet::new();
    let mut before: HashMap<(&EntityPath, &ComponentName), StartingBefore> = HashMap::new();
    for entry in &manifest.entries {
        let id = entry.chunk_id;
        if entry.components.iter().any(|c| c.name.is_clear()) {
            needed.insert(id);
            continue;
        }
        if !query.contents().matches(&entry.entity_path) {
            continue;
        }
        if entry.is_static {
            needed.insert(id);
            continue;
        }
        let in_range = entry
            .ranges
            .iter()
            .any(|r| r.timeline.name() == index && TimeRange::new(r.min, r.max).intersects(range));
        if rows && in_range {
            needed.insert(id);
        }
        let columns_here = columns || under_clear(&entry.entity_path);
        for component in &entry.components {
            for r in &component.ranges {
                if columns_here
                    && planned.insert((&entry.entity_path, &component.name, r.timeline.name()))
                {
                    needed.insert(id);
                }
                if rows
                    && query.fill_latest_at()
                    && r.timeline.name() == index
                    && r.min <= range.min()
                {
                    before
                        .entry((&entry.entity_path, &component.name))
                        .or_default()
                        .push((id, r.min, r.max));
                }
            }
        }
    }
    for chunks in before.values() {
        if let Some(floor) = chunks.iter().map(|&(_, min, _)| min).max() {
            needed.extend(
                chunks
                    .iter()
                    .filter(|&&(_, _, max)| max >= floor)
                    .map(|&(id, ..)| id),
            );
        }
    }
    needed
}
