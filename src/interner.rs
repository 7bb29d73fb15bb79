//! One shared copy of each timeline name, component name and list item field,
//! process-wide.
//!
//! Every chunk names its timelines and components and types its list columns, and a store
//! compares those on every insert, merge, removal and query (its per-entity maps are keyed
//! by the names; compaction groups chunks by type). Built independently, each chunk would
//! carry its own allocation of `frame`, of `Points3D:positions` and of its lists' item
//! field: memory per chunk, and cold cache lines at each comparison.
//! [`crate::Timeline::new`], [`crate::ComponentName::new`] and chunk construction use the
//! shared copy instead, so equal values are usually the same allocation (`Arc::ptr_eq`,
//! which `Arc`'s equality checks first) and that one copy stays in cache.
//!
//! The sets must not hold memory nobody uses, so each is bounded twice: by bytes
//! ([`MAX_SHARED_BYTES`]) and by entries ([`MAX_SHARED`]), and a value larger than
//! [`MAX_SHARED_VALUE_BYTES`] is never shared (a generated 100 KB component name is rare
//! enough that sharing it saves nothing). When a set is full, it first forgets the values
//! only it still holds (a sweep, at most once per half a set's worth of refused values, so
//! that a set full of values in use costs O(1) per refusal); a value that still finds no
//! room keeps its own allocation, which is just as correct.

use std::cell::RefCell;
use std::hash::Hash;
use std::sync::{Arc, OnceLock};

use arrow_schema::{DataType, Field, FieldRef};
use parking_lot::RwLock;

use crate::sanity::{SanityError, Structure, ensure};

/// How many distinct values of each kind are shared at most.
pub(crate) const MAX_SHARED: usize = 16_384;

/// How many bytes the values of each kind take at most (estimated; see [`Shareable`]).
pub(crate) const MAX_SHARED_BYTES: usize = 4 << 20;

/// The largest value that is shared.
pub(crate) const MAX_SHARED_VALUE_BYTES: usize = 1024;

/// A value a [`SharedSet`] can hold.
pub(crate) trait Shareable: Hash + Eq {
    /// Estimated heap of the value behind its `Arc`, with its slot in the set.
    fn shared_bytes(&self) -> usize;

    /// A new allocation of the value, for the set to hand out. (A caller's own `Arc` is not
    /// adopted: a chunk built while the set was full keeps its own field, and counts it in
    /// its memory, so that field must never become the shared copy later.)
    fn fresh_copy(&self) -> Arc<Self>;
}

impl Shareable for str {
    fn shared_bytes(&self) -> usize {
        // The `Arc` header and the set's slot (a fat pointer and a control byte).
        self.len() + 2 * size_of::<usize>() + 2 * size_of::<usize>() + 1
    }

    fn fresh_copy(&self) -> Arc<Self> {
        Arc::from(self)
    }
}

impl Shareable for Field {
    fn shared_bytes(&self) -> usize {
        field_bytes(self) + 2 * size_of::<usize>() + size_of::<usize>() + 1
    }

    fn fresh_copy(&self) -> Arc<Self> {
        Arc::new(self.clone())
    }
}

/// Estimated heap of a field: the struct, its name and metadata, and the fields nested in
/// its type.
fn field_bytes(field: &Field) -> usize {
    let metadata: usize = field
        .metadata()
        .iter()
        .map(|(key, value)| key.len() + value.len() + 3 * size_of::<usize>())
        .sum();
    let nested: usize = match field.data_type() {
        DataType::List(item)
        | DataType::LargeList(item)
        | DataType::ListView(item)
        | DataType::LargeListView(item)
        | DataType::FixedSizeList(item, _)
        | DataType::Map(item, _) => field_bytes(item),
        DataType::Struct(fields) => fields.iter().map(|f| field_bytes(f)).sum(),
        DataType::Union(fields, _) => fields.iter().map(|(_, f)| field_bytes(f)).sum(),
        DataType::Dictionary(..) | DataType::RunEndEncoded(..) => size_of::<Field>(),
        _ => 0,
    };
    size_of::<Field>() + field.name().len() + metadata + nested
}

