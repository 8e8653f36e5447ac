//! Volume readers and the scene parser on real files, including malformed ones.

use std::path::{Path, PathBuf};

use nimbus_scene::io;
use nimbus_scene::{Scene, phase::Phase};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nimbus-scene-tests-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

#[test]
fn vdb_float_grid_is_densified() {
    // Written by pyopenvdb 10: voxels (2+x, −1+y, z) = 1 + x + 10y + 100z for a 4×3×2 block,
    // voxel (3, 0, 1) switched off, voxel size 0.25; plus a vec3 grid that must be ignored.
    let f = io::read_grid(data("small_density.vdb")).unwrap();
    assert_eq!(f.grid.res(), [4, 3, 2]);
    for z in 0..2 {
        for y in 0..3 {
            for x in 0..4 {
                let expected = if (x, y, z) == (1, 1, 1) {
                    0.0
                } else {
                    (1 + x + 10 * y + 100 * z) as f32
                };
                assert_eq!(f.grid.get(x, y, z), expected, "voxel {x},{y},{z}");
            }
        }
    }
    let (lo, hi) = f.bounds.unwrap();
    let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
    assert!(close(lo.x, 1.5 * 0.25) && close(lo.y, -1.5 * 0.25) && close(lo.z, -0.5 * 0.25));
    assert!(close(hi.x, 5.5 * 0.25) && close(hi.y, 1.5 * 0.25) && close(hi.z, 1.5 * 0.25));
    // Half floats: tests/vdb.rs.
}

