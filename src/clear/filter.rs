//! [`ClearFilter`]: the bits that spare most queries the walk of the Clear tree (see the
//! module docs of `clear`): a bit per path hash and kind of Clear, kept in step with the
//! tree and made again from it once too many of its bits are stale.

use super::{ClearNode, Holds};
use crate::entity_path::PathPart;
use crate::sanity::{SanityError, Structure, ensure};

/// Bits in a [`ClearFilter`].
const FILTER_BITS: usize = 4096;

/// Which path hashes may belong to an entity holding Clears (any, or recursive ones): a bit
/// per hash and kind, never clear for an entity that holds them, possibly set for one
/// that no longer does (`stale` counts those; once they outnumber the entities holding
/// Clears, the filter is made again from the tree, so a query's false hits stay rare
/// and each costs a walk it would have made anyway).
#[derive(Clone, Debug)]
pub(super) struct ClearFilter {
    bits: [u64; FILTER_BITS / 64],
    /// Entities holding Clears.
    entities: usize,
    /// Bits left set for Clears that went since the filter was last made.
    stale: usize,
}

impl Default for ClearFilter {
    fn default() -> Self {
        Self {
            bits: [0; FILTER_BITS / 64],
            entities: 0,
            stale: 0,
        }
    }
}

impl ClearFilter {
    /// The bit of an entity with any Clear, by its path's hash (well mixed: a path's hash
    /// is ahash's). The bits of the two kinds come from different halves of the hash.
    #[expect(clippy::cast_possible_truncation, reason = "below FILTER_BITS")]
    fn any_bit(hash: u64) -> usize {
        (hash % FILTER_BITS as u64) as usize
    }

    fn recursive_bit(hash: u64) -> usize {
        ((hash >> 32) % FILTER_BITS as u64) as usize
    }

    fn test(&self, bit: usize) -> bool {
        self.bits[bit / 64] & (1 << (bit % 64)) != 0
    }

    fn set(&mut self, bit: usize) {
        self.bits[bit / 64] |= 1 << (bit % 64);
    }

    /// May the entity whose path hashes to `hash` hold a Clear?
    pub(super) fn may_hold_any(&self, hash: u64) -> bool {
        self.test(Self::any_bit(hash))
    }

    /// May it hold a recursive Clear?
    pub(super) fn may_hold_recursive(&self, hash: u64) -> bool {
        self.test(Self::recursive_bit(hash))
    }

    fn mark(&mut self, hash: u64, holds: Holds) {
        if holds.any {
            self.set(Self::any_bit(hash));
        }
        if holds.recursive {
            self.set(Self::recursive_bit(hash));
        }
    }

    /// Notes that the entity whose path hashes to `hash` held `before` and holds `after`;
    /// makes the filter again from `root` once stale bits outnumber the entities.
    pub(super) fn note(&mut self, root: &ClearNode, hash: u64, before: Holds, after: Holds) {
        self.mark(hash, after);
        match (before.any, after.any) {
            (false, true) => self.entities += 1,
            (true, false) => self.entities -= 1,
            _ => {}
        }
        self.stale += usize::from(before.any && !after.any)
            + usize::from(before.recursive && !after.recursive);
        self.rebuild_if_stale(root);
    }

    /// Notes that `gone` entities no longer hold Clears (each may leave both its bits).
    pub(super) fn forget(&mut self, gone: usize, root: &ClearNode) {
        self.entities -= gone;
        self.stale += 2 * gone;
        self.rebuild_if_stale(root);
    }

    fn rebuild_if_stale(&mut self, root: &ClearNode) {
        if self.stale > self.entities {
            *self = Self::of(root);
        }
    }

    /// The filter of the tree below `root`, without stale bits.
    pub(super) fn of(root: &ClearNode) -> Self {
        let mut filter = Self::default();
        root.for_each_entity(PathPart::ROOT_HASH, &mut |hash, node| {
            filter.mark(hash, Holds::of(Some(node)));
            filter.entities += 1;
        });
        filter
    }

    /// Every entity holding Clears under `root` has its bits, the count of such entities
    /// is right, and at most `stale` bits are set beyond those.
    pub(super) fn sanity_check(&self, root: &ClearNode) -> Result<(), SanityError> {
        let fresh = Self::of(root);
        let ones = |bits: &[u64]| bits.iter().map(|w| w.count_ones() as usize).sum::<usize>();
        ensure(
            fresh.bits.iter().zip(&self.bits).all(|(f, k)| f & !k == 0),
            Structure::ClearIndex,
            "the filter marks every entity holding Clears",
        )?;
        ensure(
            fresh.entities == self.entities,
            Structure::ClearIndex,
            "the filter counts the entities holding Clears",
        )?;
        ensure(
            self.stale <= self.entities && ones(&self.bits) <= ones(&fresh.bits) + self.stale,
            Structure::ClearIndex,
            "the filter's stale bits are counted and fewer than the entities",
        )
    }
}
