//! The source tree reads bottom-up: each room of `host-sim/src` (a top-level folder, or a
//! group of top-level files) imports only the rooms at or below it in [`LAYERS`], the library
//! never names the command line (`cli/`, declared from `main.rs` only), and no two source
//! files import each other, directly or around a circle.
//!
//! Imports are the `crate::…`, `super::…` and `self::…` paths of each file, outside comments
//! and `#[cfg(test)]` modules (tests may reach anywhere). Pure Rust: the check reads the files.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The rooms of `host-sim/src`, lowest first, each with the top-level modules it holds. A room
/// may import itself and the rooms listed before it, never one listed after it:
///
/// - utilities: numerical helpers, argument checks and the rule of which files host-sim may
///   replace (`output`), no model;
/// - `plant`: the joint, its effects and their files;
/// - `sim`: integration of a plant under given valve inputs;
/// - `io`: files in and out (recordings, scenarios, run outputs, plots) and the replays that
///   read a recording, integrate it and write one;
/// - `identify`, `control`, `diagnose`: the jobs, each free to use the ones before it (the
///   comparisons and `calibrate` in `control` use the identification);
/// - the demos, then the command line (`main.rs` and `cli/`), which nothing imports.
///
/// `lib.rs` (the crate's table of contents and re-exports) is in no room.
const LAYERS: &[(&str, &[&str])] = &[
    (
        "utilities",
        &[
            "output", "validate", "fit", "optimize", "signal", "defaults",
        ],
    ),
    ("plant", &["plant"]),
    ("sim", &["sim"]),
    ("io", &["io"]),
    ("identify", &["identify"]),
    ("control", &["control"]),
    ("diagnose", &["diagnose"]),
    ("demo", &["demo", "demo_arm3"]),
    ("cli", &["cli", "main"]),
];

fn src_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file under `dir`, relative to `src`.
fn rust_files(src: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(src, &p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p.strip_prefix(src).unwrap().to_path_buf());
        }
    }
}

/// The module path of a file: `io/recording.rs` -> [io, recording], `plant/mod.rs` -> [plant],
/// `lib.rs` -> [], `main.rs` -> [main] (the binary's root, a room of its own).
fn module_of(file: &Path) -> Vec<String> {
    let mut parts: Vec<String> = file
        .with_extension("")
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if parts.last().is_some_and(|l| l == "mod" || l == "lib") {
        parts.pop();
    }
    parts
}

/// The source without comments and without `#[cfg(test)]` modules (a `mod … {` line after a
/// `#[cfg(test)]` line, up to the closing `}` in the first column).
fn code_of(text: &str) -> String {
    let mut out = String::new();
    let mut lines = text.lines().peekable();
    let mut previous = "";
    while let Some(line) = lines.next() {
        let t = line.trim_start();
        if previous.trim() == "#[cfg(test)]" && t.starts_with("mod ") && t.trim_end().ends_with('{')
        {
            let indent = line.len() - t.len();
            for inner in lines.by_ref() {
                if inner.len() - inner.trim_start().len() == indent && inner.trim() == "}" {
                    break;
                }
            }
            previous = "";
            continue;
        }
        let code = match line.find("//") {
            Some(i) => &line[..i],
            None => line,
        };
        out.push_str(code);
        out.push('\n');
        previous = line;
    }
    out
}

/// The absolute module paths a file names: `crate::a::b`, `super::x`, `self::y`.
fn paths_named(code: &str, module: &[String]) -> Vec<Vec<String>> {
    let bytes = code.as_bytes();
    let ident = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    let mut found = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        if !ident(bytes[i]) || (i > 0 && (ident(bytes[i - 1]) || bytes[i - 1] == b':')) {
            i += 1;
            continue;
        }
        let start = i;
        while i < bytes.len() && ident(bytes[i]) {
            i += 1;
        }
        let root = &code[start..i];
        if !matches!(root, "crate" | "super" | "self") || !code[i..].starts_with("::") {
            continue;
        }
        let mut segments = vec![root.to_owned()];
        while code[i..].starts_with("::") {
            let s = i + 2;
            let mut e = s;
            while e < bytes.len() && ident(bytes[e]) {
                e += 1;
            }
            if e == s {
                break;
            }
            segments.push(code[s..e].to_owned());
            i = e;
        }
        // The module the path starts from: `self` is the file's module, `super` its parent
        // (each further `super` one more up).
        let mut base: Vec<String> = match root {
            "crate" => Vec::new(),
            _ => module.to_vec(),
        };
        let mut rest = &segments[1..];
        if root == "super" {
            base.pop();
            while rest.first().is_some_and(|s| s == "super") {
                base.pop();
                rest = &rest[1..];
            }
        }
        base.extend(rest.iter().cloned());
        found.push(base);
    }
    found
}

fn room_of(module: &[String]) -> Option<usize> {
    let top = module.first()?;
    LAYERS
        .iter()
        .position(|(_, tops)| tops.contains(&top.as_str()))
}

struct Source {
    /// Module path -> file.
    files: BTreeMap<Vec<String>, PathBuf>,
    /// File -> the module paths it names, each with the line it is on.
    named: BTreeMap<PathBuf, Vec<(Vec<String>, usize)>>,
}