/// One kind of shared values, with the figures that bound it.
struct SharedSet<T: ?Sized> {
    values: ahash::HashSet<Arc<T>>,
    /// [`Shareable::shared_bytes`] of `values`.
    bytes: usize,
    /// Values refused for lack of room since the last sweep.
    refused_since_sweep: usize,
    max_values: usize,
    max_bytes: usize,
}

impl<T: ?Sized + Shareable> SharedSet<T> {
    fn new(max_values: usize, max_bytes: usize) -> Self {
        Self {
            values: ahash::HashSet::default(),
            bytes: 0,
            refused_since_sweep: 0,
            max_values,
            max_bytes,
        }
    }

    /// The estimated bytes the set holds.
    #[cfg(test)]
    fn bytes(&self) -> usize {
        self.bytes
    }

    /// The number of values it holds.
    #[cfg(test)]
    fn len(&self) -> usize {
        self.values.len()
    }

    /// The byte count is that of its values, within the caps; every value is at most
    /// [`MAX_SHARED_VALUE_BYTES`]. Checked in debug builds after every sweep, and by the
    /// tests.
    fn sanity_check(&self) -> Result<(), SanityError> {
        let Self {
            values,
            bytes,
            refused_since_sweep: _, // a count of refusals: nothing to check it against
            max_values,
            max_bytes,
        } = self;
        let counted: usize = values.iter().map(|v| v.shared_bytes()).sum();
        ensure(
            counted == *bytes
                && values.len() <= *max_values
                && *bytes <= *max_bytes
                && values
                    .iter()
                    .all(|v| v.shared_bytes() <= MAX_SHARED_VALUE_BYTES),
            Structure::SharedSet,
            "a shared set counts its values' bytes, within its caps",
        )
    }

    fn has_room_for(&self, bytes: usize) -> bool {
        self.values.len() < self.max_values && self.bytes + bytes <= self.max_bytes
    }

    /// Forgets every value no one else holds.
    fn sweep(&mut self) {
        self.values.retain(|value| Arc::strong_count(value) > 1);
        self.bytes = self.values.iter().map(|v| v.shared_bytes()).sum();
        self.refused_since_sweep = 0;
        debug_assert!(self.sanity_check().is_ok(), "{:?}", self.sanity_check());
    }

    /// The shared copy of a value equal to `value`, if there is or can be one.
    fn share(&mut self, value: &T) -> Option<Arc<T>> {
        if let Some(shared) = self.values.get(value) {
            return Some(Arc::clone(shared));
        }
        let bytes = value.shared_bytes();
        if bytes > MAX_SHARED_VALUE_BYTES {
            return None;
        }
        if !self.has_room_for(bytes) && self.refused_since_sweep >= self.values.len() / 2 {
            self.sweep();
        }
        if !self.has_room_for(bytes) {
            self.refused_since_sweep += 1;
            return None;
        }
        let shared = value.fresh_copy();
        self.values.insert(Arc::clone(&shared));
        self.bytes += bytes;
        Some(shared)
    }
}

type Shared<T> = RwLock<SharedSet<T>>;

fn shared_names() -> &'static Shared<str> {
    static NAMES: OnceLock<Shared<str>> = OnceLock::new();
    NAMES.get_or_init(|| RwLock::new(SharedSet::new(MAX_SHARED, MAX_SHARED_BYTES)))
}

fn shared_fields() -> &'static Shared<Field> {
    static FIELDS: OnceLock<Shared<Field>> = OnceLock::new();
    FIELDS.get_or_init(|| RwLock::new(SharedSet::new(MAX_SHARED, MAX_SHARED_BYTES)))
}

/// The shared copy of `name` if there is or can be one, else `name` itself.
pub(crate) fn share_name(name: Arc<str>) -> Arc<str> {
    share_in(shared_names(), name)
}

/// How many fields each thread remembers having shared.
const RECENT_FIELDS: usize = 8;

