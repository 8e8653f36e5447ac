//! Every crate's integration tests are modules of one test binary (`tests/main.rs`, with
//! `autotests = false`): a test file that `main.rs` does not name would never be compiled, so
//! its tests would silently not run. This checks that each file is named. One module layout
//! everywhere, and every file opened, read or written through `nimbus_scene::fsio`.

use std::path::Path;

#[test]
fn every_integration_test_file_is_a_module_of_its_binary() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let mut dirs = vec![root.join("tests/tests")];
    for e in std::fs::read_dir(root.join("crates")).unwrap().flatten() {
        dirs.push(e.path().join("tests"));
    }
    let mut checked = 0;
    for dir in dirs {
        let main = dir.join("main.rs");
        let Ok(text) = std::fs::read_to_string(&main) else {
            continue; // no merged binary: cargo's auto-discovery compiles each file
        };
        let manifest = std::fs::read_to_string(dir.parent().unwrap().join("Cargo.toml")).unwrap();
        assert!(
            manifest.contains("autotests = false") && manifest.contains("path = \"tests/main.rs\""),
            "{}: a tests/main.rs needs `autotests = false` and a [[test]] for it",
            dir.display()
        );
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(module) = name.strip_suffix(".rs") else {
                continue;
            };
            if module == "main" {
                continue;
            }
            assert!(
                text.lines().any(|l| l.trim() == format!("mod {module};")),
                "{}: {name} is not a module of {} (add `mod {module};`), so its tests never run",
                dir.display(),
                main.display()
            );
            checked += 1;
        }
    }
    // 23 files in six merged binaries today: the walk must have found them.
    assert!(checked >= 20, "only {checked} test files found");
}

/// One module layout in every crate: a module with submodules is a folder with `mod.rs`, never a
/// `x.rs` beside a folder `x/`, so a module's files are found in one place.
#[test]
fn modules_with_submodules_are_folders_with_mod_rs() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let mut stack: Vec<_> = std::fs::read_dir(root.join("crates"))
        .unwrap()
        .flatten()
        .map(|e| e.path().join("src"))
        .filter(|p| p.is_dir())
        .collect();
    let mut folders = 0;
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = e.path();
            if !p.is_dir() {
                continue;
            }
            let name = e.file_name().to_string_lossy().into_owned();
            // Folders without Rust files (data, shaders) are not modules.
            let has_rs = std::fs::read_dir(&p)
                .unwrap()
                .flatten()
                .any(|f| f.path().extension().is_some_and(|x| x == "rs"));
            if has_rs {
                assert!(
                    !dir.join(format!("{name}.rs")).exists(),
                    "{}: both {name}.rs and {name}/; move it to {name}/mod.rs",
                    dir.display()
                );
                assert!(
                    p.join("mod.rs").exists() || dir.ends_with("src") && name == "bin",
                    "{}: a module folder without mod.rs",
                    p.display()
                );
                folders += 1;
            }
            stack.push(p);
        }
    }
    // Nine module folders today (scene: generate, io, io/nvdb, io/vdb, phase; photon: cpu,
    // mapper; render: engine; rpnn: pyramid): the walk must have found them.
    assert!(folders >= 9, "only {folders} module folders found");
}

/// The calls that open, read or write a file by path or read a whole stream, outside
/// `nimbus_scene::fsio` (the one place that checks what it opens: a pipe, a device, a bad link,
/// a size over the budget; and writes whole or not at all).
const FILE_CALLS: [&str; 8] = [
    "File::open",
    "File::create",
    "OpenOptions",
    "fs::read(",
    "fs::read_to_string",
    "read_to_string(",
    "read_to_end(",
    "fs::write(",
];

/// The calls of [`FILE_CALLS`] allowed outside `fsio.rs`: (file, a piece of its line, why). Each
/// entry must still match a line (a stale one fails, so the list only shrinks).
const FILE_CALLS_ALLOWED: &[(&str, &str, &str)] = &[
    // System files, not user input: the kernel's own, small and regular.
    (
        "crates/scene/src/memory.rs",
        "\"/proc/meminfo\"",
        "physical memory for the default budget",
    ),
    (
        "crates/scene/src/memory.rs",
        "\"/sys/fs/cgroup/memory.max\"",
        "the container's memory limit",
    ),
    // The stress child's stdout and stderr: pipes this process made, drained on threads
    // while the parent enforces the child's time limit.
    (
        "crates/eval/src/stress.rs",
        "so.read_to_string(",
        "stress child's stdout pipe",
    ),
    (
        "crates/eval/src/stress.rs",
        "se.read_to_string(",
        "stress child's stderr pipe",
    ),
];