#[test]
fn vdb_errors_are_clear() {
    let e = io::read_grid(data("no_density.vdb"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no_density.vdb") && e.contains("no grid named `density`"),
        "{e}"
    );
    // Truncated and corrupted copies: an error, never a panic escaping or a hang.
    let bytes = std::fs::read(data("small_density.vdb")).unwrap();
    for cut in [0usize, 4, 8, 100, 400, bytes.len() / 2] {
        let p = tmp(&format!("cut{cut}.vdb"));
        std::fs::write(&p, &bytes[..cut]).unwrap();
        let e = io::read_grid(&p).unwrap_err().to_string();
        assert!(e.contains(&format!("cut{cut}.vdb")), "{e}");
    }
    let p = tmp("garbage.vdb");
    std::fs::write(&p, b"this is not a vdb file at all").unwrap();
    assert!(io::read_grid(&p).unwrap_err().to_string().contains("magic"));
    // Found by `cargo fuzz run vdb` against the former third-party reader (it panicked): a
    // descriptor whose offsets point past the end of the file.
    let e = io::read_grid(data("fuzz-transform-not-supported.vdb"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("fuzz-transform-not-supported.vdb")
            && e.contains("grid.descriptor")
            && e.contains("within the 6690 bytes of the file"),
        "{e}"
    );
}

#[test]
fn shared_reference_volumes_load() {
    // ../shared/refs holds the Mitsuba cases; .vol and .npy hold the same data.
    let refs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/refs/volumes");
    let a =
        io::read_grid(refs.join("cumulus.vol")).expect("shared/refs must sit beside the checkout");
    let b = io::read_grid(refs.join("cumulus.npy")).unwrap();
    assert_eq!(a.grid, b.grid);
    assert_eq!(a.grid.res(), [128, 96, 128]);
    let s = a.grid.stats();
    // Values from shared/refs/volumes/cumulus.json.
    assert!((s.mean - 0.09821947664022446).abs() < 1e-6);
    assert!((s.nonzero_fraction - 0.1356525421142578).abs() < 1e-9);
    let cols = a.grid.max_column_sums();
    let cell = 0.015625;
    assert!((cols[0] * cell - 1.2433457374572754).abs() < 1e-5);
}

const GOOD: &str = r#"
[volume]
generator = { kind = "cumulus", seed = 1, resolution = [16, 12, 16] }
density_scale = 10.0
albedo = 0.9
phase = { kind = "hg", g = 0.857 }
[sun]
direction = [1.0, 1.0, 0.0]
irradiance = 2.0
[sky]
radiance = [0.1, 0.2, 0.3]
[camera]
origin = [0.0, 0.0, 4.0]
target = [0.0, 0.0, 0.0]
vfov_deg = 30.0
width = 16
height = 12
[render]
spp = 4
"#;

fn parse(text: &str) -> Result<Scene, String> {
    Scene::from_toml_str(text, Path::new("."), Path::new("test.toml")).map_err(|e| e.to_string())
}

#[test]
fn scene_parses() {
    let s = parse(GOOD).unwrap();
    assert_eq!(s.volume.grid().res(), [16, 12, 16]);
    assert!(matches!(s.medium.phase, Phase::HenyeyGreenstein(_)));
    assert_eq!(s.render.spp, 4);
    assert_eq!(s.render.max_depth, None);
    assert!((s.sun.as_ref().unwrap().irradiance.x - 2.0).abs() < 1e-12);
    // Mie with a chopped peak: full function first, reduced density after.
    let mie = GOOD.replace(
        r#"phase = { kind = "hg", g = 0.857 }"#,
        r#"phase = { kind = "mie", effective_radius_um = 8.0, chop_deg = 5.0 }"#,
    );
    let s = parse(&mie).unwrap();
    let c = s.medium.chopped.as_ref().unwrap();
    assert!(c.density_factor < 1.0 && c.density_factor > 0.4);
    assert_eq!(s.medium.density_factor(0), 1.0);
    assert_eq!(s.medium.density_factor(1), c.density_factor);
}

#[test]
fn scene_errors_name_file_and_field() {
    let cases: &[(&str, &str, &str)] = &[
        ("g = 0.857", "g = 1.0", "volume.phase.g"),
        ("g = 0.857", "g = -1.5", "volume.phase.g"),
        ("albedo = 0.9", "albedo = 1.5", "volume.albedo"),
        ("albedo = 0.9", "albdo = 0.9", "unknown field `albdo`"),
        ("spp = 4", "spp = 0", "render.spp"),
        ("spp = 4", "spp = -3", "render.spp"),
        ("width = 16", "width = -16", "camera.width"),
        ("width = 16", "width = 100000000", "camera.width"),
        ("vfov_deg = 30.0", "vfov_deg = nan", "camera.vfov_deg"),
        (
            "density_scale = 10.0",
            "density_scale = -1.0",
            "volume.density_scale",
        ),
        ("[16, 12, 16]", "[0, 12, 16]", "volume.generator.resolution"),
        (
            "[16, 12, 16]",
            "[100000, 100000, 100000]",
            "volume.generator.resolution",
        ),
        (
            "kind = \"cumulus\"",
            "kind = \"fog\"",
            "volume.generator.kind",
        ),
        ("irradiance = 2.0", "irradiance = -2.0", "sun.irradiance"),
        ("[1.0, 1.0, 0.0]", "[0.0, 0.0, 0.0]", "sun.direction"),
        (
            "kind = \"hg\", g = 0.857",
            "kind = \"hg\", g = 0.857, h = 1",
            "volume.phase.h",
        ),
        ("kind = \"hg\"", "kind = \"rayleigh\"", "volume.phase.kind"),
        // The sky's factors are checked one by one: -1 × -1 is no radiance of 1, and a
        // negative radiance is no black sky because its scale is 0.
        (
            "radiance = [0.1, 0.2, 0.3]",
            "radiance = -1.0\nscale = -1.0",
            "sky.scale",
        ),
        (
            "radiance = [0.1, 0.2, 0.3]",
            "radiance = -1.0\nscale = 0.0",
            "sky.radiance",
        ),
        (
            "radiance = [0.1, 0.2, 0.3]",
            "radiance = [0.1, nan, 0.3]",
            "sky.radiance",
        ),
        // Two valid factors whose product overflows: named as the overflow it is.
        (
            "radiance = [0.1, 0.2, 0.3]",
            "radiance = 1e300\nscale = 1e300",
            "radiance × scale = inf exceeds",
        ),
    ];
    for (from, to, field) in cases {
        assert!(GOOD.contains(from), "{from}");
        let e = parse(&GOOD.replacen(from, to, 1)).unwrap_err();
        assert!(e.contains("test.toml") && e.contains(field), "{to}: {e}");
    }
    // Missing volume file: names the file.
    let e = parse(&GOOD.replace(
        r#"generator = { kind = "cumulus", seed = 1, resolution = [16, 12, 16] }"#,
        r#"file = "missing.vol""#,
    ))
    .unwrap_err();
    assert!(e.contains("missing.vol"), "{e}");
    assert!(parse("not [ toml").unwrap_err().contains("test.toml"));
}

/// Environment maps that cannot light a scene are refused, naming the file and the field:
/// a missing file, NaN and negative texels, and a multi-part EXR whose RGB part claims
/// 10⁶ × 10⁶ pixels behind a 1×1 first part. The memory budget once checked the first part
/// only, while the reader takes the first part with RGB; this file's short chunk table still
/// stopped the exr crate, but one with a table to match (≈ 0.5 MB) would have had 12 TB
/// allocated. Now the budget refuses it, naming the size.
#[test]
fn bad_environment_maps_are_refused() {
    let with_map = |p: &Path| {
        GOOD.replace(
            "radiance = [0.1, 0.2, 0.3]",
            &format!("envmap = {:?}", p.display().to_string()),
        )
    };
    let e = parse(&with_map(&tmp("no-such-map.exr"))).unwrap_err();
    assert!(
        e.contains("test.toml") && e.contains("sky.envmap") && e.contains("no-such-map.exr"),
        "{e}"
    );
    for (name, texel, says) in [
        ("nan-map.exr", [0.5, f32::NAN, 0.5], "pixel[2,1]"),
        ("negative-map.exr", [0.5, -0.25, 0.5], "pixel[2,1]"),
    ] {
        // Written by the exr crate itself: Nimbus' own writer refuses NaN.
        let p = tmp(name);
        exr::prelude::write_rgb_file(&p, 8, 4, |x, y| {
            let [r, g, b] = if (x, y) == (2, 1) { texel } else { [1.0; 3] };
            (r, g, b)
        })
        .unwrap();
        let e = parse(&with_map(&p)).unwrap_err();
        assert!(e.contains(name) && e.contains(says), "{name}: {e}");
    }
    // The scale is the scene's field, named there, with either kind of sky.
    let bright = tmp("bright-map.exr");
    exr::prelude::write_rgb_file(&bright, 8, 4, |x, _| {
        let v = if x == 0 { 1e20f32 } else { 1.0 };
        (v, v, v)
    })
    .unwrap();
    // A map scaled by 0 is no sky: left out, as a black constant sky is.
    let text = with_map(&bright).replace("[camera]", "scale = 0.0\n[camera]");
    assert!(parse(&text).unwrap().sky.is_none());
    for (scale, says) in [("-1.0", "must be finite"), ("1e20", "brightest pixel")] {
        let text = with_map(&bright).replace("[camera]", &format!("scale = {scale}\n[camera]"));
        let e = parse(&text).unwrap_err();
        assert!(
            e.starts_with("test.toml") && e.contains("sky.scale") && e.contains(says),
            "scale {scale}: {e}"
        );
    }
    // Two parts: a 1×1 depth image, then a 4×4 RGB image whose data window is patched to
    // 10⁶ × 10⁶ (its chunk table stays the 4×4 one's: the header is what the budget reads).
    use exr::prelude::*;
    let depth = Layer::new(
        (1, 1),
        LayerAttributes::named("depth"),
        Encoding::UNCOMPRESSED,
        AnyChannels::sort(vec![AnyChannel::new("Z", FlatSamples::F32(vec![1.0]))].into()),
    );
    let rgb = Layer::new(
        (4, 4),
        LayerAttributes::named("rgb"),
        Encoding::UNCOMPRESSED,
        AnyChannels::sort(
            vec![
                AnyChannel::new("B", FlatSamples::F32(vec![1.0; 16])),
                AnyChannel::new("G", FlatSamples::F32(vec![1.0; 16])),
                AnyChannel::new("R", FlatSamples::F32(vec![1.0; 16])),
            ]
            .into(),
        ),
    );
    let p = tmp("two-parts.exr");
    let layers: Layers<_> = vec![depth, rgb].into();
    Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions((4, 4))),
        layers,
    )
    .write()
    .to_file(&p)
    .unwrap();
    let mut bytes = std::fs::read(&p).unwrap();
    let key = b"dataWindow\0box2i\0";
    let at: Vec<usize> = bytes
        .windows(key.len())
        .enumerate()
        .filter(|(_, w)| *w == key)
        .map(|(i, _)| i + key.len() + 4)
        .collect();
    assert_eq!(at.len(), 2, "one data window per part");
    // box2i: x_min, y_min, x_max, y_max; the second part's maxima become 999 999.
    for k in [2, 3] {
        bytes[at[1] + 4 * k..at[1] + 4 * k + 4].copy_from_slice(&999_999i32.to_le_bytes());
    }
    std::fs::write(&p, &bytes).unwrap();
    let e = parse(&with_map(&p)).unwrap_err();
    assert!(
        e.contains("two-parts.exr") && e.contains("1000000×1000000"),
        "{e}"
    );
}

