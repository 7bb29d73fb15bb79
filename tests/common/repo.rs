//! The repository's own files, for the tests that hold the code and the documents to their
//! rules (`tests/core`: docs, module graph, file sizes, seeds).

use std::path::{Path, PathBuf};

/// The repository's root (the core crate's manifest directory).
pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Every file under `dir` that `keep` keeps, sorted; build output, Git's directory and
/// installed packages (`target`, `.git`, `node_modules`, virtual environments) left out.
pub fn files_under(dir: &Path, keep: impl Fn(&Path) -> bool) -> Vec<PathBuf> {
    let mut files = Vec::new();
    let mut stack = vec![dir.to_owned()];
    while let Some(dir) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            let name = entry.file_name();
            if ["target", ".git", "node_modules", ".venv"]
                .iter()
                .any(|skip| name == *skip)
            {
                continue;
            }
            if path.is_dir() {
                stack.push(path);
            } else if keep(&path) {
                files.push(path);
            }
        }
    }
    files.sort();
    files
}

/// Is `path` a Rust source?
pub fn is_rust(path: &Path) -> bool {
    path.extension().is_some_and(|e| e == "rs")
}

/// A source's part that is not its unit tests: everything before `#[cfg(test)] mod tests`.
pub fn non_test_part(text: &str) -> &str {
    match text.find("#[cfg(test)]\nmod tests") {
        Some(tests) => &text[..tests],
        None => text,
    }
}