/// The lines (1-based, trimmed) of `text` that make one of [`FILE_CALLS`]: comments skipped,
/// calls through `fsio::` not counted, and the file read up to its test module (a
/// `#[cfg(...test...)]` line followed by `mod tests`), whose fixtures may write as they like.
fn file_calls(text: &str) -> Vec<(usize, String)> {
    let lines: Vec<&str> = text.lines().collect();
    let mut found = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let t = line.trim();
        let next = lines.get(i + 1).map_or("", |l| l.trim());
        if t.starts_with("#[cfg(")
            && t.contains("test")
            && (next.starts_with("mod tests") || next.starts_with("pub mod tests"))
        {
            break;
        }
        if t.starts_with("//") {
            continue;
        }
        // `fsio::read_to_string(` is the way, not a stray call.
        let mut code = t.to_string();
        while let Some(at) = code.find("fsio::") {
            let end = code[at + 6..]
                .find(|c: char| !(c.is_alphanumeric() || c == '_'))
                .map_or(code.len(), |e| at + 6 + e);
            code.replace_range(at..end, "");
        }
        // A call, not a name that ends like one (`SlabFile::create`).
        let starts_word = |at: usize| {
            !code[..at]
                .chars()
                .next_back()
                .is_some_and(|c| c.is_alphanumeric() || c == '_')
        };
        if FILE_CALLS
            .iter()
            .any(|p| code.match_indices(p).any(|(at, _)| starts_word(at)))
        {
            found.push((i + 1, t.to_string()));
        }
    }
    found
}

#[test]
fn the_file_call_matcher_finds_stray_calls_only() {
    let text = r#"
use std::fs::OpenOptions;
fn a(p: &Path) {
    let t = std::fs::read_to_string(p).unwrap(); // stray
    // let t = std::fs::read_to_string(p); a comment
    let t = nimbus_scene::fsio::read_to_string(p)?;
    let b = fsio::read(p)?;
    let f = SlabFile::create(p, res, bounds)?;
    let f = File::create(p)?;
    std::fs::write(p, b)?;
    r.read_to_end(&mut v)?;
}
#[cfg(test)]
mod tests {
    fn t() { std::fs::write("x", "y").unwrap(); }
}
"#;
    let lines: Vec<usize> = file_calls(text).into_iter().map(|(n, _)| n).collect();
    assert_eq!(lines, [2, 4, 9, 10, 11]);
}

#[test]
fn every_file_is_opened_through_fsio() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let mut stack: Vec<_> = std::fs::read_dir(root.join("crates"))
        .unwrap()
        .flatten()
        .map(|e| e.path().join("src"))
        .filter(|p| p.is_dir())
        .collect();
    let mut used = vec![0usize; FILE_CALLS_ALLOWED.len()];
    let (mut stray, mut files) = (Vec::new(), 0);
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
                continue;
            }
            if p.extension().is_none_or(|x| x != "rs") {
                continue;
            }
            let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
            if rel == "crates/scene/src/fsio.rs" {
                continue;
            }
            files += 1;
            for (n, line) in file_calls(&std::fs::read_to_string(&p).unwrap()) {
                match FILE_CALLS_ALLOWED
                    .iter()
                    .position(|(f, piece, _)| *f == rel && line.contains(piece))
                {
                    Some(k) => used[k] += 1,
                    None => stray.push(format!("{rel}:{n}: {line}")),
                }
            }
        }
    }
    assert!(
        stray.is_empty(),
        "files opened, read or written outside nimbus_scene::fsio (use fsio::open, read, \
         read_to_string, write_atomically or write_bytes; or allow it in FILE_CALLS_ALLOWED \
         with a reason):\n{}",
        stray.join("\n")
    );
    let stale: Vec<_> = FILE_CALLS_ALLOWED
        .iter()
        .zip(&used)
        .filter(|(_, n)| **n == 0)
        .map(|((f, piece, _), _)| format!("{f}: {piece}"))
        .collect();
    assert!(
        stale.is_empty(),
        "FILE_CALLS_ALLOWED entries that match nothing any more (remove them):\n{}",
        stale.join("\n")
    );
    // Some 130 source files in nine crates today: the walk must have found them.
    assert!(files >= 100, "only {files} source files scanned");
}
