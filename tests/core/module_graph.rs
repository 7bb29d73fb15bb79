//! The module graph is one-way: no module imports from a module that imports it back.
//!
//! Read from the sources, not from the compiler: every `crate::…` and `super::…` path in
//! library code (comments and `#[cfg(test)] mod tests` left out) is an edge from its file's
//! module to the module it names, a name re-exported by `lib.rs` or a directory's `mod.rs`
//! counting for the module that defines it. Two graphs must have no cycle:
//! - the crate's top-level modules (`src/x.rs`, `src/x/`);
//! - within each directory, at every depth, its files and subdirectories, leaving out edges
//!   to the directory's own `mod.rs` (a parent owns its children: their items and `impl`
//!   blocks are its parts).
//!
//! The same holds for the tool, `src/bin/chunkstore/`, a crate of its own.
//!
//! `cargo test --test core module_graph -- --nocapture` prints the layers of the top-level
//! graph, which `docs/ARCHITECTURE.md` draws.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a test fails loudly"
)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use crate::common::repo;

/// A module's source: its path (`store::entity`) and its library code.
struct Module {
    path: Vec<String>,
    code: String,
}

fn library_code(text: &str) -> String {
    repo::non_test_part(text)
        .lines()
        .map(|line| match line.find("//") {
            Some(comment) => &line[..comment],
            None => line,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// The modules of the crate whose root is in `src`: the library (`src/`, `lib.rs`; the
/// tool in `src/bin/` is a crate of its own, a user of the library) or the tool
/// (`src/bin/chunkstore/`, `main.rs`).
fn modules(src: &Path) -> Vec<Module> {
    let bin = repo::root().join("src/bin");
    let mut modules = Vec::new();
    for path in repo::files_under(src, repo::is_rust) {
        if !src.starts_with(&bin) && path.starts_with(&bin) {
            continue;
        }
        let relative = path.strip_prefix(src).unwrap();
        let mut parts: Vec<String> = relative
            .iter()
            .map(|p| p.to_string_lossy().into_owned())
            .collect();
        let file = parts.pop().unwrap();
        match file.as_str() {
            "lib.rs" | "main.rs" | "mod.rs" => {}
            "tests.rs" => continue, // a `#[cfg(test)] mod tests;`
            other => parts.push(other.trim_end_matches(".rs").to_owned()),
        }
        let code = library_code(&std::fs::read_to_string(&path).unwrap());
        modules.push(Module { path: parts, code });
    }
    modules.sort_by(|a, b| a.path.cmp(&b.path));
    modules
}

fn library() -> Vec<Module> {
    modules(&repo::root().join("src"))
}

fn tool() -> Vec<Module> {
    modules(&repo::root().join("src/bin/chunkstore"))
}

/// Every path of a `use` tree such as `a::{b, c::{d, e}}` (without the leading `a::` when
/// `prefix` is empty), as segment lists.
fn expand_tree(tree: &str, prefix: &[String], out: &mut Vec<Vec<String>>) {
    let tree = tree.trim();
    if let Some(open) = tree.find('{') {
        let head: Vec<String> = tree[..open]
            .split("::")
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(str::to_owned)
            .collect();
        let mut base = prefix.to_vec();
        base.extend(head);
        let inner = &tree[open + 1..tree.rfind('}').unwrap()];
        let (mut depth, mut start) = (0, 0);
        for (i, c) in inner.char_indices() {
            match c {
                '{' => depth += 1,
                '}' => depth -= 1,
                ',' if depth == 0 => {
                    expand_tree(&inner[start..i], &base, out);
                    start = i + 1;
                }
                _ => {}
            }
        }
        expand_tree(&inner[start..], &base, out);
    } else if !tree.is_empty() {
        let mut path = prefix.to_vec();
        let tree = tree.split(" as ").next().unwrap();
        path.extend(tree.split("::").map(|s| s.trim().to_owned()));
        out.push(path);
    }
}

/// Every path the code names through `crate::` or `super::`, as absolute segment lists.
fn references(module: &Module) -> Vec<Vec<String>> {
    let mut found = Vec::new();
    for (anchor, base) in [
        ("crate::", Vec::new()),
        (
            "super::",
            module.path[..module.path.len().saturating_sub(1)].to_vec(),
        ),
    ] {
        let code = &module.code;
        let mut from = 0;
        while let Some(at) = code[from..].find(anchor) {
            let start = from + at;
            from = start + anchor.len();
            let preceded = code[..start].chars().next_back();
            if preceded.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':') {
                continue;
            }
            let rest = &code[from..];
            let end = if rest.starts_with('{') {
                let mut depth = 0;
                rest.char_indices()
                    .find(|&(_, c)| {
                        match c {
                            '{' => depth += 1,
                            '}' => depth -= 1,
                            _ => {}
                        }
                        depth == 0
                    })
                    .map_or(rest.len(), |(i, _)| i + 1)
            } else {
                rest.find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                    .unwrap_or(rest.len())
            };
            expand_tree(rest[..end].trim_end_matches(':'), &base, &mut found);
        }
    }
    found
}

/// For `lib.rs` (`[]`) or a directory's `mod.rs`: each re-exported or imported name, with
/// the segments it comes from relative to that module (`pub use store::{ChunkStore}` maps
/// `ChunkStore` to `[store]`).
fn imports(module: &Module) -> BTreeMap<String, Vec<String>> {
    let mut names = BTreeMap::new();
    let code = &module.code;
    let mut from = 0;
    while let Some(at) = code[from..].find("use ") {
        let start = from + at + 4;
        from = start;
        let line_start = code[..start].rfind('\n').map_or(0, |n| n + 1);
        let before = code[line_start..start - 4].trim();
        if !(before.is_empty() || before.starts_with("pub")) {
            continue;
        }
        let end = start + code[start..].find(';').unwrap();
        let tree = &code[start..end];
        if tree.starts_with("crate::") || tree.starts_with("super::") || tree.starts_with("std") {
            continue;
        }
        let mut paths = Vec::new();
        expand_tree(tree, &[], &mut paths);
        for path in paths {
            if let Some((name, source)) = path.split_last() {
                names.insert(name.clone(), source.to_vec());
            }
        }
    }
    names
}

/// The module (absolute segments) an absolute path names: its longest prefix that is a
/// module, following re-exports of the modules on the way.
fn resolve(
    path: &[String],
    known: &BTreeSet<Vec<String>>,
    reexports: &BTreeMap<Vec<String>, BTreeMap<String, Vec<String>>>,
) -> Vec<String> {
    let mut module: Vec<String> = Vec::new();
    for segment in path {
        let mut child = module.clone();
        child.push(segment.clone());
        if known.contains(&child) {
            module = child;
            continue;
        }
        // An item of `module`: maybe one it re-exports from a submodule.
        if let Some(source) = reexports.get(&module).and_then(|r| r.get(segment)) {
            let mut target = module.clone();
            target.extend(source.iter().cloned());
            target.push(segment.clone());
            return resolve(&target, known, reexports);
        }
        break;
    }
    module
}

/// A cycle of `graph`, if it has one.
fn find_cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(node.to_owned(), 1);
        stack.push(node.to_owned());
        for next in graph.get(node).into_iter().flatten() {
            match state.get(next.as_str()).copied().unwrap_or(0) {
                1 => {
                    let from = stack.iter().position(|n| n == next).unwrap();
                    let mut cycle = stack[from..].to_vec();
                    cycle.push(next.clone());
                    return Some(cycle);
                }
                0 => {
                    if let Some(cycle) = visit(next, graph, state, stack) {
                        return Some(cycle);
                    }
                }
                _ => {}
            }
        }
        stack.pop();
        state.insert(node.to_owned(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for node in graph.keys() {
        if state.get(node.as_str()).copied().unwrap_or(0) == 0
            && let Some(cycle) = visit(node, graph, &mut state, &mut Vec::new())
        {
            return Some(cycle);
        }
    }
    None
}

/// Each node's imports.
type Graph = BTreeMap<String, BTreeSet<String>>;

/// A graph per directory, by its path (`""` for the crate's top-level modules, `sql`,
/// `sql/dataset`): its files and subdirectories, each with those it imports. An item of a
/// subdirectory is the subdirectory's; an import of the directory's own `mod.rs` is no
/// edge (a parent owns its children: their items and `impl` blocks are its parts).
fn graphs(modules: &[Module]) -> BTreeMap<String, Graph> {
    let known: BTreeSet<Vec<String>> = modules.iter().map(|m| m.path.clone()).collect();
    let reexports: BTreeMap<Vec<String>, BTreeMap<String, Vec<String>>> = modules
        .iter()
        .filter(|m| {
            m.path.is_empty()
                || known
                    .iter()
                    .any(|k| k.len() > m.path.len() && k.starts_with(&m.path))
        })
        .map(|m| (m.path.clone(), imports(m)))
        .collect();
    let mut graphs: BTreeMap<String, Graph> = BTreeMap::new();
    for module in modules.iter().filter(|m| !m.path.is_empty()) {
        // The module is a node of each directory above it: `sql/dataset/scan` is `sql` in
        // the top-level graph, `dataset` in `sql`'s and `scan` in `sql/dataset`'s.
        for depth in 0..module.path.len() {
            graphs
                .entry(module.path[..depth].join("/"))
                .or_default()
                .entry(module.path[depth].clone())
                .or_default();
        }
        for path in references(module) {
            let target = resolve(&path, &known, &reexports);
            for depth in 0..module.path.len() {
                if !target.starts_with(&module.path[..depth]) {
                    break;
                }
                if let Some(node) = target.get(depth)
                    && *node != module.path[depth]
                {
                    graphs
                        .get_mut(&module.path[..depth].join("/"))
                        .unwrap()
                        .get_mut(&module.path[depth])
                        .unwrap()
                        .insert(node.clone());
                    break;
                }
            }
        }
    }
    graphs
}

/// Layers of an acyclic graph: each module after everything it imports.
fn layers(graph: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    let mut placed: BTreeMap<String, usize> = BTreeMap::new();
    let mut layers: Vec<Vec<String>> = Vec::new();
    while placed.len() < graph.len() {
        let ready: Vec<String> = graph
            .iter()
            .filter(|(n, deps)| {
                !placed.contains_key(*n) && deps.iter().all(|d| placed.contains_key(d))
            })
            .map(|(n, _)| n.clone())
            .collect();
        assert!(!ready.is_empty(), "a cycle");
        for n in &ready {
            placed.insert(n.clone(), layers.len());
        }
        layers.push(ready);
    }
    layers
}

#[test]
fn the_top_level_module_graph_has_no_cycle() {
    let graphs = graphs(&library());
    let top = &graphs[""];
    assert!(top.len() > 10, "the sources were read: {top:?}");
    assert!(
        top["store"].contains("chunk") && top["insert"].contains("store"),
        "edges are found: {top:?}"
    );
    if let Some(cycle) = find_cycle(top) {
        panic!("modules import each other: {}", cycle.join(" -> "));
    }
    for (depth, layer) in layers(top).iter().enumerate() {
        println!("layer {depth}: {}", layer.join(", "));
    }
    for (module, imports) in top {
        println!(
            "{module} -> {}",
            imports.iter().cloned().collect::<Vec<_>>().join(", ")
        );
    }
}

/// Every directory's graph of `modules` is acyclic; prints the edges.
fn assert_one_way(crate_name: &str, graphs: &BTreeMap<String, Graph>) {
    for (dir, graph) in graphs {
        if let Some(cycle) = find_cycle(graph) {
            panic!(
                "{crate_name}: files of {}/ import each other: {}",
                if dir.is_empty() { "the top level" } else { dir },
                cycle.join(" -> ")
            );
        }
        for (file, imports) in graph {
            println!(
                "{crate_name}: {dir}/{file} -> {}",
                imports.iter().cloned().collect::<Vec<_>>().join(", ")
            );
        }
    }
}

#[test]
fn the_files_of_each_directory_import_one_way() {
    let graphs = graphs(&library());
    assert!(
        graphs["store"].len() > 3 && graphs["sql/dataset"]["tables"].contains("scan"),
        "every directory, at every depth, is read: {graphs:?}"
    );
    assert_one_way("the library", &graphs);
}

#[test]
fn the_tools_modules_import_one_way() {
    let graphs = graphs(&tool());
    assert!(
        graphs[""].len() > 5 && graphs.contains_key("commands/serve"),
        "the tool's sources were read: {graphs:?}"
    );
    assert_one_way("src/bin/chunkstore", &graphs);
}

#[test]
fn a_cycle_is_found() {
    let graph: BTreeMap<String, BTreeSet<String>> = [
        ("a", vec!["b"]),
        ("b", vec!["c"]),
        ("c", vec!["a"]),
        ("d", vec![]),
    ]
    .into_iter()
    .map(|(n, d)| (n.to_owned(), d.into_iter().map(str::to_owned).collect()))
    .collect();
    assert_eq!(find_cycle(&graph).unwrap(), ["a", "b", "c", "a"]);
    let mut paths = Vec::new();
    expand_tree("a::{b, c::{d, e as f}}", &[], &mut paths);
    assert_eq!(
        paths,
        [vec!["a", "b"], vec!["a", "c", "d"], vec!["a", "c", "e"]]
    );
}