#[test]
fn npy_volume_needs_bounds() {
    let g = nimbus_scene::DensityGrid::constant([2, 2, 2], 1.0).unwrap();
    let p = tmp("cube.npy");
    io::npy::write(&p, &g).unwrap();
    let text = GOOD.replace(
        r#"generator = { kind = "cumulus", seed = 1, resolution = [16, 12, 16] }"#,
        &format!("file = {:?}", p.display().to_string()),
    );
    let e = parse(&text).unwrap_err();
    assert!(e.contains("volume.aabb_min"), "{e}");
    let with_box = text.replace(
        "density_scale",
        "aabb_min = [0,0,0]\naabb_max = [1,1,1]\ndensity_scale",
    );
    assert!(parse(&with_box).is_ok());
}

#[test]
fn atmosphere_reddens_a_low_sun() {
    let high =
        parse(&GOOD.replace("irradiance = 2.0", "irradiance = 2.0\natmosphere = true")).unwrap();
    let low = parse(
        &GOOD
            .replace("irradiance = 2.0", "irradiance = 2.0\natmosphere = true")
            .replace(
                "direction = [1.0, 1.0, 0.0]",
                "direction = [1.0, 0.05, 0.0]",
            ),
    )
    .unwrap();
    let (h, l) = (high.sun.unwrap().irradiance, low.sun.unwrap().irradiance);
    // 45° sun: air mass √2, 550 nm transmittance exp(−0.197 √2) ≈ 0.757.
    assert!(
        (h.y / 2.0
            - (-(nimbus_scene::atmosphere::rayleigh_tau(0.55) + 0.1) * std::f64::consts::SQRT_2)
                .exp())
        .abs()
            < 0.01
    );
    assert!(l.x / l.z > h.x / h.z && l.y < h.y);
}

