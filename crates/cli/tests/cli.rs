//! The `nimbus` binary end to end: generate → info → render, and clear errors on bad input.

use crate::common::{nimbus, nimbus_within, root, text, tmp};
use std::path::Path;
use std::process::Command;

#[test]
fn info_gpu_lists_the_adapter_in_use() {
    if !nimbus_gpu::testing::has_adapter("cli::info_gpu_lists_the_adapter_in_use") {
        return;
    }
    // CI and dev machines have at least lavapipe (scripts/test.sh installs it).
    let o = nimbus(&["info", "--gpu"]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    let first = t.lines().next().unwrap_or_default();
    assert!(
        first.starts_with("used ") && first.contains('(') && first.contains(", "),
        "{t}"
    );
    // Without a file and without --gpu, clap names the missing argument.
    let o = nimbus(&["info"]);
    assert!(
        !o.status.success() && text(&o).contains("<FILE>"),
        "{}",
        text(&o)
    );
}

/// Without any GPU adapter (`WGPU_BACKEND` naming a backend this platform lacks), `info --gpu`
/// says so with the install hint and a GPU method is a clear error, while the CPU path tracer
/// still renders.
#[test]
fn no_adapter_is_a_clear_error() {
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_nimbus"))
            .args(args)
            .env("WGPU_BACKEND", "dx12")
            .output()
            .unwrap()
    };
    let o = run(&["info", "--gpu"]);
    assert!(
        o.status.success()
            && text(&o).contains("no GPU adapter")
            && text(&o).contains("mesa-vulkan-drivers"),
        "{}",
        text(&o)
    );
    let scene = root().join("scenes/refs/cube_iso.toml");
    let out = tmp("no-adapter");
    let base = [
        "render",
        scene.to_str().unwrap(),
        "-q",
        "--spp",
        "1",
        "-o",
        out.to_str().unwrap(),
    ];
    for extra in [&["--method", "pm"][..], &["--device", "gpu"][..]] {
        let o = run(&[&base[..], extra].concat());
        let t = text(&o);
        assert!(
            o.status.code() == Some(1)
                && t.contains("no GPU adapter")
                && t.contains("mesa-vulkan-drivers"),
            "{extra:?}: {t}"
        );
    }
    let o = run(&base);
    assert!(
        o.status.success() && out.with_extension("exr").exists(),
        "{}",
        text(&o)
    );
}

