//! Volume files written by the official OpenVDB tools render end to end: full- and half-float
//! OpenVDB, NanoVDB Float and Fp16 (`crates/scene/tests/data/make_codecs.sh`).

use crate::common::{nimbus, text};
use std::path::{Path, PathBuf};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../scene/tests/data")
        .join(name)
        .canonicalize()
        .unwrap()
}

/// A scene of `file` under a fixed sun (HG g = 0.85, albedo 0.99, seed 3); `camera` holds the
/// camera's origin, target, vfov_deg, width and height lines.
fn scene_toml(file: &Path, density_scale: f64, camera: &str, spp: u32) -> String {
    format!(
        r#"[volume]
file = "{}"
density_scale = {density_scale:?}
albedo = 0.99
phase = {{ kind = "hg", g = 0.85 }}

[sun]
direction = [0.4, 0.8, 0.6]
irradiance = [3.0, 3.0, 3.0]

[camera]
{camera}
up = [0.0, 1.0, 0.0]

[render]
spp = {spp}
seed = 3
"#,
        file.display()
    )
}

/// Renders `file` with the path tracer (fixed seed) and returns the PNG's bytes.
fn render(dir: &Path, file: &str) -> Vec<u8> {
    let scene = dir.join(format!("{file}.toml"));
    let camera = "origin = [1.07, 1.15, 3.2]\ntarget = [1.07, 1.15, 1.12]\nvfov_deg = 24.0\nwidth = 32\nheight = 24";
    std::fs::write(&scene, scene_toml(&data(file), 40.0, camera, 8)).unwrap();
    let out = dir.join(file);
    let o = nimbus(&[
        "render",
        scene.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{file}: {}", text(&o));
    std::fs::read(out.with_extension("png")).unwrap()
}

fn mean(png: &[u8]) -> f64 {
    let img = image::load_from_memory(png).unwrap().to_rgb8();
    img.pixels().map(|p| p[1] as f64).sum::<f64>() / (img.width() * img.height()) as f64
}

#[test]
fn openvdb_and_nanovdb_files_render_alike() {
    let dir = std::env::temp_dir().join(format!("nimbus-volumes-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let o = nimbus(&["info", data("cloud_fp16.nvdb").to_str().unwrap()]);
    assert!(
        o.status.success() && text(&o).contains("36 x 28 x 31"),
        "{}",
        text(&o)
    );
    // The same float grid through both readers: the same image, bit for bit.
    let a = render(&dir, "cloud_blosc.vdb");
    let b = render(&dir, "cloud.nvdb");
    assert!(a == b, "OpenVDB and NanoVDB renders differ");
    // Half floats (rel. error ≤ 2^-11) and 16-bit quantisation (≤ 6e-6 of the range) change
    // densities by < 0.05 %: the mean 8-bit level of a 32×24 image moves by < 0.5 %.
    let m = mean(&a);
    assert!(m > 5.0, "the cloud must be visible: mean level {m}");
    for f in ["cloud_half.vdb", "cloud_fp16.nvdb"] {
        let mh = mean(&render(&dir, f));
        assert!((mh / m - 1.0).abs() < 0.005, "{f}: mean {mh} vs {m}");
    }
}

/// A sparse file whose box is 4.8 G voxels (19 GB dense, more voxels than a u32 counts;
/// `make_sparse.sh`) renders with every estimator under a 1 GB budget: the CPU path tracer, the
/// GPU one, which reads the bricks through its brick-map atlas, RPNN, whose stencils read level
/// 0 of the pyramid at this density (stored as bricks: the level is zero away from the
/// spheres), and the photon map, whose light volumes are fine enough for the spheres' density
/// with only the 8³ bricks near them stored — and which says so, and that its image is too
/// dark: the cache's cells over this box are far wider than the spheres (BENCHMARKS.md).
#[test]
fn a_sparse_file_renders_with_every_estimator() {
    let dir = std::env::temp_dir().join(format!("nimbus-sparse-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("far.toml");
    let camera = "origin = [0.010, 0.010, 0.06]\ntarget = [0.010, 0.010, 0.010]\nvfov_deg = 20.0\nwidth = 24\nheight = 16";
    std::fs::write(
        &scene,
        scene_toml(&data("far_spheres.vdb"), 500.0, camera, 4),
    )
    .unwrap();
    // `info` says how it is stored: the spheres' 16 leaves, the block's 8 tiles, the rest absent.
    let o = nimbus(&["info", data("far_spheres.vdb").to_str().unwrap()]);
    assert!(
        text(&o).contains("sparse: 16 stored, 8 constant, 9528104 absent bricks"),
        "{}",
        text(&o)
    );
    let out = dir.join("far");
    let o = nimbus(&[
        "render",
        scene.to_str().unwrap(),
        "--max-memory",
        "1G",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let m = mean(&std::fs::read(out.with_extension("png")).unwrap());
    assert!(m > 5.0, "the sphere must be visible: mean level {m}");
    for args in [
        &["--method", "rpnn"][..],
        // A short ring: most beams cross the empty box (BENCHMARKS.md).
        &["--method", "pm", "--ring", "8"][..],
        &["--method", "pm-march", "--ring", "8"][..],
        &["--device", "gpu"][..],
    ] {
        if args[0] != "--method" || args[1].starts_with("pm") {
            let what = format!("volumes: the sparse file with {args:?}");
            if !nimbus_gpu::testing::has_adapter(&what) {
                continue;
            }
        }
        let mut a = vec!["render", scene.to_str().unwrap(), "--max-memory", "1G"];
        a.extend_from_slice(args);
        a.extend_from_slice(&["-o", out.to_str().unwrap()]);
        let o = nimbus(&a);
        let t = text(&o);
        assert!(o.status.success(), "{args:?}: {t}");
        let mg = mean(&std::fs::read(out.with_extension("png")).unwrap());
        // Visible (4 spp of a tone-mapped 24×16 image are too noisy to compare means;
        // RPNN's sparse levels equal the dense ones bit for bit: `nimbus_rpnn::pyramid`).
        assert!(
            mg > 5.0,
            "{args:?}: the sphere must be visible: mean level {mg}"
        );
        // The photon maps name their coarse light volumes and the thinly filled cache: the
        // ray marcher warns of a dark image, final gathering bounces through such cells.
        if args[1].starts_with("pm") {
            let consequence = if args[1] == "pm" {
                "gather paths bounce on through them"
            } else {
                "the image comes out too dark"
            };
            assert!(
                t.contains("light volumes")
                    && t.contains("bricks stored (those near density)")
                    && t.contains(consequence),
                "{t}"
            );
        }
    }
}