#[test]
fn moving_the_sun_recolours_it_like_a_scene_written_that_way() {
    let with = |dir: &str| {
        parse(
            &GOOD
                .replace("irradiance = 2.0", "irradiance = 2.0\natmosphere = true")
                .replace("direction = [1.0, 1.0, 0.0]", dir),
        )
        .unwrap()
    };
    let mut moved = with("direction = [1.0, 1.0, 0.0]");
    moved.set_sun_dir(glam::DVec3::new(1.0, 0.05, 0.0));
    let low = with("direction = [1.0, 0.05, 0.0]");
    let (a, b) = (moved.sun.as_ref().unwrap(), low.sun.as_ref().unwrap());
    assert!((a.dir - b.dir).length() < 1e-12);
    assert!((a.irradiance - b.irradiance).length() < 1e-12);
    match (&moved.sky, &low.sky) {
        (Some(nimbus_scene::Sky::Constant(x)), Some(nimbus_scene::Sky::Constant(y))) => {
            assert!((*x - *y).length() < 1e-12)
        }
        _ => panic!("constant skies expected"),
    }
    // Without an atmosphere only the direction changes.
    let mut plain = parse(GOOD).unwrap();
    let e = plain.sun.as_ref().unwrap().irradiance;
    plain.set_sun_dir(glam::DVec3::new(1.0, 0.05, 0.0));
    assert_eq!(plain.sun.as_ref().unwrap().irradiance, e);
}

