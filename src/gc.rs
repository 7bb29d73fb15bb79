//! Garbage collection (SEMANTICS.md section 7): whole temporal chunks dropped until a
//! memory target is met. (The explicit drops of a time range or an entity are `drop.rs`.)
//!
//! Garbage collection plans first ([`ChunkStore::plan_gc`], `&self`) and applies second
//! ([`ChunkStore::apply_gc`]), so a plan can be inspected and tested on its own. Planning
//! walks candidates in the requested order from ordered sets the store keeps up to date,
//! so its cost is proportional to the chunks it looks at (those it drops, and the
//! protected ones it skips on the way), times `log n`: never to the size of the store.

use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::store::{DeletionReason, EntityIndex, EntityView, StoredChunk};
use crate::{Chunk, ChunkId, ChunkStore, StoreEvent, TimeInt, TimeRange};
use std::fmt;

use smallvec::SmallVec;

/// How much garbage collection should free.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum GcTarget {
    /// At least this many heap bytes ([`crate::StoreStats::heap_bytes`]).
    DropAtLeastBytes(u64),
    /// At least this fraction of the store's heap bytes.
    DropAtLeastFraction(GcFraction),
    /// Every chunk that is not protected.
    Everything,
}

impl GcTarget {
    /// [`GcTarget::DropAtLeastFraction`] of `fraction`, checked by [`GcFraction::new`].
    ///
    /// # Errors
    /// If `fraction` is not in `(0, 1]`.
    pub fn drop_at_least_fraction(fraction: f64) -> Result<Self, GcOptionsError> {
        GcFraction::new(fraction).map(Self::DropAtLeastFraction)
    }
}

/// A fraction of a store's heap in `(0, 1]`: a garbage collection target that means
/// something. `NaN`, zero, negative and above-one fractions are refused where they are
/// made, rather than making a collection silently do nothing (or everything).
///
/// ```
/// use chunkstore::GcFraction;
/// assert_eq!(GcFraction::new(0.25).unwrap().get(), 0.25);
/// assert!(GcFraction::new(f64::NAN).is_err());
/// assert!(GcFraction::new(0.0).is_err());
/// ```
#[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
pub struct GcFraction(f64);

impl GcFraction {
    /// The whole heap.
    pub const ALL: Self = Self(1.0);

    /// `fraction`, if it is in `(0, 1]`.
    ///
    /// # Errors
    /// [`GcOptionsError::FractionOutOfRange`] otherwise (`NaN` included).
    pub fn new(fraction: f64) -> Result<Self, GcOptionsError> {
        if fraction > 0.0 && fraction <= 1.0 {
            Ok(Self(fraction))
        } else {
            Err(GcOptionsError::FractionOutOfRange { fraction })
        }
    }

    /// The fraction, in `(0, 1]`.
    pub fn get(self) -> f64 {
        self.0
    }
}

impl TryFrom<f64> for GcFraction {
    type Error = GcOptionsError;

    fn try_from(fraction: f64) -> Result<Self, Self::Error> {
        Self::new(fraction)
    }
}

/// Which chunks garbage collection drops first.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum GcOrder {
    /// The chunks holding the oldest rows (smallest least row id) first.
    OldestRowIdsFirst,
    /// The chunks furthest in time from `time` on `timeline` first (a viewer's time
    /// cursor: what is far from it is least likely to be looked at). Chunks without the
    /// timeline go last, oldest first.
    FurthestFrom {
        /// The timeline.
        timeline: Arc<str>,
        /// The cursor.
        time: TimeInt,
    },
}

