//! Clears (SEMANTICS.md section 5), indexed on their own: a tree mirroring the entity tree
//! holds, per entity that ever logged a Clear, the indices of its Clears per timeline. A
//! query walks from the root to the queried entity, one map lookup per level, and never
//! looks at any entity's data.

use std::collections::BTreeMap;
use std::sync::Arc;

use arrow_array::{Array, BooleanArray};
use arrow_buffer::ArrowNativeType;

use crate::{Chunk, EntityPath, RowId, TimeInt};

/// A multiset of indices: duplicated row ids must neither crash nor miscount.
type IndexMultiset<K> = BTreeMap<K, u32>;

/// The Clears logged at one entity.
#[derive(Clone, Debug, Default)]
struct EntityClears {
    /// All Clears, flat and recursive, per timeline: they hide this entity's own data.
    any_per_timeline: ahash::HashMap<Arc<str>, IndexMultiset<(TimeInt, RowId)>>,
    /// Recursive Clears per timeline: they hide descendants' data too.
    recursive_per_timeline: ahash::HashMap<Arc<str>, IndexMultiset<(TimeInt, RowId)>>,
    static_any: IndexMultiset<RowId>,
    static_recursive: IndexMultiset<RowId>,
}

/// The Clears of a whole store, as a tree of entity path parts.
#[derive(Clone, Debug, Default)]
pub(crate) struct ClearIndex {
    clears: Option<Box<EntityClears>>,
    children: ahash::HashMap<Arc<str>, ClearIndex>,
}

/// One Clear row: its row, and whether it is recursive.
fn clear_rows(chunk: &Chunk) -> Vec<(usize, bool)> {
    let Some(column) = chunk.component(crate::ComponentName::CLEAR_IS_RECURSIVE) else {
        return Vec::new();
    };
    let list = column.list_array();
    let Some(flags) = list.values().as_any().downcast_ref::<BooleanArray>() else {
        return Vec::new(); // the store rejects such chunks before indexing them
    };
    let offsets = list.offsets();
    (0..list.len())
        .filter(|&row| list.is_valid(row) && list.value_length(row) > 0)
        .map(|row| {
            // A Clear holds one instance; a null flag is read as flat.
            let first = offsets[row].as_usize();
            (row, flags.is_valid(first) && flags.value(first))
        })
        .collect()
}

impl ClearIndex {
    /// Does the store hold any Clear at all? Queries skip the walk when not.
    pub fn is_empty(&self) -> bool {
        self.clears.is_none() && self.children.is_empty()
    }

    /// Indexes every Clear row of `chunk`; a chunk without any is not touched.
    pub fn insert_chunk(&mut self, chunk: &Chunk) {
        let rows = clear_rows(chunk);
        if rows.is_empty() {
            return;
        }
        let mut node = self;
        for part in chunk.entity_path().part_arcs() {
            node = node.children.entry(Arc::clone(part)).or_default();
        }
        let clears = node.clears.get_or_insert_with(Box::default);
        let row_ids = chunk.row_ids();
        for &(row, recursive) in &rows {
            let row_id = row_ids[row];
            if chunk.is_static() {
                *clears.static_any.entry(row_id).or_default() += 1;
                if recursive {
                    *clears.static_recursive.entry(row_id).or_default() += 1;
                }
            }
            for column in chunk.time_columns() {
                let name = column.timeline().name_arc();
                let key = (TimeInt::saturating(column.times()[row]), row_id);
                *clears
                    .any_per_timeline
                    .entry(Arc::clone(name))
                    .or_default()
                    .entry(key)
                    .or_default() += 1;
                if recursive {
                    *clears
                        .recursive_per_timeline
                        .entry(Arc::clone(name))
                        .or_default()
                        .entry(key)
                        .or_default() += 1;
                }
            }
        }
    }

    /// Is a cell of `entity` with index `(time, row_id)` (`time` `None` for static) hidden
    /// by a Clear visible at `at` on `timeline`?
    pub fn is_hidden(
        &self,
        entity: &EntityPath,
        timeline: &str,
        at: TimeInt,
        time: Option<TimeInt>,
        row_id: RowId,
    ) -> bool {
        let parts = entity.part_arcs();
        let mut node = self;
        for depth in 0..=parts.len() {
            if let Some(clears) = &node.clears {
                let is_self = depth == parts.len();
                if clears.hides(is_self, timeline, at, time, row_id) {
                    return true;
                }
            }
            match parts.get(depth).and_then(|part| node.children.get(part)) {
                Some(child) => node = child,
                None => return false,
            }
        }
        false
    }

    pub fn sanity_check(&self) -> Result<(), String> {
        let Self { clears, children } = self;
        if let Some(clears) = clears {
            let EntityClears {
                any_per_timeline,
                recursive_per_timeline,
                static_any,
                static_recursive,
            } = &**clears;
            let counts_positive = any_per_timeline
                .values()
                .chain(recursive_per_timeline.values())
                .all(|set| !set.is_empty() && set.values().all(|&n| n > 0))
                && static_any
                    .values()
                    .chain(static_recursive.values())
                    .all(|&n| n > 0);
            if !counts_positive {
                return Err("clear multisets hold positive counts and no empty sets".into());
            }
            for (timeline, recursive) in recursive_per_timeline {
                let any = any_per_timeline.get(timeline);
                if !recursive
                    .keys()
                    .all(|k| any.is_some_and(|a| a.contains_key(k)))
                {
                    return Err("every recursive Clear is also among all Clears".into());
                }
            }
        }
        for child in children.values() {
            if child.is_empty() {
                return Err("clear index holds no empty subtrees".into());
            }
            child.sanity_check()?;
        }
        Ok(())
    }
}

impl EntityClears {
    fn hides(
        &self,
        is_self: bool,
        timeline: &str,
        at: TimeInt,
        time: Option<TimeInt>,
        row_id: RowId,
    ) -> bool {
        let (statics, per_timeline) = if is_self {
            (&self.static_any, &self.any_per_timeline)
        } else {
            (&self.static_recursive, &self.recursive_per_timeline)
        };
        // A static Clear hides all temporal data, and static data with a smaller row id.
        if let Some((&latest_static, _)) = statics.last_key_value() {
            match time {
                None if row_id <= latest_static => return true,
                Some(_) => return true,
                None => {}
            }
        }
        // A temporal Clear only hides temporal data, and only once it is visible at `at`.
        let Some(time) = time else { return false };
        per_timeline
            .get(timeline)
            .and_then(|set| set.range(..=(at, RowId::MAX)).next_back())
            .is_some_and(|(&clear_index, _)| (time, row_id) <= clear_index)
    }
}
