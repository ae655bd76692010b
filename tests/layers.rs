//! The layers stay layers: read from the sources, each folder of the library
//! imports only the folders below it (the order of `src/lib.rs`'s doc
//! comment), and no two files of the library or of the C ABI import each
//! other, directly or around a longer circle. A `mod.rs` only declares and
//! re-exports its folder's files, so its own imports are not edges.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The library's folders, lowest first.
const LAYERS: [&str; 15] = ["error", "profile", "threads", "memory", "math", "field", "backend", "input", "model", "render", "format", "encode", "series", "domain", "io"];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The paths after every `crate::` outside comments, as segments.
fn crate_paths(text: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    for line in text.lines() {
        let code = line.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(i) = rest.find("crate::") {
            rest = &rest[i + 7..];
            let path: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':').collect();
            out.push(path.split("::").filter(|s| !s.is_empty()).map(str::to_owned).collect());
        }
    }
    out
}

/// The module of a file under `base`: `input/prepare.rs` -> ["input", "prepare"].
fn module_of(base: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(base).unwrap().with_extension("");
    let mut m: Vec<String> = rel.components().map(|c| c.as_os_str().to_string_lossy().into_owned()).collect();
    if m.last().is_some_and(|s| s == "mod" || s == "lib") {
        m.pop();
    }
    m
}

/// Edges between the modules (files) of the crate rooted at `base`: the
/// longest known module that prefixes each `crate::` path.
fn module_graph(base: &Path) -> BTreeMap<Vec<String>, BTreeSet<Vec<String>>> {
    let mut files = Vec::new();
    rust_files(base, &mut files);
    let modules: BTreeSet<Vec<String>> = files.iter().map(|f| module_of(base, f)).collect();
    let mut graph = BTreeMap::new();
    for f in &files {
        let from = module_of(base, f);
        let name = f.file_name().unwrap().to_string_lossy();
        let edges: &mut BTreeSet<Vec<String>> = graph.entry(from.clone()).or_default();
        if name == "mod.rs" || name == "lib.rs" {
            continue;
        }
        for path in crate_paths(&std::fs::read_to_string(f).unwrap()) {
            let target = (1..=path.len()).rev().map(|k| path[..k].to_vec()).find(|m| modules.contains(m));
            if let Some(t) = target.filter(|t| *t != from && !t.is_empty()) {
                edges.insert(t);
            }
        }
    }
    graph
}

/// A circle of imports, if there is one.
fn find_cycle(graph: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>) -> Option<Vec<String>> {
    fn visit(
        n: &Vec<String>,
        graph: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>,
        state: &mut BTreeMap<Vec<String>, u8>,
        stack: &mut Vec<Vec<String>>,
    ) -> Option<Vec<String>> {
        match state.get(n) {
            Some(2) => return None,
            Some(1) => {
                let at = stack.iter().position(|m| m == n).unwrap();
                return Some(stack[at..].iter().chain([n]).map(|m| m.join("::")).collect());
            }
            _ => {}
        }
        state.insert(n.clone(), 1);
        stack.push(n.clone());
        for m in graph.get(n).into_iter().flatten() {
            if let Some(c) = visit(m, graph, state, stack) {
                return Some(c);
            }
        }
        stack.pop();
        state.insert(n.clone(), 2);
        None
    }
    let mut state = BTreeMap::new();
    graph.keys().find_map(|n| visit(n, graph, &mut state, &mut Vec::new()))
}

fn layer_rank(m: &[String]) -> Option<usize> {
    m.first().and_then(|l| LAYERS.iter().position(|x| x == l))
}

/// Imports from a layer into one above it.
fn upward_imports(graph: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>) -> Vec<String> {
    let mut upward = Vec::new();
    for (from, to) in graph {
        let Some(r) = layer_rank(from) else { continue };
        for t in to.iter().filter(|t| layer_rank(t).is_some_and(|rt| rt > r)) {
            upward.push(format!("{} imports {}", from.join("::"), t.join("::")));
        }
    }
    upward
}

#[test]
fn each_folder_of_the_library_imports_only_the_ones_below() {
    let graph = module_graph(&root().join("src"));
    let upward = upward_imports(&graph);
    assert!(upward.is_empty(), "imports against the layers:\n{}", upward.join("\n"));
    // Every folder is a known layer (a new one must be placed in LAYERS).
    for m in graph.keys().filter(|m| !m.is_empty()) {
        assert!(layer_rank(m).is_some(), "module {} is in no layer of LAYERS", m.join("::"));
    }
}

#[test]
fn no_circles_of_imports_in_the_library_or_the_c_abi() {
    for dir in ["src", "capi"] {
        let graph = module_graph(&root().join(dir));
        assert!(graph.len() > 5, "{dir}: too few modules found ({})", graph.len());
        if let Some(cycle) = find_cycle(&graph) {
            panic!("{dir}: a circle of imports: {}", cycle.join(" -> "));
        }
    }
}

/// The checks above can fail: a made-up graph with an upward import and a
/// circle is caught by the same functions, and commented-out imports are
/// not imports.
#[test]
fn the_checks_find_upward_imports_and_circles() {
    let m = |s: &str| s.split("::").map(str::to_owned).collect::<Vec<_>>();
    let mut g = BTreeMap::new();
    g.insert(m("input::cells"), BTreeSet::from([m("input::prepare")]));
    g.insert(m("input::prepare"), BTreeSet::from([m("input::cells"), m("field::frame"), m("io::models")]));
    g.insert(m("field::frame"), BTreeSet::new());
    let c = find_cycle(&g).expect("the circle cells -> prepare -> cells");
    assert_eq!(c.first(), c.last());
    assert_eq!(upward_imports(&g), ["input::prepare imports io::models"]);
    assert_eq!(crate_paths("use crate::input::prepare::{X, Y}; // crate::io::x"), vec![m("input::prepare")]);
}