/// What garbage collection may drop, and how far it should go. Made by
/// [`GcOptions::everything`] or [`GcOptions::drop_at_least_fraction`], then adjusted with
/// the `with_*` methods.
///
/// ```
/// # use std::time::Duration;
/// # use chunkstore::*;
/// let t = |v| TimeInt::new(v).unwrap();
/// let options = GcOptions::drop_at_least_fraction(0.25)?
///     .with_protect_latest(2)
///     .with_protected_time_range("frame", TimeRange::new(t(100), t(200)))
///     .with_time_budget(Duration::from_millis(5));
/// assert_eq!(options.protect_latest, 2);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct GcOptions {
    /// How much to free.
    pub target: GcTarget,
    /// Keep the `n` latest chunks of every (entity, timeline, component), and those
    /// holding the `n` latest Clears of every entity and timeline. With `n ≥ 1`, every
    /// latest-at at `+∞` answers as before.
    pub protect_latest: usize,
    /// Keep every chunk with rows in one of these ranges of a timeline.
    pub protected_time_ranges: Vec<(Arc<str>, TimeRange)>,
    /// Stop planning once this much time has passed, but only after choosing at least one
    /// chunk to drop: a call that finds collectable data always frees some.
    pub time_budget: Option<Duration>,
    /// Which chunks go first.
    pub order: GcOrder,
}

impl GcOptions {
    /// Drop every unprotected temporal chunk, protecting nothing.
    ///
    /// ```
    /// # use chunkstore::*;
    /// let mut store = ChunkStore::new();
    /// let events = store.gc(&GcOptions::everything());
    /// assert!(events.is_empty()); // nothing to collect in an empty store
    /// ```
    pub fn everything() -> Self {
        Self {
            target: GcTarget::Everything,
            protect_latest: 0,
            protected_time_ranges: Vec::new(),
            time_budget: None,
            order: GcOrder::OldestRowIdsFirst,
        }
    }

    /// Drop at least `fraction` of the store's heap, oldest rows first, protecting the
    /// latest chunk of every (entity, timeline, component).
    ///
    /// # Errors
    /// If `fraction` is not in `(0, 1]` (see [`GcFraction`]).
    pub fn drop_at_least_fraction(fraction: f64) -> Result<Self, GcOptionsError> {
        Ok(Self {
            target: GcTarget::drop_at_least_fraction(fraction)?,
            protect_latest: 1,
            ..Self::everything()
        })
    }

    /// The same options, freeing `target`.
    #[must_use]
    pub fn with_target(mut self, target: GcTarget) -> Self {
        self.target = target;
        self
    }

    /// The same options, keeping the `n` latest chunks of every (entity, timeline,
    /// component) (see [`GcOptions::protect_latest`]).
    #[must_use]
    pub fn with_protect_latest(mut self, n: usize) -> Self {
        self.protect_latest = n;
        self
    }

    /// The same options, also keeping every chunk with rows in `range` of `timeline`.
    #[must_use]
    pub fn with_protected_time_range(
        mut self,
        timeline: impl Into<Arc<str>>,
        range: TimeRange,
    ) -> Self {
        self.protected_time_ranges.push((timeline.into(), range));
        self
    }

    /// The same options, planning for at most `budget` (see [`GcOptions::time_budget`]).
    #[must_use]
    pub fn with_time_budget(mut self, budget: Duration) -> Self {
        self.time_budget = Some(budget);
        self
    }

    /// The same options, dropping chunks in `order`.
    #[must_use]
    pub fn with_order(mut self, order: GcOrder) -> Self {
        self.order = order;
        self
    }
}

impl GcOrder {
    /// [`GcOrder::FurthestFrom`] `time` on `timeline`.
    pub fn furthest_from(timeline: impl Into<Arc<str>>, time: TimeInt) -> Self {
        Self::FurthestFrom {
            timeline: timeline.into(),
            time,
        }
    }
}

/// The chunks one garbage collection will drop, in order.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct GcPlan {
    /// The chunks to drop.
    pub chunk_ids: Vec<ChunkId>,
    /// Heap bytes dropping them frees (a buffer still shared by a kept chunk frees
    /// nothing).
    pub bytes_to_free: u64,
    /// Candidates looked at, dropped or protected.
    pub num_considered: usize,
    /// Planning stopped on the time budget before meeting the target.
    pub out_of_time: bool,
}