/// A `.vdb` whose fog grid is not called `density` (written by OpenVDB's own bindings,
/// `make_named_grid.py`): refused by default with the names in the file and how to choose, read
/// by name from the API and from a scene's `grid` key; naming a grid of another format or next
/// to a generator is an error.
#[test]
fn vdb_grids_are_chosen_by_name() {
    let path = data("smoke_grid.vdb");
    let e = io::read_grid(&path).unwrap_err().to_string();
    assert!(
        e.contains("smoke_grid.vdb") && e.contains("\"smoke\"") && e.contains("grid = "),
        "{e}"
    );
    let f = io::read_grid_named(&path, Some("smoke")).unwrap();
    // A 6³ block of 0.5 at index 2..=7: 216 voxels, all 0.5, box from voxel corners.
    assert_eq!(f.grid.res(), [6, 6, 6]);
    assert!(f.grid.dense().unwrap().iter().all(|&v| v == 0.5));
    let (lo, hi) = f.bounds.unwrap();
    assert_eq!((lo.x, hi.x), (1.5, 7.5));
    let t = io::read_grid_named(&path, Some("temperature")).unwrap();
    assert_eq!(t.grid.res(), [4, 4, 4]);
    let e = io::read_grid_named(data("small_density.vdb"), Some("smoke"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("no grid named `smoke`"), "{e}");
    let dir = std::env::temp_dir().join(format!("nimbus-grid-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cam =
        "[camera]\norigin = [0, 0, 20]\ntarget = [4, 4, 4]\nvfov_deg = 30\nwidth = 4\nheight = 4\n";
    let scene = |vol: &str| {
        let p = dir.join("s.toml");
        std::fs::write(&p, format!("[volume]\n{vol}\n{cam}")).unwrap();
        nimbus_scene::Scene::load(&p)
    };
    let s = scene(&format!(
        "file = {:?}\ngrid = \"smoke\"",
        path.to_str().unwrap()
    ))
    .unwrap();
    assert_eq!(s.volume.grid().res(), [6, 6, 6]);
    let e = scene("generator = { kind = \"cumulus\", resolution = [8, 8, 8] }\ngrid = \"smoke\"")
        .unwrap_err()
        .to_string();
    assert!(e.contains("volume.grid"), "{e}");
    let vol = dir.join("a.vol");
    io::write_grid(&vol, &f.grid, (lo, hi)).unwrap();
    let e = io::read_grid_named(&vol, Some("smoke"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("only .vdb and .nvdb files hold named grids"),
        "{e}"
    );
}

/// Bytes held in memory (a file dropped onto a page) parse to the grid the file reads to, in
/// every format; a name's extension chooses the reader and labels the errors.
#[test]
fn grids_parse_from_bytes_as_from_files() {
    let refs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/refs/volumes");
    let files = [
        refs.join("cube.vol"),
        data("cloud_dense.npy"),
        data("cloud_blosc.vdb"),
        data("cloud_fp8.nvdb"),
    ];
    for f in files {
        let from_file = io::read_grid(&f).unwrap();
        let bytes = std::fs::read(&f).unwrap();
        let name = Path::new(f.file_name().unwrap());
        let from_bytes = io::parse_grid_named(&bytes, name, None).unwrap();
        assert_eq!(from_bytes.grid, from_file.grid, "{}", f.display());
        assert_eq!(from_bytes.bounds, from_file.bounds, "{}", f.display());
        let e = io::parse_grid_named(&bytes[..bytes.len() / 2], name, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains(&*name.to_string_lossy()), "{e}");
    }
    let e = io::parse_grid_named(b"x", Path::new("cloud.txt"), None)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cloud.txt") && e.contains("unknown volume format"),
        "{e}"
    );
}
