//! No source file grows past 700 lines of non-test code (its `#[cfg(test)] mod tests`
//! left out) unless [`ALLOWED`] names it with the reason it earns its size: a file that
//! long has usually grown a second job, and the split is cheaper before others build on
//! it. The library (`src/`), the tool (`src/bin/`) and the Python package's native crate
//! (`python/src/`) are held to it.

use crate::common::repo;

/// Lines of non-test code a source may have.
const LIMIT: usize = 700;

/// The files allowed past [`LIMIT`], each with its reason.
const ALLOWED: &[(&str, &str)] = &[(
    "src/rrd/reader.rs",
    "one state machine: the `.rrd` stream's framing, its messages and its footer decoded \
     in one loop, whose states only make sense together",
)];

fn oversized() -> Vec<(String, usize)> {
    let root = repo::root();
    ["src", "python/src"]
        .iter()
        .flat_map(|dir| repo::files_under(&root.join(dir), repo::is_rust))
        .filter(|path| !path.ends_with("tests.rs"))
        .filter_map(|path| {
            let text = std::fs::read_to_string(&path).ok()?;
            let lines = repo::non_test_part(&text).lines().count();
            let name = path.strip_prefix(root).ok()?.to_string_lossy().into_owned();
            (lines > LIMIT).then_some((name, lines))
        })
        .collect()
}

#[test]
fn no_source_file_passes_the_limit_without_a_reason() {
    let oversized = oversized();
    let unexplained: Vec<String> = oversized
        .iter()
        .filter(|(name, _)| !ALLOWED.iter().any(|(allowed, _)| allowed == name))
        .map(|(name, lines)| format!("{name}: {lines} lines of non-test code"))
        .collect();
    assert!(
        unexplained.is_empty(),
        "past {LIMIT} lines without a reason in tests/core/file_size.rs (split it by \
         job, or say why it earns its size):\n{}",
        unexplained.join("\n")
    );
    // An entry that no longer needs its reason goes.
    let stale: Vec<&str> = ALLOWED
        .iter()
        .map(|(name, _)| *name)
        .filter(|name| !oversized.iter().any(|(o, _)| o == name))
        .collect();
    assert!(stale.is_empty(), "allowed but within the limit: {stale:?}");
}

#[test]
fn the_count_leaves_out_unit_tests_only() {
    let text = "fn a() {}\n// note\n#[cfg(test)]\nmod tests {\n    fn t() {}\n}\n";
    assert_eq!(repo::non_test_part(text).lines().count(), 2);
    assert_eq!(repo::non_test_part("fn a() {}\n").lines().count(), 1);
    assert!(
        !oversized().is_empty() || ALLOWED.is_empty(),
        "sources were read"
    );
}
