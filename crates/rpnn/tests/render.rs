//! Rendering with the network (Kallweit 2017 §4.4): the two backends give the same image, sky
//! directions are queried only with a sky, and the shipped model against the path tracer.

use std::path::Path;

use nimbus_rpnn::Pyramid;
use nimbus_rpnn::gpu_mlp::GpuRpnn;
use nimbus_rpnn::model::Rpnn;
use nimbus_rpnn::ort_backend::OrtModel;
use nimbus_rpnn::render::{Backend, RpnnOptions, render};
use nimbus_scene::Scene;

fn scene(sky: bool, w: usize, h: usize, seed: u64) -> Scene {
    let sky = if sky {
        "[sky]\nradiance = [0.1, 0.15, 0.3]"
    } else {
        ""
    };
    scene_with_sky(sky, w, h, seed)
}

/// [`scene`] with `sky` (a `[sky]` table, or nothing) as its sky.
fn scene_with_sky(sky: &str, w: usize, h: usize, seed: u64) -> Scene {
    let text = format!(
        r#"
[volume]
generator = {{ kind = "cumulus", seed = {seed}, resolution = [48, 36, 48] }}
density_scale = 30.0
phase = {{ kind = "hg", g = 0.857 }}
[sun]
direction = [0.5, 0.7, 0.5]
irradiance = [1.0, 1.0, 1.0]
{sky}
[camera]
origin = [0.0, 0.2, 3.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
vfov_deg = 30.0
width = {w}
height = {h}
[render]
seed = 3
"#
    );
    Scene::from_toml_str(&text, Path::new("."), Path::new("rpnn-test.toml")).unwrap()
}

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

#[test]
fn wgpu_and_ort_backends_render_the_same_image() {
    let s = scene(true, 24, 16, 5);
    let pyr = Pyramid::new(&s.volume).unwrap();
    let path = data("rpnn-tiny.onnx");
    let model = Rpnn::load(&path).unwrap();
    let opts = RpnnOptions::new(2, 1, 3);
    let Some(gpu) = nimbus_gpu::testing::gpu("render::wgpu_and_ort_backends_render_the_same_image")
    else {
        return;
    };
    let mut g = Backend::Wgpu(Box::new(GpuRpnn::new(&gpu, &pyr, &model, 256).unwrap()));
    let a = render(&s, &pyr, &mut g, &opts).unwrap();
    let mut o = Backend::Ort(OrtModel::load(&path, 1).unwrap());
    let b = render(&s, &pyr, &mut o, &opts).unwrap();
    // Same random numbers for everything but the network; descriptors (1e-5) and network
    // (1e-4) agree, so pixels agree to 1e-4 of the mean.
    let mean = b
        .image
        .pixels
        .iter()
        .flatten()
        .map(|v| *v as f64)
        .sum::<f64>()
        / (3 * b.image.pixels.len()) as f64;
    for (p, q) in a
        .image
        .pixels
        .iter()
        .flatten()
        .zip(b.image.pixels.iter().flatten())
    {
        assert!(
            ((p - q) as f64).abs() <= 1e-4 * mean.max(q.abs() as f64),
            "{p} vs {q}"
        );
    }
    assert_eq!(a.times.queries, b.times.queries);
    // Sun + 3 sky directions per shading point.
    assert_eq!(a.times.queries % 4, 0);
}

/// The render's queries through one session and through workers in small pieces: the same
/// image to the bit (an f32 model's outputs do not depend on the split), so each query's
/// descriptor reaches its own row and its answer its own pixel.
#[test]
fn ort_workers_render_the_one_session_image() {
    use nimbus_rpnn::ort_backend::Cores;
    let s = scene(true, 20, 14, 7);
    let pyr = Pyramid::new(&s.volume).unwrap();
    let path = data("rpnn-tiny-sky.onnx");
    let opts = RpnnOptions::new(2, 1, 3);
    let mut one = Backend::Ort(OrtModel::load(&path, 1).unwrap());
    let a = render(&s, &pyr, &mut one, &opts).unwrap();
    let mut workers = OrtModel::load(&path, Cores::Workers(3)).unwrap();
    // Pieces of at most 7 queries: many runs per worker.
    workers.rows_per_run = 7;
    let b = render(&s, &pyr, &mut Backend::Ort(workers), &opts).unwrap();
    assert!(a.times.queries > 3 * 7, "{} queries", a.times.queries);
    assert_eq!(a.times.queries, b.times.queries);
    let bits = |i: &nimbus_scene::Image| {
        i.pixels
            .iter()
            .flatten()
            .map(|v| v.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&a.image), bits(&b.image));
    // The image is not a constant (a lost query would show).
    let first = a.image.pixels[0];
    assert!(a.image.pixels.iter().any(|p| *p != first));
}

/// One sample in every m asking the network (`query_every`, beyond the paper) renders the
/// image of every sample asking, up to noise. The samples' random numbers do not depend on m,
/// so the direct light is the same in both images, and their difference is the network's part
/// only: m × (the answers of the samples that ask) − (all answers). With the sky head under
/// sun + sky, 128 spp on 24×16 pixels, m = 4: the image means differ by less than 4 standard
/// errors of that difference, the queries fall to a quarter (±5 %), and m outside 1..=64 is
/// refused by name. A weight of 1 instead of m would leave out three quarters of the
/// network's part (the image with the heads' last layers zeroed gives the part): asserted to
/// be more than 8 of those standard errors. Progressive steps (1 + 4 samples) give the image
/// of one call of 5 to the bit, so the sample index that picks the asking samples carries
/// over between calls.
#[test]
fn one_query_in_every_m_samples_renders_the_same_image() {
    let s = scene(true, 24, 16, 5);
    let pyr = Pyramid::new(&s.volume).unwrap();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rpnn-hg-sky.onnx");
    let mut o = Backend::Ort(OrtModel::load(&path, 0).unwrap());
    let opts = |m| RpnnOptions {
        sky_sh: nimbus_rpnn::render::SkySh::of(&s, 4, 32),
        query_every: m,
        ..RpnnOptions::new(128, 1, 4)
    };
    for bad in [0, nimbus_rpnn::render::MAX_QUERY_EVERY + 1] {
        let e = render(&s, &pyr, &mut o, &opts(bad)).err().expect("refused");
        assert!(e.to_string().contains("query period"), "{e}");
    }
    let all = render(&s, &pyr, &mut o, &opts(1)).unwrap();
    let some = render(&s, &pyr, &mut o, &opts(4)).unwrap();
    let lum = |p: &[f32; 3]| (p[0] + p[1] + p[2]) as f64 / 3.0;
    let n = all.image.pixels.len() as f64;
    // Per pixel the difference of the two means is a mean over 128 samples of
    // (m·[asks] − 1) × answer; its variance is at most the m = 4 image's variance of the mean
    // (which holds m² × the answers' spread), so the sum of those bounds the mean's.
    let diff: f64 = all
        .image
        .pixels
        .iter()
        .zip(&some.image.pixels)
        .map(|(a, b)| lum(b) - lum(a))
        .sum::<f64>()
        / n;
    let var: f64 = some.variance.iter().map(|&v| v as f64).sum::<f64>() / (n * n);
    let mean: f64 = all.image.pixels.iter().map(lum).sum::<f64>() / n;
    eprintln!(
        "mean {mean:.5}, m = 4 − m = 1: {diff:.6} ± {:.6}; queries {} and {}",
        var.sqrt(),
        all.times.queries,
        some.times.queries
    );
    assert!(diff.abs() <= 4.0 * var.sqrt(), "{diff} vs σ {}", var.sqrt());
    let ratio = some.times.queries as f64 / all.times.queries as f64;
    assert!((ratio - 0.25).abs() < 0.25 * 0.05, "{ratio}");
    // Per-pixel offsets: in one sample the pixels that ask are a binomial draw of 1/4 from
    // m = 1's queries (the same paths at any m): within 4 standard deviations. An offset
    // shared by all pixels would ask in all of them or none, 4·n₁/4 away.
    let mut first = |m| {
        let one = RpnnOptions { spp: 1, ..opts(m) };
        render(&s, &pyr, &mut o, &one).unwrap().times.queries as f64
    };
    let (n1, n4) = (first(1), first(4));
    let sd = (n1 * 0.25 * 0.75).sqrt();
    eprintln!("one sample: {n4} of {n1} queries ask");
    assert!(0.25 * n1 > 4.0 * sd, "a test that could fail: {n1} queries");
    assert!((n4 - 0.25 * n1).abs() <= 4.0 * sd, "{n4} of {n1}");
    // The network's part: the same paths with both heads' last layers zeroed.
    let silent = zeroed_heads(&path);
    let mut z = Backend::Ort(OrtModel::load(&silent, 0).unwrap());
    std::fs::remove_file(&silent).ok();
    let direct = render(&s, &pyr, &mut z, &opts(1)).unwrap();
    let part = mean - direct.image.pixels.iter().map(lum).sum::<f64>() / n;
    eprintln!("the network's part: {part:.5} of {mean:.5}");
    assert!(0.75 * part > 8.0 * var.sqrt(), "a test that could fail");
    // Progressive: 1 + 4 samples are the 5 of one call, bit for bit.
    let mut progressive = |steps: &[u32]| {
        let mut sums = nimbus_rpnn::render::RpnnSums::new(s.camera.width, s.camera.height);
        let maj = nimbus_rpnn::render::majorants(&s);
        for &spp in steps {
            let step = RpnnOptions { spp, ..opts(4) };
            nimbus_rpnn::render::accumulate(&s, &pyr, &maj, &mut o, &step, &mut sums).unwrap();
        }
        sums.image().0.pixels
    };
    assert_eq!(progressive(&[1, 4]), progressive(&[5]));
}

/// A copy of the model at `path` whose heads' last layers (sun `sun.head.2`, sky
/// `head.layers.2`) are zero: it answers 0, and a render with it is the direct light alone.
fn zeroed_heads(path: &Path) -> std::path::PathBuf {
    use protobuf::Message;
    let bytes = std::fs::read(path).unwrap();
    let mut m = onnx_protobuf::ModelProto::parse_from_bytes(&bytes).unwrap();
    let mut zeroed = 0;
    for t in &mut m.graph.as_mut().unwrap().initializer {
        if t.name.starts_with("sun.head.2.") || t.name.starts_with("head.layers.2.") {
            t.raw_data.iter_mut().for_each(|b| *b = 0);
            t.float_data.iter_mut().for_each(|v| *v = 0.0);
            zeroed += 1;
        }
    }
    assert_eq!(zeroed, 4, "{}: the heads' last layers", path.display());
    let out = std::env::temp_dir().join(format!("nimbus-zeroed-heads-{}.onnx", std::process::id()));
    std::fs::write(&out, m.write_to_bytes().unwrap()).unwrap();
    out
}

#[test]
fn no_sky_means_no_sky_queries() {
    let s = scene(false, 16, 12, 5);
    let pyr = Pyramid::new(&s.volume).unwrap();
    let mut o = Backend::Ort(OrtModel::load(&data("rpnn-tiny.onnx"), 1).unwrap());
    let out = render(&s, &pyr, &mut o, &RpnnOptions::new(1, 1, 8)).unwrap();
    // One query (the sun) per camera ray that hits the cloud, never more.
    assert!(out.times.queries > 0 && out.times.queries <= 16 * 12);
    assert!(
        out.image
            .pixels
            .iter()
            .flatten()
            .all(|v| v.is_finite() && *v >= 0.0)
    );
}

/// A network that answers NaN or ∞ (weights no trained network has, which ONNX Runtime runs
/// unchecked: an int8 copy's are not checked on load) stops the render with an error naming
/// the model file; once such samples became black pixels without a word.
#[test]
fn a_nan_answer_is_an_error_naming_the_model() {
    use protobuf::Message;
    let bytes = std::fs::read(data("rpnn-tiny.onnx")).unwrap();
    let mut m = onnx_protobuf::ModelProto::parse_from_bytes(&bytes).unwrap();
    for t in &mut m.graph.as_mut().unwrap().initializer {
        // +∞ rather than NaN: the output's ReLU may turn a NaN into 0.
        if t.name == "head.2.bias" {
            t.raw_data[..4].copy_from_slice(&f32::INFINITY.to_le_bytes());
        }
    }
    let path = std::env::temp_dir().join(format!("nimbus-nan-answer-{}.onnx", std::process::id()));
    std::fs::write(&path, m.write_to_bytes().unwrap()).unwrap();
    let s = scene(false, 16, 12, 5);
    let pyr = Pyramid::new(&s.volume).unwrap();
    let mut o = Backend::Ort(OrtModel::load(&path, 1).unwrap());
    let e = render(&s, &pyr, &mut o, &RpnnOptions::new(1, 1, 8))
        .err()
        .expect("a NaN answer rendered")
        .to_string();
    std::fs::remove_file(&path).ok();
    assert!(
        e.contains("nimbus-nan-answer") && e.contains("answered inf"),
        "{e}"
    );
}

#[test]
fn shipped_model_against_the_path_tracer() {
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rpnn-hg.onnx");
    // A generated cumulus not in the training set (seed 901), sun and sky.
    let s = scene(true, 48, 32, 901);
    let pyr = Pyramid::new(&s.volume).unwrap();
    let mut o = Backend::Ort(OrtModel::load(&model, 0).unwrap());
    let rp = render(&s, &pyr, &mut o, &RpnnOptions::new(32, 1, 4)).unwrap();
    let pt = nimbus_trace::render(
        &s,
        &nimbus_trace::RenderOptions {
            spp: 512,
            seed: 2,
            progress: false,
        },
    );
    let m = nimbus_scene::compare::compare(&rp.image, &pt.image, None);
    eprintln!(
        "shipped RPNN vs path tracer: rel RMSE {:.3} (4x4 {:.3}), mean ratio {:.3}",
        m.rel_rmse_cloud, m.rel_rmse_cloud_4x4, m.mean_lum_ratio
    );
    assert_eq!(m.nonfinite, 0);
    // The network carries the multiple scattering: without it (single scattering only) the
    // cloud is far too dark.
    let mut single = s.clone();
    single.render.max_depth = Some(1);
    let ss = nimbus_trace::render(
        &single,
        &nimbus_trace::RenderOptions {
            spp: 128,
            seed: 2,
            progress: false,
        },
    );
    let m1 = nimbus_scene::compare::compare(&ss.image, &pt.image, None);
    eprintln!(
        "single scattering vs path tracer: mean ratio {:.3}",
        m1.mean_lum_ratio
    );
    assert!(m1.mean_lum_ratio < 1.0 - 2.0 * MEAN_BOUND);
    // Bounds from the measured bias of the shipped model (see models/rpnn-hg.md): the 4×4
    // error is network bias plus the noise of 32 spp RPNN / 512 spp PT (≈ 3 %).
    assert!(
        (m.mean_lum_ratio - 1.0).abs() < MEAN_BOUND,
        "{}",
        m.mean_lum_ratio
    );
    assert!(
        m.rel_rmse_cloud_4x4 < RMSE_BOUND,
        "{}",
        m.rel_rmse_cloud_4x4
    );
}

/// The shipped sky-head model (`models/rpnn-hg-sky.onnx`, one query per shading point for sun
/// and sky) against the path tracer on the unseen cumulus of
/// [`shipped_model_against_the_path_tracer`], under its constant sky and under a clear-sky
/// environment map (`SkyModel`, 256×128, projected texel by texel). Measured: 4×4 error 0.014
/// and 0.017, mean ratio 0.999 and 1.000 (the head on the last block alone: 0.014 and 0.028,
/// 1.000 and 1.002). Bounds from the bench suite's extremes over 18 sky
/// cases (BENCHMARKS.md): mean ratio within [0.985, 1.048], hence 5 %; 4×4 bias up to 0.055,
/// plus the noise of 32 spp RPNN and 512 spp path tracing (≈ 0.015), hence 0.07. The sky
/// lights most of this image (the sun alone gives a tenth of it), so a head that dropped the
/// sky's light or counted it twice would fail the mean bound many times over.
#[test]
fn shipped_sky_head_against_the_path_tracer() {
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rpnn-hg-sky.onnx");
    let constant = scene(true, 48, 32, 901);
    let dir = std::env::temp_dir().join(format!("nimbus-rpnn-sky-head-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let map = dir.join("sky.exr");
    // The map's glow where the scene's sun is ([0.5, 0.7, 0.5]).
    let sun = glam::DVec3::new(0.5, 0.7, 0.5).normalize();
    nimbus_rpnn::sky::SkyModel {
        sun_elevation_deg: sun.y.asin().to_degrees(),
        sun_azimuth_deg: sun.x.atan2(sun.z).to_degrees(),
        turbidity: 3.0,
        zenith: glam::DVec3::new(0.08, 0.16, 0.36),
        ground: glam::DVec3::new(0.06, 0.055, 0.05),
    }
    .latlong(256, 128)
    .write_exr(&map, None)
    .unwrap();
    let env = scene_with_sky(
        &format!("[sky]\nenvmap = \"{}\"", map.display()),
        48,
        32,
        901,
    );
    let pyr = Pyramid::new(&constant.volume).unwrap();
    let mut o = Backend::Ort(OrtModel::load(&model, 0).unwrap());
    // Without the sky (the same scene under its sun alone), to show the sky's share.
    let dark = nimbus_trace::render(
        &scene(false, 48, 32, 901),
        &nimbus_trace::RenderOptions {
            spp: 128,
            seed: 2,
            progress: false,
        },
    );
    for (name, s) in [("constant sky", &constant), ("environment map", &env)] {
        let opts = RpnnOptions {
            sky_sh: nimbus_rpnn::render::SkySh::of(s, 4, 64),
            ..RpnnOptions::new(32, 1, 4)
        };
        let rp = render(s, &pyr, &mut o, &opts).unwrap();
        let pt = nimbus_trace::render(
            s,
            &nimbus_trace::RenderOptions {
                spp: 512,
                seed: 2,
                progress: false,
            },
        );
        let m = nimbus_scene::compare::compare(&rp.image, &pt.image, None);
        let share =
            1.0 - nimbus_scene::compare::compare(&dark.image, &pt.image, None).mean_lum_ratio;
        eprintln!(
            "sky head, {name}: 4x4 {:.3}, mean ratio {:.3}; the sky's share of the image {share:.3}",
            m.rel_rmse_cloud_4x4, m.mean_lum_ratio
        );
        assert_eq!(m.nonfinite, 0);
        assert!(share > 0.5, "{name}: the sky is {share} of the image");
        assert!(
            (m.mean_lum_ratio - 1.0).abs() < 0.05,
            "{name}: {}",
            m.mean_lum_ratio
        );
        assert!(
            m.rel_rmse_cloud_4x4 < 0.07,
            "{name}: {}",
            m.rel_rmse_cloud_4x4
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Mean-luminance bias allowed for the shipped model on this unseen cloud (measured: see
/// models/rpnn-hg.md); the single-scattering image is 30 % too dark, far outside it.
const MEAN_BOUND: f64 = 0.06;
/// 4×4-block relative RMSE allowed: the model's bias plus the noise of 32 spp RPNN and 512 spp
/// path tracing (≈ 3 % at this size).
const RMSE_BOUND: f64 = 0.10;

/// The int8 copy of the shipped sky model (`--backend ort-int8`, beyond the paper) renders the
/// f32 model's image: the same paths (same seed), only the network's answers differ. On an
/// unseen cumulus under sun + sky at 32 spp the cloud pixels' mean luminance moves by less than
/// 0.5 % and its 4×4-block relative RMSE against the f32 image stays under 1 %: a tenth of the
/// shipped model's own bias on the bench suite (2–4 %), so int8 leaves the error a user sees
/// where it was (quantize.py: 0.6 % median per query). The int8 image is the same to the bit
/// on one core or three.
#[test]
fn int8_network_renders_the_f32_image() {
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rpnn-hg-sky.onnx");
    let s = scene(true, 48, 32, 901);
    let pyr = Pyramid::new(&s.volume).unwrap();
    let opts = RpnnOptions {
        sky_sh: nimbus_rpnn::render::SkySh::of(&s, 4, 64),
        ..RpnnOptions::new(32, 1, 4)
    };
    let mut f = Backend::Ort(OrtModel::load(&model, 0).unwrap());
    let mut q = Backend::Ort(OrtModel::load_int8(&model, 0).unwrap());
    assert_eq!(
        (f.name(), q.name()),
        ("ort", "ort int8"),
        "the summary tells them apart"
    );
    let a = render(&s, &pyr, &mut f, &opts).unwrap();
    let b = render(&s, &pyr, &mut q, &opts).unwrap();
    assert_eq!(a.times.queries, b.times.queries, "the same paths");
    // Cloud pixels: camera optical depth ≥ 0.1 (the sky's pixels are equal in both images).
    let cloud = nimbus_scene::tau::cloud_mask(&nimbus_scene::tau::optical_depth_image(&s));
    let m = nimbus_scene::compare::compare(&b.image, &a.image, Some(&cloud));
    eprintln!(
        "int8 against f32: 4x4 {:.4}, mean ratio {:.4}, cloud pixels {}",
        m.rel_rmse_cloud_4x4, m.mean_lum_ratio, m.cloud_pixels
    );
    assert!(m.cloud_pixels > 200, "{}", m.cloud_pixels);
    assert!(
        (m.mean_lum_ratio - 1.0).abs() < 0.005,
        "{}",
        m.mean_lum_ratio
    );
    assert!(m.rel_rmse_cloud_4x4 < 0.01, "{}", m.rel_rmse_cloud_4x4);
    assert!(m.rel_rmse_cloud_4x4 > 0.0, "int8 is not the f32 network");
    // The same int8 image on any number of cores: one session on one thread, or three
    // single-threaded workers (the runs the copy scales by are cut by the queries alone).
    for cores in [
        nimbus_rpnn::ort_backend::Cores::Pool(1),
        nimbus_rpnn::ort_backend::Cores::Workers(3),
    ] {
        let mut o = Backend::Ort(OrtModel::load_int8(&model, cores).unwrap());
        let c = render(&s, &pyr, &mut o, &opts).unwrap();
        assert!(c.image == b.image, "{cores:?}: another int8 image");
    }
}

/// With a sky head, a sky costs no query of its own: one query per shading point (the sun's,
/// whose output also carries the sky's transfer) where the paper's sampling asks 1 + sky_dirs;
/// the image is finite and non-negative, and a sun-only scene never asks the sky head.
#[test]
fn a_sky_head_answers_sun_and_sky_in_one_query() {
    let s = scene(true, 16, 12, 5);
    assert!(s.sky.is_some() && s.sun.is_some());
    let pyr = Pyramid::new(&s.volume).unwrap();
    let mut o = Backend::Ort(OrtModel::load(&data("rpnn-tiny-sky.onnx"), 1).unwrap());
    let head = RpnnOptions {
        sky_sh: nimbus_rpnn::render::SkySh::of(&s, 4, 16),
        ..RpnnOptions::new(1, 1, 8)
    };
    let out = render(&s, &pyr, &mut o, &head).unwrap();
    let dirs = render(
        &s,
        &pyr,
        &mut Backend::Ort(OrtModel::load(&data("rpnn-tiny.onnx"), 1).unwrap()),
        &RpnnOptions::new(1, 1, 8),
    )
    .unwrap();
    assert!(out.times.queries > 0);
    assert_eq!(
        dirs.times.queries,
        9 * out.times.queries,
        "1 + 8 queries per shading point"
    );
    assert!(
        out.image
            .pixels
            .iter()
            .flatten()
            .all(|v| v.is_finite() && *v >= 0.0)
    );
    // The sky model without asking for the head (the paper's directions): its sky columns are
    // not read, and its sun column is the sun model's, so the image is the sun model's to the
    // bit.
    let plain = render(&s, &pyr, &mut o, &RpnnOptions::new(1, 1, 2)).unwrap();
    let sun_model = render(
        &s,
        &pyr,
        &mut Backend::Ort(OrtModel::load(&data("rpnn-tiny.onnx"), 1).unwrap()),
        &RpnnOptions::new(1, 1, 2),
    )
    .unwrap();
    assert_eq!(plain.image.pixels, sun_model.image.pixels);
    // Any other width is refused by name.
    let e = render(
        &s,
        &pyr,
        &mut o,
        &RpnnOptions {
            sun_outputs: 3,
            ..RpnnOptions::new(1, 1, 2)
        },
    )
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("26 values per query, expected 3"), "{e}");
}

/// Traced bounces are unbiased: with the network's last layer zeroed (it predicts no multiple
/// scattering at all), RPNN with k traced bounces is the path tracer limited to k + 1
/// scattering events, whose light it then computes by Monte Carlo at every vertex. Checked for
/// k = 0 and 2 at albedo 0.7, under the sun alone (a sky's single scattering would dominate the
/// cloud and hide a wrong vertex) and under sun + sky, on the mean luminance of the cloud's
/// pixels (camera optical depth ≥ 0.1).
#[test]
fn traced_bounces_match_the_path_tracer_of_as_many_events() {
    let Some(gpu) =
        nimbus_gpu::testing::gpu("render::traced_bounces_match_the_path_tracer_of_as_many_events")
    else {
        return;
    };
    // The tiny test model, zeroed: only the Monte Carlo vertices are left.
    let mut model = Rpnn::load(&data("rpnn-tiny.onnx")).unwrap();
    let last = model.head.last_mut().unwrap();
    last.w.iter_mut().for_each(|v| *v = 0.0);
    last.b.iter_mut().for_each(|v| *v = 0.0);
    // More bounces than the renderer takes: refused by name, before anything is rendered.
    {
        let s = scene(false, 4, 3, 7);
        let pyr = Pyramid::new(&s.volume).unwrap();
        let mut g = Backend::Wgpu(Box::new(GpuRpnn::new(&gpu, &pyr, &model, 64).unwrap()));
        let opts = RpnnOptions {
            traced_bounces: nimbus_rpnn::render::MAX_TRACED_BOUNCES + 1,
            ..RpnnOptions::new(1, 1, 1)
        };
        let e = render(&s, &pyr, &mut g, &opts).err().expect("refused");
        assert!(e.to_string().contains("traced bounces"), "{e}");
    }
    for sky in [false, true] {
        let mut s = scene(sky, 12, 8, 7);
        // An albedo well below 1: a vertex's albedo counted once too often or too few times
        // moves the image by 30 %.
        s.medium.albedo = 0.7;
        // A milder lobe than the clouds' g = 0.857: next-event estimation at later vertices
        // then has no heavy tail (a path along the sun meets a phase peak of 8 × the mean),
        // and the means converge in a test's samples. The zeroed network does not mind.
        s.medium.phase = nimbus_scene::Phase::HenyeyGreenstein(
            nimbus_scene::phase::HenyeyGreenstein::new(0.5).unwrap(),
        );
        let pyr = Pyramid::new(&s.volume).unwrap();
        let cloud = nimbus_scene::tau::cloud_mask(&nimbus_scene::tau::optical_depth_image(&s));
        assert!(cloud.iter().filter(|c| **c).count() >= 30);
        let mut g = Backend::Wgpu(Box::new(GpuRpnn::new(&gpu, &pyr, &model, 4096).unwrap()));
        let pt_of = |depth: Option<u32>| {
            let mut limited = s.clone();
            limited.render.max_depth = depth;
            nimbus_trace::render(
                &limited,
                &nimbus_trace::RenderOptions {
                    spp: 8192,
                    seed: 2,
                    progress: false,
                },
            )
            .image
        };
        let full = pt_of(None);
        for k in [0u32, 2] {
            let opts = RpnnOptions {
                traced_bounces: k,
                ..RpnnOptions::new(1024, 1, 1)
            };
            let rp = render(&s, &pyr, &mut g, &opts).unwrap();
            let m = nimbus_scene::compare::compare(&rp.image, &pt_of(Some(k + 1)), Some(&cloud));
            let mf = nimbus_scene::compare::compare(&rp.image, &full, Some(&cloud));
            eprintln!(
                "sky {sky}, k = {k}: against the path tracer of {} events: mean ratio {:.4}; \
                 against the unlimited one: {:.4}",
                k + 1,
                m.mean_lum_ratio,
                mf.mean_lum_ratio
            );
            assert_eq!(m.nonfinite, 0);
            // See TRACED_MEAN_TOLERANCE.
            assert!(
                (m.mean_lum_ratio - 1.0).abs() < TRACED_MEAN_TOLERANCE,
                "sky {sky}, k = {k}: {}",
                m.mean_lum_ratio
            );
            // The limit is what is matched: the unlimited path tracer is brighter.
            assert!(
                mf.mean_lum_ratio < 1.0 - 2.0 * TRACED_MEAN_TOLERANCE,
                "sky {sky}, k = {k}: {}",
                mf.mean_lum_ratio
            );
        }
    }
}

/// Mean-luminance tolerance of the traced-bounce test: 1 024 RPNN against 8 192 path-traced
/// samples over the cloud's pixels of a 12×8 image read 0.986–1.000 (seeded; with the network
/// zeroed the numbers do not depend on the GPU). A vertex too many (the next order: ≥ 10 % of
/// the image here), one too few, or an albedo of 0.7 counted once too often or too few times
/// moves the mean by more.
const TRACED_MEAN_TOLERANCE: f64 = 0.03;
