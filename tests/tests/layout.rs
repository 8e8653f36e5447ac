//! Every crate's integration tests are modules of one test binary (`tests/main.rs`, with
//! `autotests = false`): a test file that `main.rs` does not name would never be compiled, so
//! its tests would silently not run. This checks that each file is named.

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
