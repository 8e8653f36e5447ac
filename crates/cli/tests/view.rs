//! `nimbus view` end to end: a real window under Xvfb (Debian `xvfb`) with lavapipe, driven by a
//! script, and the headless mode against `render --method pm`.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::{root, text, tmp};
use nimbus_scene::Image;

/// An Xvfb server on a display of its own, stopped on drop.
struct Xvfb {
    child: Child,
    display: String,
}

impl Xvfb {
    fn start() -> Self {
        let n = 100 + std::process::id() % 800;
        let display = format!(":{n}");
        let child = Command::new("Xvfb")
            .args([&display, "-screen", "0", "800x600x24", "-nolisten", "tcp"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("Xvfb is needed for the viewer test: apt-get install xvfb");
        let socket = PathBuf::from(format!("/tmp/.X11-unix/X{n}"));
        let t0 = Instant::now();
        while !socket.exists() {
            assert!(
                t0.elapsed() < Duration::from_secs(20),
                "Xvfb did not start on {display}"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        Self { child, display }
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

const SIZE: &str = "160x100";
/// The ray-marched photon map (whose ring, impostors and convergence these tests follow).
const PM: [&str; 6] = ["--method", "pm-march", "--ring", "6", "--beams", "1024"];

fn lum(p: [f32; 3]) -> f64 {
    (0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]) as f64
}

/// The cloud is in the middle of the demo view and brighter than the sky around it.
fn assert_cloud(img: &Image, what: &str) {
    assert!(
        img.pixels
            .iter()
            .flatten()
            .all(|c| c.is_finite() && *c >= 0.0),
        "{what}: NaN, Inf or negative pixels"
    );
    let sky = lum(img.get(0, 0));
    let (w, h) = (img.width, img.height);
    let (mut cloud, mut n) = (0, 0);
    for y in h * 3 / 10..h * 7 / 10 {
        for x in w * 3 / 10..w * 7 / 10 {
            n += 1;
            cloud += (lum(img.get(x, y)) > 1.2 * sky) as usize;
        }
    }
    // The generated cumulus fills most of the central box: at least 1.2× the sky in 68 % of
    // its pixels in the path tracer's image (64 spp, 320×200), 70 % in the photon map at this
    // test's budget (6 × 1 024 beams); half is a floor that an empty or black frame fails.
    assert!(
        cloud * 2 > n,
        "{what}: only {cloud} of {n} central pixels brighter than the sky"
    );
}

fn mean_abs_rel(a: &Image, b: &Image) -> f64 {
    let (mut d, mut s) = (0.0, 0.0);
    for (p, q) in a.pixels.iter().zip(&b.pixels) {
        d += (lum(*p) - lum(*q)).abs();
        s += lum(*q);
    }
    d / s
}

#[test]
fn window_under_xvfb_with_scripted_input() {
    if !nimbus_gpu::testing::has_adapter("view::window_under_xvfb_with_scripted_input") {
        return;
    }
    let x = Xvfb::start();
    let d = tmp("window");
    let (a, b) = (d.join("before.exr"), d.join("after.exr"));
    let script = d.join("script.txt");
    // Frames 0–5 fill the ring; frame 6 is the converged image. Then the sun swings round and
    // the ring is replaced over six frames; the camera orbits a little on the way.
    std::fs::write(
        &script,
        format!(
            "6 screenshot {}\n7 sun 60 30\n9 orbit 2 1\n9 zoom 0.95\n13 screenshot {}\n13 save-scene {}\n13 quit\n",
            a.display(),
            b.display(),
            d.join("saved.toml").display()
        ),
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .current_dir(root())
        .env("DISPLAY", &x.display)
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .args(["view", "scenes/demo-cumulus.toml", "--size", SIZE, "--log"])
        .args(PM)
        .args(["--script", script.to_str().unwrap(), "--frames", "40"])
        .output()
        .unwrap();
    let log = text(&out);
    assert!(out.status.success(), "{log}");
    // The title/status line carries stage times, photons and the impostor criteria.
    assert!(log.contains("frame 13:"), "{log}");
    assert!(log.contains("photon beams this frame") && log.contains("impostor"));
    assert!(log.contains("present"));
    assert!(
        !log.contains("frame 14:"),
        "quit at frame 13 did not stop the viewer"
    );
    let before = Image::read_exr(&a).unwrap();
    let after = Image::read_exr(&b).unwrap();
    assert_eq!((before.width, before.height), (160, 100));
    assert_cloud(&before, "before");
    assert_cloud(&after, "after");
    // Back-lit → front-lit changes the image strongly (seen: ≈ 0.3 mean relative luminance
    // change); camera noise-free PM images of the same view differ by 0.
    let change = mean_abs_rel(&after, &before);
    assert!(
        change > 0.05,
        "sun change altered the image by only {change}"
    );
    let saved = nimbus_scene::Scene::load(d.join("saved.toml")).unwrap();
    assert!((saved.sun.unwrap().dir.y - 30f64.to_radians().sin()).abs() < 1e-9);
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn headless_converges_to_the_photon_mapping_render() {
    if !nimbus_gpu::testing::has_adapter("view::headless_converges_to_the_photon_mapping_render") {
        return;
    }
    let d = tmp("headless");
    let (v, r) = (d.join("view.exr"), d.join("render.exr"));
    let view = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .current_dir(root())
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .args([
            "view",
            "scenes/demo-cumulus.toml",
            "--headless",
            "--size",
            SIZE,
        ])
        .args(PM)
        .args(["--screenshot", v.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(view.status.success(), "{}", text(&view));
    assert!(text(&view).contains("6 frames"), "{}", text(&view));
    // `render` uses the scene camera's size: give it the same through a copy of the scene.
    let scene = std::fs::read_to_string(root().join("scenes/demo-cumulus.toml"))
        .unwrap()
        .replace("width = 320", "width = 160")
        .replace("height = 200", "height = 100");
    let sp = d.join("scene.toml");
    std::fs::write(&sp, scene).unwrap();
    let render = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .args(["render", sp.to_str().unwrap()])
        .args(PM)
        .args(["-o", r.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(render.status.success(), "{}", text(&render));
    let (a, b) = (Image::read_exr(&v).unwrap(), Image::read_exr(&r).unwrap());
    assert_cloud(&a, "headless");
    // After m frames the viewer's ring holds the same generations as `render`'s converged one,
    // traced with the same seeds and integer deposits: the same image, bit for bit.
    assert_eq!(a.pixels, b.pixels);
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn no_display_is_a_clear_error() {
    let out = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .args(["view", "--frames", "1"])
        .current_dir(root())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let t = text(&out);
    assert!(t.contains("display") && t.contains("--headless"), "{t}");
}

#[test]
fn bad_script_names_file_and_line() {
    let d = tmp("script");
    let script = d.join("bad.txt");
    std::fs::write(&script, "0 sun 10 20\n1 orbit ten 0\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .args(["view", "--headless", "--script", script.to_str().unwrap()])
        .current_dir(root())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let t = text(&out);
    assert!(
        t.contains("bad.txt:2: `orbit`: `ten` is not a number"),
        "{t}"
    );
    std::fs::remove_dir_all(&d).ok();
}

/// The viewer's default, the gathered photon map, headless: the ring fills, then gathered
/// samples accumulate (the log counts them) into an image of the cloud.
#[test]
fn headless_gathered_photon_map_accumulates() {
    if !nimbus_gpu::testing::has_adapter("view::headless_gathered_photon_map_accumulates") {
        return;
    }
    let d = tmp("gathered");
    let v = d.join("view.exr");
    let o = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .current_dir(root())
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .args([
            "view",
            "scenes/demo-cumulus.toml",
            "--headless",
            "--size",
            SIZE,
        ])
        .args(["--ring", "4", "--beams", "16384", "--frames", "12", "--log"])
        .args(["--screenshot", v.to_str().unwrap()])
        .output()
        .unwrap();
    let log = text(&o);
    assert!(o.status.success(), "{log}");
    assert!(log.contains("ring 4/4") && log.contains("8 spp"), "{log}");
    assert_cloud(&Image::read_exr(&v).unwrap(), "gathered");
    std::fs::remove_dir_all(&d).ok();
}