#[test]
fn generate_info_render() {
    let d = tmp("generate");
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
    let d = tmp("bad-input");
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
    // I/O errors say their cause once.
    let t = text(&nimbus(&["info", d.join("missing.vol").to_str().unwrap()]));
    assert_eq!(t.matches("No such file").count(), 1, "{t}");
    // The output is checked before the work: a 1000³ grid (4 GB, minutes) is not generated for
    // a path that cannot take it. With a 1 MiB budget the generation would fail on memory, so
    // the message shows which check came first.
    let o = nimbus(&[
        "generate",
        "cumulus",
        "--res",
        "1000,1000,1000",
        "--max-memory",
        "1M",
        "-o",
        d.join("x.txt").to_str().unwrap(),
    ]);
    assert!(
        !o.status.success() && text(&o).contains(".vol or .npy") && !text(&o).contains("budget"),
        "{}",
        text(&o)
    );
    let blocker = d.join("a_file");
    std::fs::write(&blocker, b"x").unwrap();
    let o = nimbus(&[
        "generate",
        "cumulus",
        "--res",
        "1000,1000,1000",
        "--max-memory",
        "1M",
        "-o",
        blocker.join("x.vol").to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(
        !o.status.success() && t.contains("a_file") && !t.contains("budget"),
        "{t}"
    );
    // Files that are not files: a folder, and a named pipe, which opening would wait on for a
    // writer forever (once a hang).
    let o = nimbus(&["info", d.to_str().unwrap()]);
    assert!(
        !o.status.success() && text(&o).contains("a folder"),
        "{}",
        text(&o)
    );
    let fifo = d.join("pipe.vol");
    if Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .is_ok_and(|s| s.success())
    {
        let o = nimbus_within(&["info", fifo.to_str().unwrap()], 20).expect("info on a pipe hung");
        let t = text(&o);
        assert!(
            !o.status.success() && t.contains("pipe.vol") && t.contains("not a regular file"),
            "{t}"
        );
    }
    // A scene file far larger than any scene (once read whole, and its parse error quoted its
    // longest line: 200 MB on stderr for a 100 MB file of zero bytes).
    let big = d.join("big.toml");
    std::fs::write(&big, vec![0u8; 2 << 20]).unwrap();
    let o = nimbus(&["render", big.to_str().unwrap()]);
    let t = text(&o);
    assert!(
        !o.status.success()
            && t.contains("big.toml")
            && t.contains("at most 1.0 MiB")
            && t.len() < 1000,
        "{t}"
    );
}

/// Every estimator and the GPU commands run end to end on the demo scene (tiny budgets), and
/// their images agree on the sky and show a cloud.
#[test]
fn demo_scene_with_every_method() {
    if !nimbus_gpu::testing::has_adapter("cli::demo_scene_with_every_method") {
        return;
    }
    let d = tmp("demo");
    let demo = root().join("scenes/demo-cumulus.toml");
    let demo = demo.to_str().unwrap();
    let runs: [(&str, Vec<&str>); 4] = [
        ("pt", vec!["--spp", "2"]),
        ("gpt", vec!["--device", "gpu", "--spp", "2"]),
        // The final gathering's cache is as fine as its beams allow (4 per cell): with a few
        // thousand beams its view-dependent words are too sparse for a mean.
        (
            "pm",
            vec![
                "--method",
                "pm",
                "--beams",
                "16384",
                "--ring",
                "4",
                "--spp",
                "4",
                "--ring-refresh",
                "2",
                "--timings",
            ],
        ),
        (
            "pm-march",
            vec![
                "--method",
                "pm-march",
                "--beams",
                "2048",
                "--ring",
                "2",
                "--timings",
            ],
        ),
    ];
    for (name, extra) in runs {
        let out = d.join(name);
        let mut args = vec!["render", demo, "-q", "-o", out.to_str().unwrap()];
        args.extend(extra);
        let o = nimbus(&args);
        assert!(o.status.success(), "{name}: {}", text(&o));
        if name == "pm" {
            // The ring renewed once in 4 samples, and the summary says so.
            assert!(text(&o).contains("(a new one every 2 spp)"), "{}", text(&o));
        }
        let img = nimbus_scene::Image::read_exr(out.with_extension("exr")).unwrap();
        // The top-left corner is sky (0.12, 0.2, 0.38); the central region holds the sunlit
        // cloud, on average brighter than the sky (luminance 0.233).
        let corner = img.get(0, 0);
        assert!((corner[2] - 0.38).abs() < 1e-3, "{name}: corner {corner:?}");
        let (w, h) = (img.width, img.height);
        let mut centre = 0.0;
        for y in h * 2 / 5..h * 3 / 5 {
            for x in w * 2 / 5..w * 3 / 5 {
                centre += img.lum(x, y);
            }
        }
        let centre = centre / ((h / 5) * (w / 5)) as f64;
        assert!(
            centre > 0.3 && centre.is_finite(),
            "{name}: centre {centre}"
        );
        assert!(img.pixels.iter().flatten().all(|v| v.is_finite()));
    }
    // compare --png of two estimators.
    let png = d.join("diff.png");
    let o = nimbus(&[
        "compare",
        d.join("pm.exr").to_str().unwrap(),
        d.join("pt.exr").to_str().unwrap(),
        "--png",
        png.to_str().unwrap(),
    ]);
    assert!(o.status.success() && png.exists(), "{}", text(&o));
    // animate: two frames with a moving sun and their timings.
    let anim = d.join("anim");
    let o = nimbus(&[
        "animate",
        demo,
        "--frames",
        "2",
        "--beams",
        "1024",
        "--ring",
        "2",
        "--sun-speed",
        "30",
        "-o",
        anim.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let csv = std::fs::read_to_string(anim.join("timings.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "{csv}");
    assert!(anim.join("frame_00001.png").exists());
}

/// datagen end to end: a tiny set, the manifest and shards it promises.
#[test]
fn datagen_end_to_end() {
    let d = tmp("data");
    let o = nimbus(&[
        "datagen",
        "--clouds",
        "gen:5",
        "--records",
        "2",
        "--test-records",
        "1",
        "--val-records",
        "1",
        "--shard-size",
        "2",
        "--samples",
        "64",
        "--eval-samples",
        "256",
        "--light",
        "uniform-gamma",
        "--density-range",
        "10,300",
        "--device",
        "cpu",
        "-q",
        "-o",
        d.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("4 records"), "{}", text(&o));
    for f in [
        "manifest.json",
        "settings.json",
        "train_00000_x.npy",
        "train_00000_y.npy",
        "val_00000_y.npy",
        "test_00000_meta.npy",
    ] {
        assert!(d.join(f).exists(), "{f}");
    }
    let o = nimbus(&[
        "datagen",
        "--clouds",
        "gen:0",
        "--records",
        "1",
        "-o",
        d.to_str().unwrap(),
    ]);
    assert!(
        !o.status.success() && text(&o).contains("gen:N"),
        "{}",
        text(&o)
    );
}

/// `datagen --shard K/N` and `datagen merge`: two parts merge into the single run's files; bad
/// part specifications and merges are clear errors.
#[test]
fn datagen_parts_and_merge() {
    let d = tmp("parts");
    let args = |out: &Path, shard: Option<&str>| {
        let mut v: Vec<String> = [
            "datagen",
            "--clouds",
            "gen:5",
            "--records",
            "3",
            "--test-records",
            "1",
            "--val-records",
            "1",
            "--shard-size",
            "1",
            "--samples",
            "16",
            "--eval-samples",
            "16",
            "--device",
            "cpu",
            "-q",
            "-o",
        ]
        .map(String::from)
        .to_vec();
        v.push(out.to_str().unwrap().into());
        if let Some(s) = shard {
            v.extend(["--shard".into(), s.into()]);
        }
        v
    };
    let run = |a: Vec<String>| nimbus(&a.iter().map(String::as_str).collect::<Vec<_>>());
    let o = run(args(&d.join("single"), None));
    assert!(o.status.success(), "{}", text(&o));
    for k in ["1/2", "2/2"] {
        let o = run(args(&d.join(&k[..1]), Some(k)));
        assert!(
            o.status.success() && text(&o).contains(&format!("part {k}")),
            "{}",
            text(&o)
        );
    }
    let (p1, p2, m) = (d.join("1"), d.join("2"), d.join("merged"));
    let o = nimbus(&[
        "datagen",
        "merge",
        p1.to_str().unwrap(),
        p2.to_str().unwrap(),
        "-o",
        m.to_str().unwrap(),
    ]);
    assert!(
        o.status.success() && text(&o).contains("2 parts, 5 shards, 5 records"),
        "{}",
        text(&o)
    );
    for f in [
        "train_00002_y.npy",
        "val_00000_x.npy",
        "test_00000_meta.npy",
    ] {
        assert_eq!(
            std::fs::read(d.join("single").join(f)).unwrap(),
            std::fs::read(m.join(f)).unwrap(),
            "{f}"
        );
    }
    for (k, want) in [
        ("0/2", "1 <= K <= N"),
        ("3/2", "1 <= K <= N"),
        ("1-2", "expected K/N"),
    ] {
        let o = run(args(&d.join("bad"), Some(k)));
        assert!(
            !o.status.success() && text(&o).contains(want),
            "{k}: {}",
            text(&o)
        );
    }
    let o = nimbus(&[
        "datagen",
        "merge",
        p1.to_str().unwrap(),
        "-o",
        m.to_str().unwrap(),
    ]);
    assert!(
        !o.status.success() && text(&o).contains("part 2/2 is missing"),
        "{}",
        text(&o)
    );
    let o = nimbus(&["datagen", "merge", "-o", m.to_str().unwrap()]);
    assert!(!o.status.success(), "{}", text(&o));
    let o = nimbus(&["datagen", "--clouds", "gen:5", "-o", m.to_str().unwrap()]);
    assert!(
        !o.status.success() && text(&o).contains("--records"),
        "{}",
        text(&o)
    );
}

#[test]
fn rpnn_render_and_missing_model() {
    let d = tmp("rpnn");
    let out = d.join("rpnn.exr");
    let o = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .current_dir(root())
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .args([
            "render",
            "scenes/demo-cumulus.toml",
            "--method",
            "rpnn",
            "--backend",
            "ort",
        ])
        .args(["--spp", "1", "--timings", "-q", "-o", out.to_str().unwrap()])
        .output()
        .unwrap();
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    // The demo scene has a sky: the default model is the one with a sky head.
    assert!(
        t.contains("models/rpnn-hg-sky.onnx") && t.contains("sky head") && t.contains("inference"),
        "{t}"
    );
    let img = nimbus_scene::Image::read_exr(&out).unwrap();
    assert!(
        img.pixels
            .iter()
            .flatten()
            .all(|v| v.is_finite() && *v >= 0.0)
    );
    // The paper's sky directions query the sun-only model.
    let o = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .current_dir(root())
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .args([
            "render",
            "scenes/demo-cumulus.toml",
            "--method",
            "rpnn-dirs",
        ])
        .args(["--backend", "ort", "--spp", "1", "--timings", "-q"])
        .args(["-o", out.to_str().unwrap()])
        .output()
        .unwrap();
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(
        t.contains("models/rpnn-hg.onnx") && !t.contains("sky head"),
        "{t}"
    );
    let scene = root().join("scenes/demo-cumulus.toml");
    let o = nimbus(&[
        "render",
        scene.to_str().unwrap(),
        "--method",
        "rpnn",
        "--model",
        "no/such/model.onnx",
    ]);
    assert!(!o.status.success());
    let t = text(&o);
    assert!(
        t.contains("no/such/model.onnx") && t.contains("not found"),
        "{t}"
    );
    let o = nimbus(&[
        "render",
        scene.to_str().unwrap(),
        "--method",
        "rpnn",
        "--sky-dirs",
        "0",
    ]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("'--sky-dirs <SKY_DIRS>': must lie in 1..=1024"),
        "{}",
        text(&o)
    );
}

/// A scene whose albedo differs from the model's training albedo: a warning by default, a
/// refusal naming the model and both albedos with `--strict`.
#[test]
fn rpnn_albedo_guard() {
    let d = tmp("albedo");
    let scene = d.join("albedo08.toml");
    std::fs::write(
        &scene,
        r#"
[volume]
generator = { kind = "cumulus", seed = 7, resolution = [24, 18, 24] }
density_scale = 20.0
albedo = 0.8
phase = { kind = "hg", g = 0.857 }
[sun]
direction = [0.0, 1.0, 0.3]
irradiance = 1.0
[camera]
origin = [0.0, 0.0, 4.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
vfov_deg = 30.0
width = 8
height = 6
[render]
spp = 1
"#,
    )
    .unwrap();
    let model = root().join("models/rpnn-hg.onnx");
    let args = |strict: bool| {
        let mut a = vec![
            "render".to_string(),
            scene.display().to_string(),
            "--method".into(),
            "rpnn".into(),
            "--backend".into(),
            "ort".into(),
            "--model".into(),
            model.display().to_string(),
            "-q".into(),
            "-o".into(),
            d.join("albedo08").display().to_string(),
        ];
        if strict {
            a.push("--strict".into());
        }
        a
    };
    let o = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .args(args(true))
        .output()
        .unwrap();
    let t = text(&o);
    assert!(
        !o.status.success()
            && t.contains("rpnn-hg.onnx")
            && t.contains("albedo 1")
            && t.contains("albedo 0.8"),
        "{t}"
    );
    let o = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .args(args(false))
        .output()
        .unwrap();
    let t = text(&o);
    assert!(
        o.status.success() && t.contains("warning") && t.contains("albedo 0.8"),
        "{t}"
    );
}

/// Flags get the same checks as scene keys, an overflowing camera is refused instead of
/// tracing NaN rays forever, and an all-black reference is an error, not NaN metrics.
#[test]
fn flags_cameras_and_references_that_would_lie() {
    let d = tmp("flags");
    let scene = root().join("scenes/refs/cube_iso.toml");
    let s = scene.to_str().unwrap();
    for (args, want) in [
        (vec!["render", s, "--exposure", "nan"], "--exposure"),
        (vec!["render", s, "--exposure", "0"], "--exposure"),
        (vec!["render", s, "--exposure=-1"], "--exposure"),
        (vec!["render", s, "--exposure", "inf"], "--exposure"),
        (vec!["render", s, "--threads", "100000"], "--threads"),
        (vec!["render", s, "--threads", "0"], "--threads"),
        (vec!["render", s, "--spp", "4294967295"], "--spp"),
        (
            vec!["render", s, "--method", "pm", "--beams", "0"],
            "--beams",
        ),
        (
            vec!["render", s, "--method", "pm", "--similarity", "nan"],
            "--similarity",
        ),
        (
            vec!["render", s, "--method", "pm", "--similarity", "1"],
            "--similarity",
        ),
    ] {
        let start = std::time::Instant::now();
        let o = nimbus(&args);
        assert!(!o.status.success(), "{args:?} must fail: {}", text(&o));
        assert!(text(&o).contains(want), "{args:?}: {}", text(&o));
        // Refused while parsing: nothing is rendered.
        assert!(
            start.elapsed().as_secs() < 10,
            "{args:?} took {:?}",
            start.elapsed()
        );
    }
    let far = d.join("far.toml");
    std::fs::write(
        &far,
        "[volume]\ngenerator = { kind = \"cumulus\", resolution = [8, 8, 8] }\n\
         [sun]\ndirection = [0.0, 1.0, 0.0]\nirradiance = 1.0\n\
         [camera]\norigin = [1e308, 0.0, 0.0]\ntarget = [-1e308, 0.0, 0.0]\nvfov_deg = 30\nwidth = 4\nheight = 4\n",
    )
    .unwrap();
    let o = nimbus(&["render", far.to_str().unwrap(), "-q"]);
    assert!(
        !o.status.success() && text(&o).contains("far.toml") && text(&o).contains("camera.target"),
        "{}",
        text(&o)
    );
    // An all-black reference: relative metrics are undefined.
    let black = nimbus_scene::Image::new(4, 4);
    let (a, b) = (d.join("black_a.exr"), d.join("black_b.exr"));
    black.write_exr(&a, None).unwrap();
    black.write_exr(&b, None).unwrap();
    let o = nimbus(&["compare", a.to_str().unwrap(), b.to_str().unwrap()]);
    assert!(
        !o.status.success() && text(&o).contains("black_b.exr") && text(&o).contains("undefined"),
        "{}",
        text(&o)
    );
}

/// Light values whose derived radiance would not fit the f32 images are refused by field
/// (they used to write EXRs full of inf/NaN and say "wrote").
#[test]
fn lights_that_overflow_the_image_are_refused() {
    let d = tmp("lights");
    let base = "[volume]\ngenerator = { kind = \"cumulus\", resolution = [8, 8, 8] }\n\
                [camera]\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 0.0]\nvfov_deg = 30\nwidth = 4\nheight = 4\n";
    for (name, extra, field) in [
        ("sky", "[sky]\nradiance = 1e39\n", "sky.radiance"),
        (
            "sun",
            "[sun]\ndirection = [0.0, 1.0, 0.0]\nirradiance = 1e308\n",
            "sun.irradiance",
        ),
        (
            "disc",
            "[sun]\ndirection = [0.0, 1.0, 0.0]\nirradiance = 1.0\nangular_radius_deg = 1e-300\n",
            "sun.angular_radius_deg",
        ),
    ] {
        let p = d.join(format!("light_{name}.toml"));
        std::fs::write(&p, format!("{base}{extra}")).unwrap();
        let o = nimbus(&["render", p.to_str().unwrap(), "-q", "--spp", "1"]);
        let t = text(&o);
        assert!(
            !o.status.success() && t.contains(field) && !t.contains("wrote"),
            "{name}: {t}"
        );
    }
}
