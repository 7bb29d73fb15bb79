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

/// The text between backticks (code spans) of a Markdown text.
fn code_spans(text: &str) -> impl Iterator<Item = &str> {
    text.split('`').skip(1).step_by(2)
}

/// `docs/PERFORMANCE.md` is the present, not a log: at most 300 lines, and every section
/// of figures says when, at which commit and with which command they were measured (the
/// history goes to `docs/performance-log.md`).
#[test]
fn performance_md_holds_the_present_only() {
    let text = std::fs::read_to_string(root().join("docs/PERFORMANCE.md")).unwrap();
    let lines = text.lines().count();
    assert!(
        lines <= 300,
        "docs/PERFORMANCE.md has {lines} lines: keep the current figures (one table per \
         dimension) and move the story to docs/performance-log.md"
    );
    let is_date = |w: &str| {
        let b = w.as_bytes();
        b.len() >= 10
            && b[..10].iter().enumerate().all(|(i, c)| {
                if i == 4 || i == 7 {
                    *c == b'-'
                } else {
                    c.is_ascii_digit()
                }
            })
    };
    let mut problems = Vec::new();
    for section in text.split("\n## ").skip(1) {
        let title = section.lines().next().unwrap_or_default();
        if title == "Reproducing" {
            continue;
        }
        // A commit is 7 to 40 hex digits; a command starts with a tool.
        let spans: Vec<&str> = code_spans(section).collect();
        let has_date = section
            .split(|c: char| c.is_whitespace() || c == '(' || c == ',')
            .any(is_date);
        let has_commit = spans
            .iter()
            .any(|s| (7..=40).contains(&s.len()) && s.chars().all(|c| c.is_ascii_hexdigit()));
        let has_command = spans.iter().any(|s| {
            // Past any `NAME=value` settings of the environment.
            let command = s
                .split_whitespace()
                .skip_while(|w| w.contains('=') && !w.starts_with('-'))
                .collect::<Vec<_>>()
                .join(" ");
            [
                "cargo ",
                "python ",
                "chunkstore ",
                "../shared/bench/compare",
                "dataset_bench ",
            ]
            .iter()
            .any(|tool| command.starts_with(tool))
        });
        for (ok, what) in [
            (has_date, "date"),
            (has_commit, "commit"),
            (has_command, "command"),
        ] {
            if !ok {
                problems.push(format!("section {title:?} names no {what}"));
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// `CHANGELOG.md` has one `Unreleased` section, each kind of change under one heading in
/// a section, and performance entries of one line each (the headline figure; the story is
/// in the performance log).
#[test]
fn the_changelog_has_one_unreleased_section_and_one_line_performance_entries() {
    let text = std::fs::read_to_string(root().join("CHANGELOG.md")).unwrap();
    let unreleased = text
        .lines()
        .filter(|l| l.starts_with("## ") && l.contains("Unreleased"))
        .count();
    assert_eq!(unreleased, 1, "one `## Unreleased` section");
    for section in text.split("\n## ").skip(1) {
        let title = section.lines().next().unwrap_or_default();
        let mut headings: Vec<&str> = section
            .lines()
            .filter_map(|l| l.strip_prefix("### "))
            .map(|h| h.split(" (").next().unwrap_or(h))
            .collect();
        let all = headings.len();
        headings.sort_unstable();
        headings.dedup();
        assert_eq!(
            headings.len(),
            all,
            "{title}: a kind of change under two headings"
        );
        if let Some(performance) = section.split("\n### Performance\n").nth(1) {
            let performance = performance.split("\n### ").next().unwrap_or_default();
            for line in performance.lines().filter(|l| !l.trim().is_empty()) {
                assert!(
                    line.starts_with("- "),
                    "{title}: a performance entry runs past one line: {line:?}"
                );
            }
        }
    }
}

/// Every file or folder of the repository that `README.md` and `docs/` name in backticks
/// (`tests/cli/`, `src/rrd/reader.rs`, `scripts/capture_cli.sh`) exists: moving a file
/// leaves no document pointing at its old place. `docs/performance-log.md` and the
/// CHANGELOG are history, and name files as they were.
#[test]
fn every_repository_path_the_documents_name_exists() {
    const ROOTS: [&str; 7] = [
        "src/",
        "tests/",
        "benches/",
        "examples/",
        "scripts/",
        "python/",
        "fuzz/",
    ];
    const KINDS: [&str; 6] = [".rs", ".py", ".md", ".sh", ".toml", "/"];
    let mut documents = vec![root().join("README.md")];
    documents.extend(repo::files_under(&root().join("docs"), |path| {
        path.extension().is_some_and(|e| e == "md") && !path.ends_with("performance-log.md")
    }));
    let mut missing = Vec::new();
    let mut checked = 0;
    for document in &documents {
        let text = std::fs::read_to_string(document).unwrap();
        for span in code_spans(&text) {
            let path = span
                .split(|c: char| c.is_whitespace() || c == ':')
                .next()
                .unwrap_or_default();
            if !ROOTS.iter().any(|r| path.starts_with(r))
                || !KINDS.iter().any(|k| path.ends_with(k))
            {
                continue;
            }
            checked += 1;
            if !root().join(path).exists() {
                missing.push(format!("{} names {path}", document.display()));
            }
        }
    }
    assert!(checked > 20, "paths were found: {checked}");
    assert!(missing.is_empty(), "{}", missing.join("\n"));
}
