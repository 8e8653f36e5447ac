//! The `nimbus` binary end to end: generate → info → render, and clear errors on bad input.

use std::path::PathBuf;
use std::process::{Command, Output};

fn nimbus(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .args(args)
        .output()
        .unwrap()
}

fn tmp() -> PathBuf {
    let d = std::env::temp_dir().join(format!("nimbus-cli-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

#[test]
fn generate_info_render() {
    let d = tmp();
    let vol = d.join("c.vol");
    let o = nimbus(&[
        "generate",
        "stratus",
        "--seed",
        "3",
        "--res",
        "24,8,24",
        "--out",
        vol.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let o = nimbus(&["info", vol.to_str().unwrap(), "--density-scale", "10"]);
    let t = text(&o);
    assert!(
        o.status.success() && t.contains("24 x 8 x 24") && t.contains("max optical depth"),
        "{t}"
    );
    let scene = d.join("s.toml");
    std::fs::write(
        &scene,
        r#"
[volume]
file = "c.vol"
density_scale = 10.0
phase = { kind = "hg", g = 0.8 }
[sun]
direction = [0.0, 1.0, 0.3]
irradiance = 1.0
[sky]
radiance = 0.2
[camera]
origin = [0.0, 0.5, 3.0]
target = [0.0, 0.0, 0.0]
vfov_deg = 40.0
width = 16
height = 10
"#,
    )
    .unwrap();
    let out = d.join("img");
    let o = nimbus(&[
        "render",
        scene.to_str().unwrap(),
        "--spp",
        "4",
        "-q",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let img = nimbus_scene::Image::read_exr(out.with_extension("exr")).unwrap();
    assert_eq!((img.width, img.height), (16, 10));
    assert!(img.pixels.iter().flatten().all(|v| v.is_finite()));
    assert!(out.with_extension("png").exists());
    // compare against itself: ratio 1, error 0.
    let e = out.with_extension("exr");
    let o = nimbus(&["compare", e.to_str().unwrap(), e.to_str().unwrap()]);
    assert!(
        text(&o).contains("mean_lum_ratio      1.00000"),
        "{}",
        text(&o)
    );
}

#[test]
fn bad_input_is_a_clear_error() {
    let d = tmp();
    let garbage = d.join("garbage.vol");
    std::fs::write(&garbage, b"VOL\x03garbage").unwrap();
    let o = nimbus(&["info", garbage.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("garbage.vol") && text(&o).contains("header"),
        "{}",
        text(&o)
    );
    let o = nimbus(&["render", d.join("nope.toml").to_str().unwrap()]);
    assert!(!o.status.success() && text(&o).contains("nope.toml"));
    let bad = d.join("bad.toml");
    std::fs::write(&bad, "[volume]\ngenerator = { kind = \"cumulus\", resolution = [8, 8, 8] }\nphase = { kind = \"hg\", g = 1.0 }\n[camera]\norigin=[0,0,3]\ntarget=[0,0,0]\nvfov_deg=30\nwidth=4\nheight=4\n").unwrap();
    let o = nimbus(&["render", bad.to_str().unwrap(), "-q"]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("bad.toml") && text(&o).contains("volume.phase.g"),
        "{}",
        text(&o)
    );
    let o = nimbus(&[
        "generate",
        "fog",
        "--out",
        d.join("x.vol").to_str().unwrap(),
    ]);
    assert!(!o.status.success() && text(&o).contains("unknown cloud kind"));
    let o = nimbus(&[
        "generate",
        "cumulus",
        "--res",
        "0,4,4",
        "--out",
        d.join("x.vol").to_str().unwrap(),
    ]);
    assert!(
        !o.status.success() && text(&o).contains("--res"),
        "{}",
        text(&o)
    );
    // A clean error, not a panic.
    assert!(!text(&nimbus(&["info", garbage.to_str().unwrap()])).contains("panicked"));
}
