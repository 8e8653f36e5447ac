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