/// The last fields a thread shared, each beside the field it was given.
///
/// A decoder hands in the same item field for every chunk of a layout (the IPC schema cache
/// gives each message of a layout the fields it parsed once), and hashing a field sorts its
/// metadata keys into a fresh vector: remembered, its shared copy is found by pointer.
/// Holding the given field keeps its address from being reused by another field; holding
/// the shared one keeps it in the set (a sweep keeps what others hold), so a remembered
/// shared copy is always the set's.
#[derive(Default)]
struct RecentFields {
    pairs: [Option<(FieldRef, FieldRef)>; RECENT_FIELDS],
    next: usize,
}

thread_local! {
    static RECENT: RefCell<RecentFields> = RefCell::default();
}

impl RecentFields {
    /// The shared copy of `field` if `field` is a remembered given or shared field.
    fn shared_copy_of(&self, field: &FieldRef) -> Option<FieldRef> {
        self.pairs.iter().flatten().find_map(|(given, shared)| {
            (Arc::ptr_eq(given, field) || Arc::ptr_eq(shared, field)).then(|| Arc::clone(shared))
        })
    }

    /// Is `field` a remembered shared copy?
    fn is_shared_copy(&self, field: &FieldRef) -> bool {
        self.pairs
            .iter()
            .flatten()
            .any(|(_, shared)| Arc::ptr_eq(shared, field))
    }

    fn remember(&mut self, given: FieldRef, shared: FieldRef) {
        self.pairs[self.next] = Some((given, shared));
        self.next = (self.next + 1) % RECENT_FIELDS;
    }
}

/// The shared copy of a list's item field, as [`share_name`] does for names.
pub(crate) fn share_field(field: &FieldRef) -> FieldRef {
    let recent = RECENT.with(|recent| recent.try_borrow().ok()?.shared_copy_of(field));
    if let Some(shared) = recent {
        return shared;
    }
    let shared = share_in(shared_fields(), Arc::clone(field));
    // Another allocation came back: the set's copy (a refused field comes back itself).
    if !Arc::ptr_eq(&shared, field) {
        RECENT.with(|recent| {
            if let Ok(mut recent) = recent.try_borrow_mut() {
                recent.remember(Arc::clone(field), Arc::clone(&shared));
            }
        });
    }
    shared
}

/// Is `field` the shared copy (so that no chunk owns it)?
pub(crate) fn is_shared_field(field: &FieldRef) -> bool {
    let recent = RECENT.with(|recent| {
        recent
            .try_borrow()
            .is_ok_and(|recent| recent.is_shared_copy(field))
    });
    recent
        || shared_fields()
            .read()
            .values
            .get(&**field)
            .is_some_and(|shared| Arc::ptr_eq(shared, field))
}

/// Are two names equal? Pointers first: equal names are usually the one shared copy, and
/// std's `Arc` equality takes that shortcut only for sized types (for `str` it always
/// compares the bytes).
#[inline]
pub(crate) fn same_name(a: &Arc<str>, b: &Arc<str>) -> bool {
    // The shared copy decided here, inline in every caller; the text (lengths first) only
    // for names from elsewhere.
    Arc::ptr_eq(a, b) || crate::text::same_text(a, b)
}

/// Orders two names by their text, with the same shortcut as [`same_name`].
pub(crate) fn cmp_names(a: &Arc<str>, b: &Arc<str>) -> std::cmp::Ordering {
    if Arc::ptr_eq(a, b) {
        std::cmp::Ordering::Equal
    } else {
        a.cmp(b)
    }
}

