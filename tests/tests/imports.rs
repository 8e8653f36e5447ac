//! Imports run one way inside each crate: no circle between a crate's top-level modules (a
//! module that names `crate::x` depends on `x`; a name re-exported by `lib.rs` counts as the
//! module it comes from). A circle ties its modules into one unit that can only be read,
//! tested and changed together — `nimbus-render`'s estimator and its engines were one until
//! the engines took the shared types. The few circles that stand today are listed, each with
//! the reason it is harmless; any other fails here.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Circles that stand, as sorted module lists per crate, with why they are kept.
const KNOWN: &[(&str, &[&str], &str)] = &[];

/// The top-level module a file belongs to (`src/engine/pm.rs` → `engine`), `None` for the
/// crate root.
fn top_module(src: &Path, file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src).ok()?;
    let first = rel
        .components()
        .next()?
        .as_os_str()
        .to_string_lossy()
        .into_owned();
    match first.strip_suffix(".rs") {
        Some("lib" | "main") => None,
        Some(m) => Some(m.to_string()),
        None => Some(first),
    }
}

/// `pub use x::{A, B}` / `pub use x::A` lines of the crate root: name → module `x`.
fn reexports(lib: &str) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    let text = lib.replace('\n', " ");
    for stmt in text.split(';') {
        let s = stmt.trim();
        let Some(rest) = s.strip_prefix("pub use ") else {
            continue;
        };
        let rest = rest.trim_start_matches("crate::");
        let Some((module, names)) = rest.split_once("::") else {
            continue;
        };
        for n in names
            .trim_matches(|c| c == '{' || c == '}' || c == ' ')
            .split(',')
        {
            let n = n.trim().rsplit("::").next().unwrap_or("").trim();
            if !n.is_empty() {
                out.insert(n.to_string(), module.to_string());
            }
        }
    }
    out
}

/// Every `crate::a…` path in `text`, as the top-level name after `crate::` (`crate::{a, b}`
/// gives both); code after `#[cfg(test)]` is left out.
fn crate_paths(text: &str) -> BTreeSet<String> {
    let code: String = text
        .split("#[cfg(test)]")
        .next()
        .unwrap_or(text)
        .lines()
        // Comments (doc links included) name modules without importing them.
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    let body = code.as_str();
    let mut out = BTreeSet::new();
    let mut rest = body;
    while let Some(i) = rest.find("crate::") {
        let before = rest[..i].chars().last();
        rest = &rest[i + "crate::".len()..];
        // `nimbus_crate::` and the like are other crates' paths.
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue;
        }
        if let Some(group) = rest.strip_prefix('{') {
            let end = matching_brace(group);
            for part in split_top(&group[..end]) {
                let name: String = part
                    .trim()
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if !name.is_empty() {
                    out.insert(name);
                }
            }
        } else {
            let name: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() {
                out.insert(name);
            }
        }
    }
    out
}

fn matching_brace(s: &str) -> usize {
    let mut depth = 0;
    for (i, c) in s.char_indices() {
        match c {
            '{' => depth += 1,
            '}' if depth == 0 => return i,
            '}' => depth -= 1,
            _ => {}
        }
    }
    s.len()
}

/// Splits `a, b::{c, d}, e` at the commas outside braces.
fn split_top(s: &str) -> Vec<&str> {
    let (mut out, mut depth, mut start) = (Vec::new(), 0, 0);
    for (i, c) in s.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                out.push(&s[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    out.push(&s[start..]);
    out
}

fn rs_files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            rs_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module graph of one crate: module → the modules it names.
fn graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let root = ["lib.rs", "main.rs"]
        .iter()
        .find_map(|f| std::fs::read_to_string(src.join(f)).ok())
        .unwrap_or_default();
    let names = reexports(&root);
    let mut files = Vec::new();
    rs_files(src, &mut files);
    let modules: BTreeSet<String> = files.iter().filter_map(|f| top_module(src, f)).collect();
    let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for f in &files {
        let Some(from) = top_module(src, f) else {
            continue;
        };
        let text = std::fs::read_to_string(f).unwrap();
        for name in crate_paths(&text) {
            let to = if modules.contains(&name) {
                name
            } else if let Some(m) = names.get(&name) {
                m.clone()
            } else {
                continue;
            };
            if to != from {
                g.entry(from.clone()).or_default().insert(to);
            }
        }
        g.entry(from).or_default();
    }
    g
}

/// The circles of `g`: its strongly connected components of two or more modules (Tarjan).
fn circles(g: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    struct T<'a> {
        g: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on: BTreeSet<&'a str>,
        out: Vec<Vec<String>>,
    }
    fn visit<'a>(t: &mut T<'a>, v: &'a str) {
        let i = t.index.len();
        t.index.insert(v, i);
        t.low.insert(v, i);
        t.stack.push(v);
        t.on.insert(v);
        for w in t.g.get(v).into_iter().flatten() {
            let w = w.as_str();
            if !t.index.contains_key(w) {
                visit(t, w);
                let lw = t.low[w];
                let lv = t.low[v];
                t.low.insert(v, lv.min(lw));
            } else if t.on.contains(w) {
                let iw = t.index[w];
                let lv = t.low[v];
                t.low.insert(v, lv.min(iw));
            }
        }
        if t.low[v] == t.index[v] {
            let mut c = Vec::new();
            while let Some(w) = t.stack.pop() {
                t.on.remove(w);
                c.push(w.to_string());
                if w == v {
                    break;
                }
            }
            if c.len() > 1 {
                c.sort();
                t.out.push(c);
            }
        }
    }
    let mut t = T {
        g,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in g.keys() {
        if !t.index.contains_key(v.as_str()) {
            visit(&mut t, v);
        }
    }
    t.out
}