fn read_source() -> Source {
    let src = src_dir();
    let mut list = Vec::new();
    rust_files(&src, &src, &mut list);
    let mut files = BTreeMap::new();
    let mut named = BTreeMap::new();
    for f in &list {
        files.insert(module_of(f), f.clone());
    }
    for f in &list {
        let text = std::fs::read_to_string(src.join(f)).unwrap();
        let module = module_of(f);
        let mut paths = Vec::new();
        for (n, line) in code_of(&text).lines().enumerate() {
            for p in paths_named(line, &module) {
                paths.push((p, n + 1));
            }
        }
        named.insert(f.clone(), paths);
    }
    Source { files, named }
}

impl Source {
    /// The file a module path lands in: the longest prefix of it that is a file's module.
    fn file_of(&self, path: &[String]) -> Option<&PathBuf> {
        (1..=path.len())
            .rev()
            .find_map(|n| self.files.get(&path[..n]))
    }
}

#[test]
fn rooms_import_only_rooms_below_them() {
    let s = read_source();
    let mut wrong = BTreeSet::new();
    for (file, paths) in &s.named {
        let Some(here) = room_of(&module_of(file)) else {
            continue;
        };
        for (path, _) in paths {
            if let Some(there) = room_of(path) {
                if there > here {
                    wrong.insert(format!(
                        "{} (room {}) imports crate::{} (room {})",
                        file.display(),
                        LAYERS[here].0,
                        path.join("::"),
                        LAYERS[there].0
                    ));
                }
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "imports of a room above (order, lowest first: {}):\n  {}",
        LAYERS.iter().map(|l| l.0).collect::<Vec<_>>().join(" -> "),
        wrong.into_iter().collect::<Vec<_>>().join("\n  ")
    );
}

#[test]
fn the_library_never_names_the_command_line() {
    let src = src_dir();
    let lib = std::fs::read_to_string(src.join("lib.rs")).unwrap();
    let lib_code = code_of(&lib);
    assert!(
        !lib_code.lines().any(|l| l
            .split(|c: char| !(c.is_alphanumeric() || c == '_'))
            .collect::<Vec<_>>()
            .windows(2)
            .any(|w| w[0] == "mod" && w[1] == "cli")),
        "lib.rs declares the cli module: it belongs to main.rs"
    );
    let s = read_source();
    let mut wrong = Vec::new();
    for (file, paths) in &s.named {
        let module = module_of(file);
        if module.first().is_some_and(|m| m == "cli" || m == "main") {
            continue;
        }
        for (path, line) in paths {
            if path.first().is_some_and(|m| m == "cli") {
                wrong.push(format!(
                    "{}:{line}: crate::{}",
                    file.display(),
                    path.join("::")
                ));
            }
        }
        let text = std::fs::read_to_string(src.join(file)).unwrap();
        for (n, line) in code_of(&text).lines().enumerate() {
            if line.contains("clap::") || line.contains("use clap") {
                wrong.push(format!("{}:{}: {}", file.display(), n + 1, line.trim()));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "the library names the command line or clap:\n  {}",
        wrong.join("\n  ")
    );
}

/// Strongly connected components of more than one file (Tarjan), each sorted.
fn circles(graph: &BTreeMap<PathBuf, BTreeSet<PathBuf>>) -> Vec<Vec<PathBuf>> {
    struct Walk<'a> {
        graph: &'a BTreeMap<PathBuf, BTreeSet<PathBuf>>,
        index: BTreeMap<&'a PathBuf, usize>,
        low: BTreeMap<&'a PathBuf, usize>,
        stack: Vec<&'a PathBuf>,
        on_stack: BTreeSet<&'a PathBuf>,
        out: Vec<Vec<PathBuf>>,
    }
    fn visit<'a>(w: &mut Walk<'a>, v: &'a PathBuf) {
        let i = w.index.len();
        w.index.insert(v, i);
        w.low.insert(v, i);
        w.stack.push(v);
        w.on_stack.insert(v);
        let graph = w.graph;
        for t in graph.get(v).into_iter().flatten() {
            if !w.index.contains_key(t) {
                visit(w, t);
                let lt = w.low[t];
                let lv = w.low.get_mut(v).unwrap();
                *lv = (*lv).min(lt);
            } else if w.on_stack.contains(t) {
                let it = w.index[t];
                let lv = w.low.get_mut(v).unwrap();
                *lv = (*lv).min(it);
            }
        }
        if w.low[v] == w.index[v] {
            let mut component = Vec::new();
            loop {
                let t = w.stack.pop().unwrap();
                w.on_stack.remove(t);
                component.push(t.clone());
                if t == v {
                    break;
                }
            }
            if component.len() > 1 {
                component.sort();
                w.out.push(component);
            }
        }
    }
    let mut w = Walk {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in graph.keys() {
        if !w.index.contains_key(v) {
            visit(&mut w, v);
        }
    }
    w.out
}

#[test]
fn source_files_import_no_circle() {
    let s = read_source();
    let mut graph: BTreeMap<PathBuf, BTreeSet<PathBuf>> = BTreeMap::new();
    for (file, paths) in &s.named {
        let targets = graph.entry(file.clone()).or_default();
        for (path, _) in paths {
            if let Some(t) = s.file_of(path) {
                if t != file {
                    targets.insert(t.clone());
                }
            }
        }
    }
    let found = circles(&graph);
    for c in &found {
        println!("circle of {} files:", c.len());
        for f in c {
            println!("  {}", f.display());
        }
    }
    assert!(
        found.is_empty(),
        "{} import circle(s), listed above",
        found.len()
    );
}
