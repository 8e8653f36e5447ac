//! What the test modules share: running the binary, reading its output, scratch folders.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs `nimbus` with `args` to completion. Mesa warns without a runtime folder, so one is set
/// where the environment has none.
pub fn nimbus(args: &[&str]) -> Output {
    let runtime =
        std::env::var_os("XDG_RUNTIME_DIR").unwrap_or_else(|| std::env::temp_dir().into());
    Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .args(args)
        .env("XDG_RUNTIME_DIR", runtime)
        .output()
        .unwrap()
}

/// Standard output then standard error, for matching and for assertion messages.
pub fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// An empty scratch folder of this test process's own, one per `name`.
pub fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nimbus-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The repository's root.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Like [`nimbus`], killed after `seconds`: `None` if it was still running (a hang). Its output
/// goes to files, so a child that writes much cannot block on a full pipe and pass for a hang.
pub fn nimbus_within(args: &[&str], seconds: u64) -> Option<Output> {
    use std::time::{Duration, Instant};
    static RUN: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let k = RUN.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let d = tmp(&format!("within-{k}"));
    let (out, err) = (d.join("stdout"), d.join("stderr"));
    let runtime =
        std::env::var_os("XDG_RUNTIME_DIR").unwrap_or_else(|| std::env::temp_dir().into());
    let mut child = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .args(args)
        .env("XDG_RUNTIME_DIR", runtime)
        .stdout(std::fs::File::create(&out).unwrap())
        .stderr(std::fs::File::create(&err).unwrap())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(seconds) {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Some(Output {
        status,
        stdout: std::fs::read(&out).unwrap(),
        stderr: std::fs::read(&err).unwrap(),
    })
}