#[test]
fn the_circle_finder_sees_a_circle_through_a_reexport() {
    let lib = "pub mod a;\npub use b::{Thing, other::Deep};\n";
    let names = reexports(lib);
    assert_eq!(names["Thing"], "b");
    assert_eq!(names["Deep"], "b");
    let paths =
        crate_paths("use crate::{a::X, Thing};\nfn f() { nimbus_crate::y(); crate::c::z() }");
    assert_eq!(
        paths,
        ["Thing", "a", "c"].map(String::from).into_iter().collect()
    );
    let mut g = BTreeMap::new();
    g.insert("a".to_string(), BTreeSet::from(["b".to_string()]));
    g.insert("b".to_string(), BTreeSet::from(["c".to_string()]));
    g.insert("c".to_string(), BTreeSet::from(["a".to_string()]));
    g.insert("d".to_string(), BTreeSet::from(["a".to_string()]));
    assert_eq!(circles(&g), vec![vec!["a", "b", "c"]]);
}

#[test]
fn no_crate_has_an_import_circle_between_its_modules() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let mut found = Vec::new();
    let mut crates = 0;
    for e in std::fs::read_dir(root.join("crates")).unwrap().flatten() {
        let src = e.path().join("src");
        if !src.is_dir() {
            continue;
        }
        crates += 1;
        let name = e.file_name().to_string_lossy().into_owned();
        for c in circles(&graph(&src)) {
            let known = KNOWN
                .iter()
                .any(|(k, m, _)| *k == name && m.iter().copied().eq(c.iter().map(String::as_str)));
            if !known {
                found.push(format!("{name}: {}", c.join(" ↔ ")));
            }
        }
    }
    assert!(crates >= 9, "only {crates} crates found");
    assert!(
        found.is_empty(),
        "import circles between modules (move the shared items into one module that both \
         use, so imports run one way):\n{}",
        found.join("\n")
    );
}

/// The crates a web page runs (`std::time::Instant::now` panics on wasm32) take time from
/// `nimbus_scene::clock` only.
#[test]
fn the_page_crates_take_time_from_the_wasm_safe_clock() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let mut stray = Vec::new();
    let mut scanned = 0;
    for krate in ["scene", "gpu", "trace", "photon", "render"] {
        let mut files = Vec::new();
        rs_files(&root.join("crates").join(krate).join("src"), &mut files);
        for f in files {
            if f.ends_with("clock.rs") {
                continue;
            }
            scanned += 1;
            let text = std::fs::read_to_string(&f).unwrap();
            // Tests run natively: their own timing is not the page's.
            let code = match text.find("#[cfg(test)]").or(text.find("#[cfg(all(test")) {
                Some(i) => &text[..i],
                None => &text,
            };
            for (i, line) in code.lines().enumerate() {
                let l = line.split("//").next().unwrap_or("");
                if l.contains("time::Instant") || l.contains("time::{") && l.contains("Instant") {
                    stray.push(format!("{}:{}: {}", f.display(), i + 1, line.trim()));
                }
            }
        }
    }
    assert!(scanned >= 60, "only {scanned} files scanned");
    assert!(
        stray.is_empty(),
        "use nimbus_scene::clock::Instant (wasm-safe):\n{}",
        stray.join("\n")
    );
}