impl ChunkStore {
    /// Chooses the chunks a garbage collection with `options` drops, without changing
    /// anything. Static chunks are never chosen.
    pub fn plan_gc(&self, options: &GcOptions) -> GcPlan {
        let start = Instant::now();
        let target = match options.target {
            GcTarget::DropAtLeastBytes(bytes) => bytes,
            #[expect(
                clippy::cast_possible_truncation,
                clippy::cast_sign_loss,
                clippy::cast_precision_loss,
                reason = "a fraction in (0, 1] of a byte count"
            )]
            GcTarget::DropAtLeastFraction(fraction) => {
                (fraction.get() * self.view.stats.heap_bytes as f64).ceil() as u64
            }
            GcTarget::Everything => u64::MAX,
        };
        let mut plan = GcPlan::default();
        // Per shared allocation: references the plan already drops.
        let mut released: ahash::HashMap<usize, u32> = ahash::HashMap::default();
        let mut candidates = self.gc_candidates(&options.order);
        let mut batch = CandidateBatch::default();
        while let Some(candidate) = batch.next(&mut candidates, &self.chunks) {
            if plan.bytes_to_free >= target {
                break;
            }
            if let Some(budget) = options.time_budget
                && !plan.chunk_ids.is_empty()
                && start.elapsed() >= budget
            {
                plan.out_of_time = true;
                break;
            }
            plan.num_considered += 1;
            let Candidate::Held(stored) = candidate else {
                continue;
            };
            // The entity found once: three searches by path a candidate were a tenth of a
            // plan.
            let entity = self.entity(stored.chunk.entity_path());
            if self.is_gc_protected(&stored.chunk, entity.map(|(_, view)| view), options) {
                continue;
            }
            plan.bytes_to_free += self.bytes_freed_by(stored, entity, &mut released);
            plan.chunk_ids.push(stored.chunk.id());
        }
        plan
    }

    /// Drops the chunks of `plan` (those the store still holds), each reported as a
    /// deletion with reason [`DeletionReason::Gc`].
    pub fn apply_gc(&mut self, plan: &GcPlan) -> Vec<StoreEvent> {
        let mut events = Vec::with_capacity(plan.chunk_ids.len());
        let mut removed = Vec::with_capacity(plan.chunk_ids.len());
        for &id in &plan.chunk_ids {
            let Some(stored) = self.chunks.remove(&id) else {
                continue;
            };
            if stored.chunk.is_static() {
                // Only a plan built by hand names one; it is left as it was.
                self.chunks.insert(id, stored);
                continue;
            }
            removed.push(stored);
        }
        // Each entity looked up once for all of its chunks (GC takes many of one entity).
        self.take_out_all(removed, DeletionReason::Gc, &mut events);
        self.finish_mutation(events)
    }

    /// Plans and applies a garbage collection: see [`ChunkStore::plan_gc`].
    pub fn gc(&mut self, options: &GcOptions) -> Vec<StoreEvent> {
        let plan = self.plan_gc(options);
        self.apply_gc(&plan)
    }

    /// Temporal chunk ids in the order `order` drops them: the store-wide orders, with the
    /// few waiting chunks compaction keeps out of them merged in.
    fn gc_candidates<'a>(&'a self, order: &'a GcOrder) -> Box<dyn Iterator<Item = ChunkId> + 'a> {
        let outside = self.chunks_outside_global_orders();
        let mut outside_by_row_id: Vec<_> = outside
            .iter()
            .map(|c| crate::store::row_id_order_key(c))
            .collect();
        outside_by_row_id.sort_unstable();
        let by_row_id = merge_sorted(
            self.temporal_by_row_id.iter().copied(),
            outside_by_row_id,
            |a, b| a < b,
        )
        .map(|(_, id)| id);
        let GcOrder::FurthestFrom { timeline, time } = order else {
            return Box::new(by_row_id);
        };
        // The waiting chunks' keys in this timeline's orders, as the orders key them.
        let on_timeline = |c: &&Arc<Chunk>| {
            crate::store::time_order_keys(c)
                .find(|(name, _, _)| ***name == **timeline)
                .map(|(_, by_min, by_max)| (by_min, by_max))
        };
        let mut outside_by_max: Vec<_> = outside
            .iter()
            .filter_map(|c| on_timeline(c).map(|(_, by_max)| by_max))
            .collect();
        outside_by_max.sort_unstable();
        let mut outside_by_min_desc: Vec<_> = outside
            .iter()
            .filter_map(|c| on_timeline(c).map(|(by_min, _)| by_min))
            .collect();
        outside_by_min_desc.sort_unstable_by(|a, b| b.cmp(a));
        let (by_max_time, by_min_time_desc) = match self.temporal_per_timeline.get(&**timeline) {
            Some(chunks) => (
                Some(chunks.by_max_time.iter().copied()),
                Some(chunks.by_min_time.iter().rev().copied()),
            ),
            None => (None, None),
        };
        if by_max_time.is_none() && outside_by_max.is_empty() {
            return Box::new(by_row_id);
        }
        let cursor = i128::from(time.as_i64());
        let min_time = |id: &ChunkId| {
            self.chunks
                .get(id)
                .and_then(|s| s.chunk.time_column(timeline))
                .map(|c| i128::from(c.time_range().min().as_i64()))
        };
        // Ending furthest before the cursor first, from one end; starting furthest after
        // it, from the other. A chunk starting after the cursor belongs to the second.
        let mut before = merge_sorted(by_max_time.into_iter().flatten(), outside_by_max, |a, b| {
            a < b
        })
        .peekable();
        let mut after = merge_sorted(
            by_min_time_desc.into_iter().flatten(),
            outside_by_min_desc,
            |a, b| a > b,
        )
        .peekable();
        let by_distance = std::iter::from_fn(move || {
            while before
                .peek()
                .is_some_and(|(_, id)| min_time(id).is_some_and(|min| min > cursor))
            {
                before.next();
            }
            let distance_before = before
                .peek()
                .map(|(max, _)| (cursor - i128::from(max.as_i64())).max(0));
            let distance_after = after
                .peek()
                .map(|(min, _)| i128::from(min.as_i64()) - cursor)
                .filter(|&d| d > 0);
            match (distance_before, distance_after) {
                (Some(b), Some(a)) if a > b => after.next(),
                (Some(_), _) => before.next(),
                (None, Some(_)) => after.next(),
                (None, None) => None,
            }
            .map(|(_, id)| id)
        });
        let without_timeline = by_row_id.filter(|id| {
            self.chunks
                .get(id)
                .is_some_and(|s| s.chunk.time_column(timeline).is_none())
        });
        Box::new(by_distance.chain(without_timeline))
    }

    /// Is the chunk kept by `options`' protections?
    fn is_gc_protected(
        &self,
        chunk: &Chunk,
        entity: Option<&EntityView>,
        options: &GcOptions,
    ) -> bool {
        if chunk.is_static() {
            return true;
        }
        let in_protected_range = options.protected_time_ranges.iter().any(|(name, range)| {
            chunk.time_column(name).is_some_and(|column| {
                let bounds = column.time_range();
                let (lo, hi) = (bounds.min(), bounds.max());
                range.intersects(TimeRange::new(lo, hi))
            })
        });
        if in_protected_range {
            return true;
        }
        let n = options.protect_latest;
        if n == 0 {
            return false;
        }
        let Some(entity) = entity else {
            return false;
        };
        if entity.is_among_latest(chunk, n) {
            return true;
        }
        chunk.clear_column().is_some()
            && self
                .clears
                .is_among_latest(chunk.entity_path(), chunk.id(), n)
    }

    /// Heap bytes dropping `stored` (of `entity`) frees, given the shared references the
    /// plan already drops (`released`, updated).
    fn bytes_freed_by(
        &self,
        stored: &StoredChunk,
        entity: Option<(&EntityIndex, &EntityView)>,
        released: &mut ahash::HashMap<usize, u32>,
    ) -> u64 {
        let chunk = &stored.chunk;
        let mut bytes = crate::stats::fixed_bytes(chunk)
            + entity.map_or(0, |(index, view)| {
                index.extra_index_heap_bytes_of(view, chunk)
            });
        if !stored.ledgered {
            return bytes + chunk.buffer_bytes();
        }
        for buffer in chunk.buffers() {
            let address = crate::chunk::memory::buffer_address(buffer);
            let gone = released.entry(address).or_default();
            *gone += 1;
            if *gone >= self.ledgers.all.references(address) {
                bytes += crate::chunk::memory::buffer_bytes(buffer);
            }
        }
        bytes
    }
}

