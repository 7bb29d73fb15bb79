//! Every proptest seed in the repository is read by a test: each seed file is under
//! `tests/proptest-regressions/`, and a test names it (`common::seed_file`, or
//! `FileFailurePersistence::Direct` in the library's unit tests); every property test
//! names its file, so that none falls back to proptest's default, which derives the file
//! from the source's path (when the tests moved into folders, 16 seeds stayed behind
//! where nothing read them).

use std::path::{Path, PathBuf};

use crate::common::repo;

const SEEDS: &str = "tests/proptest-regressions";

fn is_seed_file(path: &Path) -> bool {
    let text = path.to_string_lossy();
    text.ends_with(".proptest-regressions") || text.contains("proptest-regressions/")
}

/// The Rust sources of the core crate's library and tests and of the Python package's
/// native crate, by path relative to the root.
fn rust_sources(root: &Path) -> Vec<(PathBuf, String)> {
    ["src", "tests", "python/src"]
        .iter()
        .flat_map(|dir| repo::files_under(&root.join(dir), repo::is_rust))
        .map(|path| {
            let text = std::fs::read_to_string(&path).unwrap_or_default();
            (path.strip_prefix(root).unwrap_or(&path).to_owned(), text)
        })
        .collect()
}

#[test]
fn every_seed_file_is_read_by_a_test_and_every_property_test_names_one() {
    let root = repo::root();
    let seed_files: Vec<PathBuf> = repo::files_under(root, is_seed_file)
        .into_iter()
        .map(|path| path.strip_prefix(root).unwrap_or(&path).to_owned())
        .collect();
    let sources = rust_sources(root);
    let mut problems = Vec::new();
    for file in &seed_files {
        let Ok(relative) = file.strip_prefix(SEEDS) else {
            problems.push(format!("{}: a seed file outside {SEEDS}/", file.display()));
            continue;
        };
        // Named as `seed_file("model/main.txt")` or `Direct(".../model/main.txt")`.
        let named = format!("{}\"", relative.display());
        let quoted = [format!("\"{named}"), format!("/{named}")];
        if !sources
            .iter()
            .any(|(_, text)| quoted.iter().any(|q| text.contains(q.as_str())))
        {
            problems.push(format!("{}: no test reads it", file.display()));
        }
    }
    for (path, text) in &sources {
        if path.ends_with("tests/core/seeds.rs") {
            continue;
        }
        let tests = text.matches("proptest! {").count() + text.matches("proptest!(").count();
        let named = text.matches("seed_file(").count()
            + text.matches("FileFailurePersistence::Direct(").count();
        if tests > named {
            problems.push(format!(
                "{}: {tests} property tests name {named} seed files",
                path.display()
            ));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
    assert!(
        seed_files.len() >= 4,
        "the seed files were not found: {seed_files:?}"
    );
}
