//! One shared copy of each timeline and component name, process-wide.
//!
//! Every chunk names its timelines and components, and a store compares those names on
//! every insert, removal and query (its per-entity maps are keyed by them). Built
//! independently, each chunk would carry its own allocation of `frame` and of
//! `Points3D:positions`: memory per chunk, and a cold cache line at each comparison.
//! [`crate::Timeline::new`] and [`crate::ComponentName::new`] hand out the shared copy
//! instead, so equal names are usually the same allocation (`Arc::ptr_eq`, which `Arc`'s
//! equality checks first) and the one copy stays in cache.
//!
//! The set only grows, so it is capped: past [`MAX_SHARED_NAMES`] distinct names (far more
//! than any schema has; only generated names get there) a new name keeps its own
//! allocation, which is just as correct.

use std::sync::{Arc, OnceLock};

use parking_lot::RwLock;

/// How many distinct names are shared at most.
pub(crate) const MAX_SHARED_NAMES: usize = 16_384;

fn shared_names() -> &'static NameSet {
    static NAMES: OnceLock<NameSet> = OnceLock::new();
    NAMES.get_or_init(RwLock::default)
}

/// The shared copy of `name`: an earlier equal name's allocation if there is one, else
/// `name` itself, now shared (while the set has room).
pub(crate) fn share(name: Arc<str>) -> Arc<str> {
    share_in(shared_names(), MAX_SHARED_NAMES, name)
}

type NameSet = RwLock<ahash::HashSet<Arc<str>>>;

fn share_in(names: &NameSet, cap: usize, name: Arc<str>) -> Arc<str> {
    if let Some(shared) = names.read().get(&*name) {
        return Arc::clone(shared);
    }
    let mut names = names.write();
    if let Some(shared) = names.get(&*name) {
        return Arc::clone(shared);
    }
    if names.len() < cap {
        names.insert(Arc::clone(&name));
    }
    name
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_names_share_one_allocation() {
        let names = NameSet::default();
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
        assert_eq!(x, y);
    }

    #[test]
    fn past_the_cap_names_keep_their_own_allocation() {
        let names = NameSet::default();
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