/// How many candidates a GC plan looks up in the chunk map at once. A plan reads, per
/// candidate, the chunk map's slot, then the chunk's struct, then its first column, each
/// found through the one before and each a cache miss in a store larger than the cache.
/// Judging a candidate takes a few hundred instructions, about as many as a core keeps in
/// flight behind a load it waits for: looked up one at a time (even a few candidates
/// ahead), each candidate's misses followed the previous one's. A batch takes each step
/// for all of its candidates back to back (a handful of instructions apart), so that
/// their misses overlap.
const PLAN_BATCH: usize = 8;

/// The batch of candidates a plan has looked up, the one it judges among them: see
/// [`PLAN_BATCH`].
#[derive(Default)]
struct CandidateBatch<'a> {
    batch: SmallVec<[Option<&'a StoredChunk>; PLAN_BATCH]>,
    /// The next candidate's position in `batch`.
    next: usize,
}

impl<'a> CandidateBatch<'a> {
    /// The next candidate; once the batch looked up is judged, the next batch is looked up
    /// and its chunks' lines loaded.
    fn next(
        &mut self,
        candidates: &mut dyn Iterator<Item = ChunkId>,
        chunks: &'a ahash::HashMap<ChunkId, StoredChunk>,
    ) -> Option<Candidate<'a>> {
        if self.next == self.batch.len() {
            self.batch.clear();
            self.next = 0;
            self.batch
                .extend(candidates.take(PLAN_BATCH).map(|id| chunks.get(&id)));
            for stored in self.batch.iter().flatten() {
                stored.chunk.touch_struct();
            }
            for stored in self.batch.iter().flatten() {
                stored.chunk.touch_first_column();
            }
        }
        let candidate = self.batch.get(self.next).map(|stored| match stored {
            Some(stored) => Candidate::Held(stored),
            None => Candidate::Gone,
        });
        self.next += 1;
        candidate
    }
}

