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
//! The sets only grow, so each is capped: past [`MAX_SHARED`] distinct values (far more
//! than any schema has; only generated names get there) a new value keeps its own
//! allocation, which is just as correct.

use std::hash::Hash;
use std::sync::{Arc, OnceLock};

use arrow_schema::{Field, FieldRef};
use parking_lot::RwLock;

/// How many distinct values of each kind are shared at most.
pub(crate) const MAX_SHARED: usize = 16_384;

type SharedSet<T> = RwLock<ahash::HashSet<Arc<T>>>;

fn shared_names() -> &'static SharedSet<str> {
    static NAMES: OnceLock<SharedSet<str>> = OnceLock::new();
    NAMES.get_or_init(RwLock::default)
}

fn shared_fields() -> &'static SharedSet<Field> {
    static FIELDS: OnceLock<SharedSet<Field>> = OnceLock::new();
    FIELDS.get_or_init(RwLock::default)
}

/// The shared copy of `name`: an earlier equal name's allocation if there is one, else
/// `name` itself, now shared (while the set has room).
pub(crate) fn share_name(name: Arc<str>) -> Arc<str> {
    share_in(shared_names(), MAX_SHARED, name)
}

/// The shared copy of a list's item field, as [`share_name`] does for names.
pub(crate) fn share_field(field: &FieldRef) -> FieldRef {
    share_in(shared_fields(), MAX_SHARED, Arc::clone(field))
}

/// Is `field` the shared copy (so that no chunk owns it)?
pub(crate) fn is_shared_field(field: &FieldRef) -> bool {
    shared_fields()
        .read()
        .get(&**field)
        .is_some_and(|shared| Arc::ptr_eq(shared, field))
}

/// Are two names equal? Pointers first: equal names are usually the one shared copy, and
/// std's `Arc` equality takes that shortcut only for sized types (for `str` it always
/// compares the bytes).
pub(crate) fn same_name(a: &Arc<str>, b: &Arc<str>) -> bool {
    Arc::ptr_eq(a, b) || a == b
}

/// Orders two names by their text, with the same shortcut as [`same_name`].
pub(crate) fn cmp_names(a: &Arc<str>, b: &Arc<str>) -> std::cmp::Ordering {
    if Arc::ptr_eq(a, b) {
        std::cmp::Ordering::Equal
    } else {
        a.cmp(b)
    }
}

fn share_in<T: ?Sized + Hash + Eq>(set: &SharedSet<T>, cap: usize, value: Arc<T>) -> Arc<T> {
    if let Some(shared) = set.read().get(&*value) {
        return Arc::clone(shared);
    }
    let mut set = set.write();
    if let Some(shared) = set.get(&*value) {
        return Arc::clone(shared);
    }
    if set.len() < cap {
        set.insert(Arc::clone(&value));
    }
    value
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_names_share_one_allocation() {
        let names = SharedSet::<str>::default();
        let a = share_in(&names, 8, Arc::from("frame"));
        let b = share_in(&names, 8, Arc::from(String::from("frame")));
        assert!(Arc::ptr_eq(&a, &b));
        let other = share_in(&names, 8, Arc::from("log_time"));
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
        assert!(!is_shared_field(&second));
    }

    #[test]
    fn past_the_cap_names_keep_their_own_allocation() {
        let names = SharedSet::<str>::default();
        for i in 0..4 {
            share_in(&names, 4, Arc::from(format!("fill-{i}")));
        }
        let late = Arc::<str>::from("late");
        let shared = share_in(&names, 4, Arc::clone(&late));
        assert!(Arc::ptr_eq(&late, &shared));
        assert_eq!(names.read().len(), 4);
        // An earlier name is still shared.
        let again = share_in(&names, 4, Arc::from("fill-0"));
        assert!(Arc::ptr_eq(&again, names.read().get("fill-0").unwrap()));
    }
}
