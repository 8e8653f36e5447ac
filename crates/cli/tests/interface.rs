//! What every GPU command and every render share: no false errors on a headless machine, and
//! Ctrl-C through the estimator's cancellation token.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::{root, tmp};

/// Without a Wayland session Mesa's device-selection layer made libwayland print
/// "error: XDG_RUNTIME_DIR is invalid or not set" twice for `nimbus info --gpu`; the command
/// now prints only what it found.
#[test]
fn a_headless_gpu_command_prints_no_false_error() {
    let o = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .args(["info", "--gpu"])
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("NODEVICE_SELECT")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(!err.contains("XDG_RUNTIME_DIR"), "{err}");
}

/// Ctrl-C (SIGINT) during a render: the render stops within 2 s through its token, nothing is
/// written, exit status 130; a render of the same scene afterwards works.
#[test]
fn ctrl_c_cancels_a_render_and_writes_nothing() {
    let scene = root().join("scenes/refs/cube_iso.toml");
    let out = tmp("ctrl-c");
    let args = |spp: &str| {
        [
            "render".to_string(),
            scene.display().to_string(),
            "-q".into(),
            "--spp".into(),
            spp.into(),
            "-o".into(),
            out.display().to_string(),
        ]
    };
    // 10^6 spp of a 128×96 image: hours on any CPU.
    let mut child = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .args(args("1000000"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Past the start-up (the volume read, the majorant grid): the render is running.
    std::thread::sleep(Duration::from_millis(1500));
    assert!(
        child.try_wait().unwrap().is_none(),
        "ended before the signal"
    );
    let sent = Instant::now();
    // SAFETY: kill(2) on our own child's pid.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if sent.elapsed() > Duration::from_secs(10) {
            let _ = child.kill();
            panic!("still running 10 s after Ctrl-C");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let took = sent.elapsed();
    let mut err = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
    assert_eq!(status.code(), Some(130), "{err}");
    assert!(err.contains("cancelled"), "{err}");
    // The path tracer checks the token before each pixel: far below the bound.
    assert!(took < Duration::from_secs(2), "{took:?}");
    let written: Vec<_> = std::fs::read_dir(&out).unwrap().flatten().collect();
    assert!(written.is_empty(), "{written:?}");
    let o = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .args(args("1"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
