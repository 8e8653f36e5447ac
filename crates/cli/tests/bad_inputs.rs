//! The bad-input regression suite: every file and flag in `tests/bad-inputs/cases.toml` (made by
//! `tests/bad-inputs/make.py`) must give its exit code and message within its time limit, and
//! leave no output behind when it fails. A case that runs past its limit is killed and reported
//! as a hang.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[derive(serde::Deserialize)]
struct Cases {
    case: Vec<Case>,
}

#[derive(serde::Deserialize)]
struct Case {
    name: String,
    args: Vec<String>,
    exit: i32,
    #[serde(default)]
    expect: Vec<String>,
    #[serde(default)]
    absent: Vec<String>,
    #[serde(default)]
    present: Vec<String>,
    seconds: u64,
    /// The case runs GPU work (skipped where there is no adapter, see `nimbus_gpu::testing`).
    #[serde(default)]
    gpu: bool,
}

fn here() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bad-inputs")
}

#[test]
fn every_bad_input_fails_clearly_and_in_time() {
    let text = std::fs::read_to_string(here().join("cases.toml")).unwrap();
    let cases: Cases = toml::from_str(&text).unwrap();
    assert!(cases.case.len() >= 20);
    let files = here().join("files");
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scene/tests/data");
    let root = std::env::temp_dir().join(format!("nimbus-bad-inputs-{}", std::process::id()));
    let mut failures = Vec::new();
    let mut gpu = None;
    for (i, c) in cases.case.iter().enumerate() {
        if c.gpu
            && !*gpu.get_or_insert_with(|| {
                nimbus_gpu::testing::has_adapter("bad_inputs: the cases with `gpu = true`")
            })
        {
            continue;
        }
        let out = root.join(format!("{i:02}"));
        std::fs::create_dir_all(&out).unwrap();
        let fill = |s: &str| {
            s.replace("{files}", files.to_str().unwrap())
                .replace("{data}", data.to_str().unwrap())
                .replace("{out}", out.to_str().unwrap())
        };
        let args: Vec<String> = c.args.iter().map(|a| fill(a)).collect();
        let start = Instant::now();
        let mut child = Command::new(env!("CARGO_BIN_EXE_nimbus"))
            .args(&args)
            .env("XDG_RUNTIME_DIR", std::env::temp_dir())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let limit = Duration::from_secs(c.seconds);
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break Some(s);
            }
            if start.elapsed() > limit {
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let o = child.wait_with_output().unwrap();
        let msg = format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        let Some(status) = status else {
            failures.push(format!(
                "{}: still running after {} s (a hang)",
                c.name, c.seconds
            ));
            continue;
        };
        if status.code() != Some(c.exit) {
            failures.push(format!(
                "{}: exit {:?}, expected {}: {msg}",
                c.name,
                status.code(),
                c.exit
            ));
            continue;
        }
        for e in &c.expect {
            if !msg.contains(e.as_str()) {
                failures.push(format!("{}: message lacks `{e}`: {msg}", c.name));
            }
        }
        for p in &c.absent {
            if Path::new(&fill(p)).exists() {
                failures.push(format!("{}: left {} behind", c.name, fill(p)));
            }
        }
        for p in &c.present {
            if !Path::new(&fill(p)).exists() {
                failures.push(format!("{}: did not write {}", c.name, fill(p)));
            }
        }
    }
    let _ = std::fs::remove_dir_all(&root);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
