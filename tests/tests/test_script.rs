//! `scripts/test.sh`, the README's test command, checks the system packages before it compiles
//! anything: with `Xvfb` missing from `PATH` and installation turned off, it must stop at once
//! with the exact `apt-get install` line.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// A folder of links to every program on `PATH` except `skip`.
fn path_without(skip: &str) -> tempdir::Dir {
    let dir = tempdir::Dir::new("nimbus-path");
    let path = std::env::var_os("PATH").unwrap_or_default();
    for d in std::env::split_paths(&path) {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let name = e.file_name();
            let link = dir.0.join(&name);
            if name == skip || link.exists() {
                continue;
            }
            let _ = std::os::unix::fs::symlink(e.path(), &link);
        }
    }
    dir
}

mod tempdir {
    /// A temporary folder removed on drop.
    pub struct Dir(pub std::path::PathBuf);
    impl Dir {
        pub fn new(prefix: &str) -> Self {
            let p = std::env::temp_dir().join(format!("{prefix}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&p);
            std::fs::create_dir_all(&p).unwrap();
            Self(p)
        }
    }
    impl Drop for Dir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

#[test]
fn missing_xvfb_stops_before_compiling_with_the_install_line() {
    let bin = path_without("Xvfb");
    let start = Instant::now();
    // No `--check`: the full test command must stop at the package check, before cargo runs.
    let out = Command::new("bash")
        .arg(repo_root().join("scripts/test.sh"))
        .env("PATH", &bin.0)
        .env("NIMBUS_NO_INSTALL", "1")
        .output()
        .expect("bash runs");
    let took = start.elapsed();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(!out.status.success(), "must fail without Xvfb: {stderr}");
    assert!(
        stderr.contains("apt-get install -y --no-install-recommends") && stderr.contains("xvfb"),
        "the exact install line naming xvfb: {stderr}"
    );
    assert!(
        !stderr.contains("Compiling") && !stdout.contains("Compiling") && !stderr.contains("pip"),
        "nothing may be compiled or installed before the check: {stderr}"
    );
    // "At once": the check reads a few files and runs ldconfig; 20 s leaves room for a loaded
    // CI machine while anything that compiled would take minutes.
    assert!(took < Duration::from_secs(20), "took {took:?}");
}

#[test]
fn check_passes_with_everything_installed() {
    // On the CI machine and every machine that ran the script once, the packages are there.
    let out = Command::new("bash")
        .arg(repo_root().join("scripts/test.sh"))
        .arg("--check")
        .env("NIMBUS_NO_INSTALL", "1")
        .output()
        .expect("bash runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("system packages: ok"), "{stderr}");
}