/// A chunk a GC plan considers.
enum Candidate<'a> {
    /// The store holds it.
    Held(&'a StoredChunk),
    /// The orders named it, but the chunk map does not hold it.
    Gone,
}

/// Merges `extra` into `ordered`, both sorted by `first` (`first(a, b)`: `a` goes before
/// `b`); on ties `ordered` goes first.
fn merge_sorted<T>(
    ordered: impl Iterator<Item = T>,
    extra: Vec<T>,
    first: impl Fn(&T, &T) -> bool,
) -> impl Iterator<Item = T> {
    let mut ordered = ordered.peekable();
    let mut extra = extra.into_iter().peekable();
    std::iter::from_fn(move || match (ordered.peek(), extra.peek()) {
        (Some(a), Some(b)) if first(b, a) => extra.next(),
        (Some(_), _) => ordered.next(),
        (None, _) => extra.next(),
    })
}

/// Garbage collection options that cannot mean what they say.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum GcOptionsError {
    /// A fraction of the heap to free must be in `(0, 1]`.
    FractionOutOfRange {
        /// The fraction given.
        fraction: f64,
    },
}

impl fmt::Display for GcOptionsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::FractionOutOfRange { fraction } => write!(
                f,
                "gc options: a fraction of the heap must be in (0, 1], not {fraction}"
            ),
        }
    }
}

impl std::error::Error for GcOptionsError {}
