//! The crate's own documents are complete: every "SEMANTICS.md section N" cited in the
//! code, tests and documents names a section of `docs/SEMANTICS.md`, and every `docs/…`
//! file mentioned exists. A user of the published crate needs nothing outside the repo.
#![allow(clippy::unwrap_used, reason = "a test fails loudly")]

use std::path::{Path, PathBuf};

use crate::common::repo::{self, root};

/// Every text file the check reads: sources, tests, examples, benches, fuzz harness, docs.
fn files() -> Vec<PathBuf> {
    let mut files = vec![root().join("README.md")];
    for dir in [
        "src",
        "tests",
        "examples",
        "benches",
        "docs",
        "fuzz/harness",
    ] {
        files.extend(repo::files_under(&root().join(dir), |path| {
            path.extension().is_some_and(|e| e == "rs" || e == "md")
                && !path.ends_with("tests/core/docs.rs")
        }));
    }
    files
}

/// The section numbers of `docs/SEMANTICS.md` (`## N. Title`).
fn sections() -> Vec<u32> {
    std::fs::read_to_string(root().join("docs/SEMANTICS.md"))
        .unwrap()
        .lines()
        .filter_map(|line| line.strip_prefix("## "))
        .filter_map(|title| title.split('.').next()?.parse().ok())
        .collect()
}

/// The numbers cited after each "SEMANTICS.md section" or "sections" in `text`: a list
/// such as `2, 5 and 6` or a span `6 to 8` (both ends).
fn citations(text: &str) -> Vec<(u32, String)> {
    let mut cited = Vec::new();
    for (at, _) in text.match_indices("SEMANTICS.md section") {
        let rest = &text[at + "SEMANTICS.md section".len()..];
        let rest = rest.strip_prefix('s').unwrap_or(rest);
        // The placeholder of "cites SEMANTICS.md section N" is no citation.
        let next = rest.trim_start();
        if next.starts_with('N') && !next[1..].starts_with(char::is_alphabetic) {
            continue;
        }
        let words: Vec<&str> = rest
            .split_whitespace()
            .take_while(|w| {
                let w = w.trim_end_matches([',', ')', '.', ':', ';']);
                w.parse::<u32>().is_ok() || w == "and" || w == "to"
            })
            .collect();
        let context: String = text[at..].chars().take(40).collect();
        for word in words {
            if let Ok(n) = word.trim_end_matches([',', ')', '.', ':', ';']).parse() {
                cited.push((n, context.clone()));
            }
        }
        if rest.trim_start().starts_with(|c: char| !c.is_ascii_digit()) {
            cited.push((0, context));
        }
    }
    cited
}

#[test]
fn every_semantics_citation_names_a_section() {
    let sections = sections();
    assert!(sections.len() >= 10, "{sections:?}");
    let mut checked = 0;
    for file in files() {
        let text = std::fs::read_to_string(&file).unwrap();
        for (n, context) in citations(&text) {
            assert!(
                sections.contains(&n),
                "{}: {context:?} cites no section of docs/SEMANTICS.md",
                file.display()
            );
            checked += 1;
        }
    }
    assert!(checked > 10, "citations were found ({checked})");
}

#[test]
fn every_docs_file_mentioned_exists() {
    for file in files() {
        let text = std::fs::read_to_string(&file).unwrap();
        for (at, _) in text.match_indices("docs/") {
            let name: String = text[at..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || matches!(c, '/' | '_' | '.' | '-'))
                .collect();
            let name = name.trim_end_matches('.');
            if !Path::new(name)
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("md"))
                || text[..at].ends_with("shared/")
                || text[..at].ends_with("../")
            {
                continue;
            }
            assert!(
                root().join(name).exists(),
                "{} mentions {name}, which does not exist",
                file.display()
            );
        }
    }
}

#[test]
fn citations_are_read_in_every_form() {
    let cited = |text: &str| citations(text).into_iter().map(|c| c.0).collect::<Vec<_>>();
    assert_eq!(cited("see SEMANTICS.md section 6."), [6]);
    assert_eq!(cited("(SEMANTICS.md sections 2, 5 and 6)"), [2, 5, 6]);
    assert_eq!(cited("SEMANTICS.md sections 6 to 8"), [6, 8]);
    assert_eq!(cited("SEMANTICS.md section Transport"), [0]);
}