fn share_in<T: ?Sized + Shareable>(set: &Shared<T>, value: Arc<T>) -> Arc<T> {
    if let Some(shared) = set.read().values.get(&*value) {
        return Arc::clone(shared);
    }
    set.write().share(&value).unwrap_or(value)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn share(set: &Shared<str>, name: &str) -> Arc<str> {
        share_in(set, Arc::from(name))
    }

    #[test]
    fn equal_names_share_one_allocation() {
        let names = RwLock::new(SharedSet::<str>::new(8, 1 << 20));
        let a = share(&names, "frame");
        let b = share_in(&names, Arc::from(String::from("frame")));
        assert!(Arc::ptr_eq(&a, &b));
        let other = share(&names, "log_time");
        assert!(!Arc::ptr_eq(&a, &other));
        assert_eq!(&*other, "log_time");
        // The process-wide set behind the public constructors does the same.
        let (x, y) = (
            crate::ComponentName::new("names-test/position"),
            crate::ComponentName::new(String::from("names-test/position")),
        );
        assert_eq!(x.as_str().as_ptr(), y.as_str().as_ptr());
    }

    #[test]
    fn equal_fields_share_one_allocation() {
        let make = || {
            Arc::new(Field::new(
                "shared-test/item",
                arrow_schema::DataType::Float64,
                true,
            ))
        };
        let (first, second) = (make(), make());
        let shared = share_field(&first);
        assert!(Arc::ptr_eq(&shared, &share_field(&second)));
        assert!(is_shared_field(&shared));
        assert!(
            !is_shared_field(&first) && !is_shared_field(&second),
            "the set keeps a copy of its own, never a caller's field"
        );
    }

    /// The fields a thread shared last are found again by pointer, given or shared, and
    /// give the set's copy; a field equal to none of them still goes to the set.
    #[test]
    fn recently_shared_fields_are_found_by_pointer() {
        let make = |name: &str| Arc::new(Field::new(name, arrow_schema::DataType::Int32, true));
        let given = make("recent-test/item");
        let shared = share_field(&given);
        assert!(!Arc::ptr_eq(&shared, &given));
        for _ in 0..3 {
            assert!(Arc::ptr_eq(&share_field(&given), &shared));
            assert!(Arc::ptr_eq(&share_field(&shared), &shared));
        }
        assert!(is_shared_field(&shared) && !is_shared_field(&given));
        // More fields than a thread remembers: the first is then found through the set.
        let others: Vec<_> = (0..2 * RECENT_FIELDS)
            .map(|i| make(&format!("recent-test/other{i}")))
            .collect();
        for other in &others {
            assert!(!Arc::ptr_eq(&share_field(other), other));
        }
        assert!(Arc::ptr_eq(
            &share_field(&make("recent-test/item")),
            &shared
        ));
        assert!(is_shared_field(&shared));
    }

    #[test]
    fn past_the_cap_names_keep_their_own_allocation() {
        let names = RwLock::new(SharedSet::<str>::new(4, 1 << 20));
        let held: Vec<Arc<str>> = (0..4)
            .map(|i| share(&names, &format!("fill-{i}")))
            .collect();
        let late = Arc::<str>::from("late");
        let shared = share_in(&names, Arc::clone(&late));
        assert!(Arc::ptr_eq(&late, &shared));
        assert_eq!(names.read().len(), 4);
        // An earlier name is still shared.
        assert!(Arc::ptr_eq(&share(&names, "fill-0"), &held[0]));
    }

    #[test]
    fn long_names_are_never_shared() {
        let names = RwLock::new(SharedSet::<str>::new(8, 1 << 20));
        let long = "x".repeat(MAX_SHARED_VALUE_BYTES);
        let first = share(&names, &long);
        assert!(!Arc::ptr_eq(&first, &share(&names, &long)));
        assert_eq!(names.read().len(), 0);
    }

    /// A full set forgets the names nobody holds any more, rather than keeping them forever
    /// (issue 12: 5,000 generated names stayed resident after every chunk was dropped).
    #[test]
    fn a_full_set_sweeps_the_names_nobody_holds() {
        let per_name = "n-0000".shared_bytes();
        let names = RwLock::new(SharedSet::<str>::new(1000, 10 * per_name));
        let held: Vec<Arc<str>> = (0..10)
            .map(|i| share(&names, &format!("n-{i:04}")))
            .collect();
        assert_eq!(names.read().bytes(), 10 * per_name, "full by bytes");
        // Full of names in use: new ones keep their own allocation.
        let refused = share(&names, "n-0010");
        assert!(!Arc::ptr_eq(&refused, &share(&names, "n-0010")));
        drop(held);
        // Now every name is unused: the next refusals sweep them out, and new ones fit.
        let mut shared_again = false;
        for i in 11..30 {
            let name = format!("n-{i:04}");
            let first = share(&names, &name);
            shared_again |= Arc::ptr_eq(&first, &share(&names, &name));
        }
        assert!(shared_again, "a sweep made room");
        assert!(names.read().bytes() <= 10 * per_name);
        names.read().sanity_check().unwrap();
    }
}
