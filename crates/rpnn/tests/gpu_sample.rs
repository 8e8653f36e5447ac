//! The whole RPNN sample on the GPU (`nimbus_rpnn::gpu_sample`) against its CPU twin
//! (`nimbus_rpnn::render`, CPU shading with the same network): the same expectation under sun,
//! sun + constant sky, and a disc sun + an environment map through the sky head; progressive
//! steps equal one call; dense and brick-map densities give the same image; what it does not
//! model is refused by name.

use std::path::Path;

use glam::DVec3;
use nimbus_rpnn::Pyramid;
use nimbus_rpnn::gpu_mlp::{Precision, Tiles};
use nimbus_rpnn::gpu_sample::{GpuSampler, SamplerSettings, unsupported};
use nimbus_rpnn::model::Rpnn;
use nimbus_rpnn::ort_backend::OrtModel;
use nimbus_rpnn::render::{Backend, RpnnOptions, SkySh, render};
use nimbus_scene::{EnvMap, Image, Scene, Sky};
use nimbus_trace::gpu::DensityStorage;

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn scene(sun: &str, sky: &str) -> Scene {
    let text = format!(
        r#"
[volume]
generator = {{ kind = "cumulus", seed = 5, resolution = [40, 30, 40] }}
density_scale = 30.0
albedo = 0.9
phase = {{ kind = "hg", g = 0.857 }}
[sun]
direction = [-0.3, 0.5, -0.8]
{sun}
{sky}
[camera]
origin = [0.0, 0.2, 3.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
vfov_deg = 30.0
width = 24
height = 16
[render]
seed = 3
"#
    );
    Scene::from_toml_str(&text, Path::new("."), Path::new("gpu-sample.toml")).unwrap()
}

/// A lat-long map with a horizon gradient and a bright patch, so the sky's higher harmonics
/// (and with them the rotation into each query's frame) matter.
fn env_map() -> EnvMap {
    let (w, h) = (32, 16);
    let mut img = Image::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let v = (y as f32 + 0.5) / h as f32;
            let patch = if (4..9).contains(&x) && (3..6).contains(&y) {
                3.0
            } else {
                0.0
            };
            img.pixels[y * w + x] = [
                0.1 + 0.3 * v + patch,
                0.15 + 0.2 * v + patch,
                0.4 - 0.2 * v + 0.5 * patch,
            ];
        }
    }
    EnvMap::new(img, 1.0).unwrap()
}

fn shipped(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../models")
        .join(name)
}

/// (mean luminance over the image, variance of that mean) from an image and its per-pixel
/// variances of the mean luminance.
fn mean_and_var(img: &Image, var: &[f32]) -> (f64, f64) {
    let n = img.pixels.len() as f64;
    let m = img
        .pixels
        .iter()
        .map(|p| (p[0] + p[1] + p[2]) as f64 / 3.0)
        .sum::<f64>()
        / n;
    let v = var.iter().map(|&v| v as f64).sum::<f64>() / (n * n);
    (m, v)
}

/// `model` with both heads' last layers zeroed: it answers 0, so an image with it is the
/// direct light alone (the network's part is the difference).
fn zeroed_heads(model: &Rpnn) -> Rpnn {
    let mut silent = model.clone();
    for l in [silent.head.last_mut(), silent.sky_head.last_mut()]
        .into_iter()
        .flatten()
    {
        l.w.fill(0.0);
        l.b.fill(0.0);
    }
    silent
}

/// Largest |z| over 4×4 blocks of the difference of two independent estimates.
fn max_block_z(a: (&Image, &[f32]), b: (&Image, &[f32])) -> f64 {
    let (w, h) = (a.0.width, a.0.height);
    let mut worst: f64 = 0.0;
    for by in (0..h).step_by(4) {
        for bx in (0..w).step_by(4) {
            let (mut da, mut va, mut sa, mut n) = (0.0, 0.0, 0.0, 0.0);
            for y in by..(by + 4).min(h) {
                for x in bx..(bx + 4).min(w) {
                    let i = y * w + x;
                    let la = a.0.pixels[i].iter().map(|v| *v as f64).sum::<f64>() / 3.0;
                    let lb = b.0.pixels[i].iter().map(|v| *v as f64).sum::<f64>() / 3.0;
                    da += la - lb;
                    sa += la.abs();
                    va += a.1[i] as f64 + b.1[i] as f64;
                    n += 1.0;
                }
            }
            let _ = n;
            // The GPU's sums are f32: a block of sky alone (no noise, every sample the same
            // value) differs by their rounding, ≤ 1e-5 of the block for 64 additions of 24-bit
            // values; beyond that the difference is compared with the noise.
            if va > 0.0 && da.abs() > 1e-5 * sa {
                worst = worst.max(da.abs() / va.sqrt());
            }
        }
    }
    worst
}

/// GPU whole sample and CPU shading, each with its own random numbers, estimate the same image:
/// the image means agree within 4 standard errors and no 4×4 block differs by more than 4.5 of
/// its standard errors (24 blocks: a Gaussian exceeds 4.5σ with probability 7e-6 each). The
/// three lightings cover the delta sun, the constant sky through the sky head (band 0 of the
/// contraction), and a disc sun with an environment map (every band, and the map's texels
/// looked up on the GPU). A missing albedo factor (0.9) in either path would move the mean by
/// ≥ 10 % of the indirect part, far beyond these bounds.
#[test]
fn the_whole_sample_on_the_gpu_estimates_what_cpu_shading_does() {
    let Some(gpu) = nimbus_gpu::testing::gpu(
        "gpu_sample::the_whole_sample_on_the_gpu_estimates_what_cpu_shading_does",
    ) else {
        return;
    };
    let irr = "irradiance = [1.0, 0.9, 0.8]";
    // (name, scene, model, the paper's sky directions per collision: 0 = the sky head, the
    // contraction's degree)
    let sky = "[sky]\nradiance = [0.1, 0.15, 0.3]";
    let env = || {
        let mut s = scene("irradiance = [1.0, 0.9, 0.8]\nangular_radius_deg = 2.0", "");
        s.sky = Some(Sky::Env(env_map()));
        s
    };
    let cases: Vec<(&str, Scene, &str, u32, usize)> = vec![
        ("sun", scene(irr, ""), "rpnn-hg.onnx", 0, 4),
        ("sun + sky", scene(irr, sky), "rpnn-hg-sky.onnx", 0, 4),
        (
            "sun + sky in the paper's 4 directions",
            scene(irr, sky),
            "rpnn-hg.onnx",
            4,
            4,
        ),
        (
            "disc sun + environment map",
            env(),
            "rpnn-hg-sky.onnx",
            0,
            4,
        ),
        // `--sky-degree 2`: the GPU's contraction stops where the CPU's does.
        (
            "disc sun + environment map, degree 2",
            env(),
            "rpnn-hg-sky.onnx",
            0,
            2,
        ),
    ];
    // The GPU's and the CPU's image means per case, to tell the degrees apart.
    let mut means = std::collections::HashMap::new();
    for (name, s, model_file, dirs, degree) in cases {
        // Five queries per collision with the directions: half the samples.
        let spp = if dirs > 0 { 32 } else { 64 };
        let path = shipped(model_file);
        let model = Rpnn::load(&path).unwrap();
        let pyr = Pyramid::new(&s.volume).unwrap();
        let sky_sh = if dirs > 0 {
            None
        } else {
            SkySh::of(&s, degree, 32)
        };
        assert!(
            unsupported(&s, &model, sky_sh.as_ref(), dirs).is_none(),
            "{name}"
        );
        let settings = SamplerSettings {
            max_batch: 1 << 12,
            sky_dirs: dirs,
            ..Default::default()
        };
        let mut g =
            GpuSampler::with_settings(&gpu, &s, &pyr, &model, sky_sh.as_ref(), &settings).unwrap();
        g.reset(11);
        g.add(spp).unwrap();
        let (gi, gv) = g.image().unwrap();
        let opts = RpnnOptions {
            sky_sh: sky_sh.clone(),
            sun_outputs: model.outputs,
            ..RpnnOptions::new(spp, 12, dirs.max(1))
        };
        let mut ort = Backend::Ort(OrtModel::load(&path, 1).unwrap());
        let c = render(&s, &pyr, &mut ort, &opts).unwrap();
        let (mg, vg) = mean_and_var(&gi, &gv);
        let (mc, vc) = mean_and_var(&c.image, &c.variance);
        means.insert(name, (mg, mc));
        let z = (mg - mc).abs() / (vg + vc).sqrt();
        // The network's share: the same GPU sample with both heads' last layers zeroed
        // (direct light only, 16 spp) must lie ≥ 10 standard errors below, so the agreement
        // above is an agreement about the network's part.
        let silent = zeroed_heads(&model);
        let mut d =
            GpuSampler::with_settings(&gpu, &s, &pyr, &silent, sky_sh.as_ref(), &settings).unwrap();
        d.reset(13);
        d.add(16).unwrap();
        let (di, dv) = d.image().unwrap();
        let (md, vd) = mean_and_var(&di, &dv);
        assert!(
            mc - md >= 10.0 * (vc + vd).sqrt(),
            "{name}: the network adds {} to {md}",
            mc - md
        );
        eprintln!(
            "{name}: GPU {mg:.5} CPU {mc:.5} (z = {z:.2}), direct only {md:.5}; shade {:.0} ms, desc {:.0}, net {:.0}, resolve {:.0}, total {:.0}",
            g.times.shade_ms,
            g.times.descriptor_ms,
            g.times.inference_ms,
            g.times.resolve_ms,
            g.times.total_ms
        );
        assert!(
            mc.abs() > 10.0 * (vg + vc).sqrt(),
            "{name}: a signal to compare"
        );
        assert!(z <= 4.0, "{name}: image means {mg} vs {mc}, z = {z}");
        let bz = max_block_z((&gi, &gv), (&c.image, &c.variance));
        assert!(
            bz <= 4.5,
            "{name}: a 4x4 block differs by {bz} standard errors"
        );
        // 1 (+ the directions) queries per collision, as many collisions as the CPU's up to
        // noise (±4σ of a binomial, for each of the two).
        let per = 1.0 + dirs as f64;
        let q = g.queries().unwrap() as f64 / per;
        let qc = c.times.queries as f64 / per;
        let n = (s.camera.width * s.camera.height) as f64 * spp as f64;
        let sd = (qc * (1.0 - qc / n)).sqrt().max(1.0);
        assert!(
            (q - qc).abs() <= 4.0 * 2f64.sqrt() * sd,
            "{name}: {q} vs {qc} collisions"
        );
    }
    // Degree 2 drops light that degree 4 keeps (the map's bright patch). Each device renders
    // both degrees from the same paths (same seed), so the difference of its two means is
    // nearly free of their noise: measured 0.00146 on the GPU and 0.00141 on the CPU, 0.5 % of
    // the image. Both must be over 0.2 % of the image and agree within 25 % (the sky head's
    // queries differ between the devices' paths): a GPU that ignored the degree would differ
    // by nothing.
    let (g4, c4) = means["disc sun + environment map"];
    let (g2, c2) = means["disc sun + environment map, degree 2"];
    let (dg, dc) = (g4 - g2, c4 - c2);
    eprintln!("environment map, degree 4 − degree 2: GPU {dg:.5}, CPU {dc:.5}");
    assert!(dc > 0.002 * c4 && dg > 0.002 * g4, "GPU {dg}, CPU {dc}");
    assert!((dg / dc - 1.0).abs() < 0.25, "GPU {dg}, CPU {dc}");
}

/// One sample in every m asking the network (`query_every`) on the GPU: it estimates the
/// image of every sample asking (the GPU's own, and CPU shading's with the same m), and a
/// quarter of the queries are made. Sun + sky through the sky head, m = 4, 64 spp; bounds as
/// in [`the_whole_sample_on_the_gpu_estimates_what_cpu_shading_does`] (each image's variance
/// of the mean treats its samples as independent, which overstates the lattice's, so the z
/// bounds are conservative). A GPU that ignored m (asking in every sample with weight 4)
/// would be 3 × the network's part too bright, one that kept the weight 1 three quarters of
/// it too dark: that part (the heads' last layers zeroed) is asserted to exceed 8 standard
/// errors. Offsets are uniform per pixel: over the first sample of 8 seeds the pixels that
/// ask are a quarter of the collisions (binomial, within 4σ; a constant offset would give
/// all or none). Progressive steps give one call's image to the bit.
#[test]
fn one_query_in_every_m_samples_on_the_gpu() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu_sample::one_query_in_every_m_samples_on_the_gpu")
    else {
        return;
    };
    let s = scene(
        "irradiance = [1.0, 0.9, 0.8]",
        "[sky]\nradiance = [0.1, 0.15, 0.3]",
    );
    let path = shipped("rpnn-hg-sky.onnx");
    let model = Rpnn::load(&path).unwrap();
    let pyr = Pyramid::new(&s.volume).unwrap();
    let sky_sh = SkySh::of(&s, 4, 32);
    let spp = 64;
    // A sampler of `net` asking in one sample of `m`, in chunks of `batch` queries.
    let sampler = |net: &Rpnn, m: u32, batch: usize| {
        let settings = SamplerSettings {
            max_batch: batch,
            query_every: m,
            ..Default::default()
        };
        GpuSampler::with_settings(&gpu, &s, &pyr, net, sky_sh.as_ref(), &settings)
    };
    let gpu_run = |m: u32, seed: u64| {
        let mut g = sampler(&model, m, 1 << 12).unwrap();
        g.reset(seed);
        g.add(spp).unwrap();
        let (i, v) = g.image().unwrap();
        (i, v, g.queries().unwrap())
    };
    for bad in [0, nimbus_rpnn::render::MAX_QUERY_EVERY + 1] {
        let e = sampler(&model, bad, 1 << 12).err().expect("refused");
        assert!(e.to_string().contains("query period"), "{e}");
    }
    let (g4, v4, q4) = gpu_run(4, 11);
    let (g1, v1, q1) = gpu_run(1, 12);
    let opts = RpnnOptions {
        sky_sh: sky_sh.clone(),
        sun_outputs: model.outputs,
        query_every: 4,
        ..RpnnOptions::new(spp, 13, 1)
    };
    let mut ort = Backend::Ort(OrtModel::load(&path, 1).unwrap());
    let c4 = render(&s, &pyr, &mut ort, &opts).unwrap();
    let (m4, s4) = mean_and_var(&g4, &v4);
    for (name, img, var) in [
        ("the GPU, every sample", &g1, &v1),
        ("CPU shading, one in 4", &c4.image, &c4.variance),
    ] {
        let (m, sv) = mean_and_var(img, var);
        let z = (m4 - m).abs() / (s4 + sv).sqrt();
        eprintln!("GPU one in 4: {m4:.5}; {name}: {m:.5} (z = {z:.2})");
        assert!(
            m.abs() > 10.0 * (s4 + sv).sqrt(),
            "{name}: a signal to compare"
        );
        assert!(z <= 4.0, "{name}: image means {m4} vs {m}, z = {z}");
        let bz = max_block_z((&g4, &v4), (img, var));
        assert!(
            bz <= 4.5,
            "{name}: a 4x4 block differs by {bz} standard errors"
        );
    }
    // A quarter of the collisions ask: within 5 % of q1 / 4 (the collisions themselves vary
    // by ≈ 1 % between seeds at 64 spp).
    let r = q4 as f64 / q1 as f64;
    assert!((r - 0.25).abs() < 0.25 * 0.05, "{q4} of {q1}");
    // The network's part, against the noise of the comparisons above.
    let mut d = sampler(&zeroed_heads(&model), 1, 1 << 12).unwrap();
    d.reset(12);
    d.add(spp).unwrap();
    let (di, dv) = d.image().unwrap();
    let (md, _) = mean_and_var(&di, &dv);
    let (m1, s1) = mean_and_var(&g1, &v1);
    eprintln!("the network's part: {:.5} of {m1:.5}", m1 - md);
    assert!(
        0.75 * (m1 - md) > 8.0 * (s4 + s1).sqrt(),
        "a test that could fail"
    );
    // Per-pixel offsets: the first sample of 8 seeds, each on its own. The same seed gives
    // the same paths at any m, so the pixels that ask are a binomial draw of 1/4 from m = 1's
    // collisions: within 4 standard deviations per seed. An offset shared by the pixels (a
    // constant, or one drawn per seed) asks in all or none of them, 4·n₁/4 away.
    let first_sample = |m: u32| {
        let mut g = sampler(&model, m, 1 << 12).unwrap();
        (0..8u64)
            .map(|seed| {
                g.reset(100 + seed);
                g.add(1).unwrap();
                g.queries().unwrap() as f64
            })
            .collect::<Vec<_>>()
    };
    for (seed, (n1, n4)) in first_sample(1).into_iter().zip(first_sample(4)).enumerate() {
        let sd = (n1 * 0.25 * 0.75).sqrt();
        eprintln!("seed {seed}, first sample: {n4} of {n1} collisions ask");
        assert!(
            0.25 * n1 > 4.0 * sd,
            "a test that could fail: {n1} collisions"
        );
        assert!(
            (n4 - 0.25 * n1).abs() <= 4.0 * sd,
            "seed {seed}: {n4} of {n1}"
        );
    }
    // Progressive steps: 1 + 3 samples are the 4 of one call, bit for bit (chunks of 100).
    let mut g = sampler(&model, 4, 100).unwrap();
    g.reset(5);
    g.add(4).unwrap();
    let one = g.image().unwrap().0;
    g.reset(5);
    g.add(1).unwrap();
    g.add(3).unwrap();
    assert_eq!(one.pixels, g.image().unwrap().0.pixels);
}

/// Steps of samples give the image one call gives, bit for bit (sample indices continue); a
/// reset with the same seed repeats it; the brick-map density gives the same image as the
/// dense buffer; a moved sun takes effect without a new upload.
#[test]
fn gpu_samples_are_progressive_repeatable_and_storage_independent() {
    let Some(gpu) = nimbus_gpu::testing::gpu(
        "gpu_sample::gpu_samples_are_progressive_repeatable_and_storage_independent",
    ) else {
        return;
    };
    let mut s = scene(
        "irradiance = [1.0, 1.0, 1.0]",
        "[sky]\nradiance = [0.1, 0.15, 0.3]",
    );
    let model = Rpnn::load(&data("rpnn-tiny-sky.onnx")).unwrap();
    let pyr = Pyramid::new(&s.volume).unwrap();
    let sky_sh = SkySh::of(&s, 4, 16);
    // A batch of 100 queries: several chunks per sample, the last one partial.
    let mut g = GpuSampler::new(&gpu, &s, &pyr, &model, sky_sh.as_ref(), 100).unwrap();
    g.reset(5);
    g.add(4).unwrap();
    let (one, _) = g.image().unwrap();
    g.reset(5);
    g.add(1).unwrap();
    g.add(3).unwrap();
    assert_eq!(g.samples(), 4);
    let (steps, _) = g.image().unwrap();
    assert_eq!(one.pixels, steps.pixels);
    // The chunking does not show: batches of 4 096 (one chunk of 384 pixels), 190 and 383 (a
    // short last chunk, sharing one command buffer with the full ones) give the same image.
    for batch in [4096, 190, 383] {
        let mut c = GpuSampler::new(&gpu, &s, &pyr, &model, sky_sh.as_ref(), batch).unwrap();
        c.reset(5);
        c.add(4).unwrap();
        assert_eq!(c.image().unwrap().0.pixels, one.pixels, "batch {batch}");
    }
    // The 64 × 64 kernel (the default is 64 × 128, `one`'s): its chunkings agree bit for bit
    // too, and its image is the default's to f32 rounding (the same sums, which a compiler may
    // fuse into multiply-adds differently in the two kernels).
    assert_eq!(Tiles::default(), Tiles::Wide);
    let square = |batch| {
        let settings = SamplerSettings {
            max_batch: batch,
            tiles: Tiles::Square,
            ..Default::default()
        };
        let mut c =
            GpuSampler::with_settings(&gpu, &s, &pyr, &model, sky_sh.as_ref(), &settings).unwrap();
        c.reset(5);
        c.add(4).unwrap();
        c.image().unwrap().0
    };
    let sq = square(100);
    for batch in [4096, 190] {
        assert_eq!(square(batch).pixels, sq.pixels, "64 × 64, batch {batch}");
    }
    let top = one
        .pixels
        .iter()
        .flatten()
        .fold(0.0f32, |m, v| m.max(v.abs()));
    let diff = sq
        .pixels
        .iter()
        .flatten()
        .zip(one.pixels.iter().flatten())
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    eprintln!("64 × 64 against 64 × 128 tiles: largest difference {diff:e} of {top}");
    assert!(
        diff <= 1e-4 * top,
        "64 × 64 against 64 × 128: {diff} of {top}"
    );
    // The same with the paper's 4 sky directions (5 slots per collision: chunks of a fifth of
    // the batch), with the sun and without it (directions alone); a batch too small for one
    // collision's queries is refused.
    let plain = Rpnn::load(&data("rpnn-tiny.onnx")).unwrap();
    let mut no_sun = s.clone();
    no_sun.sun = None;
    for (what, sc) in [("sun + sky", &s), ("sky alone", &no_sun)] {
        let dirs = |batch| SamplerSettings {
            max_batch: batch,
            sky_dirs: 4,
            ..Default::default()
        };
        let image = |batch| {
            let mut c =
                GpuSampler::with_settings(&gpu, sc, &pyr, &plain, None, &dirs(batch)).unwrap();
            c.reset(5);
            c.add(4).unwrap();
            c.image().unwrap().0
        };
        let whole = image(4096);
        assert!(
            whole.pixels.iter().flatten().all(|v| v.is_finite()),
            "{what}"
        );
        for batch in [190, 383] {
            assert_eq!(image(batch).pixels, whole.pixels, "{what}, batch {batch}");
        }
        let e = GpuSampler::with_settings(&gpu, sc, &pyr, &plain, None, &dirs(4))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("at least 5 queries"), "{e}");
    }
    let bricks = SamplerSettings {
        max_batch: 100,
        storage: DensityStorage::Bricks { max_blocks: 4 },
        ..Default::default()
    };
    let mut b =
        GpuSampler::with_settings(&gpu, &s, &pyr, &model, sky_sh.as_ref(), &bricks).unwrap();
    b.reset(5);
    b.add(4).unwrap();
    assert_eq!(b.image().unwrap().0.pixels, one.pixels);
    // The sun below the horizon of the cloud's far side: another image, same sampler.
    s.sun.as_mut().unwrap().dir = DVec3::new(-0.5, 0.3, -0.8).normalize();
    g.sync(&s).unwrap();
    g.reset(5);
    g.add(4).unwrap();
    assert_ne!(g.image().unwrap().0.pixels, one.pixels);
}

/// What the GPU sample does not model is named: a tabulated phase function, the paper's sky
/// directions under an environment map (its importance sampling runs on the CPU), a sky with
/// neither the sky head nor a direction.
#[test]
fn unsupported_scenes_are_named() {
    let s = scene(
        "irradiance = [1.0, 1.0, 1.0]",
        "[sky]\nradiance = [0.1, 0.15, 0.3]",
    );
    let plain = Rpnn::load(&data("rpnn-tiny.onnx")).unwrap();
    assert!(unsupported(&s, &plain, None, 4).is_none());
    let why = unsupported(&s, &plain, None, 0).unwrap();
    assert!(why.contains("at least one sky direction"), "{why}");
    let mut env = scene("irradiance = [1.0, 1.0, 1.0]", "");
    env.sky = Some(Sky::Env(env_map()));
    let why = unsupported(&env, &plain, None, 4).unwrap();
    assert!(why.contains("environment map"), "{why}");
    let sky_model = Rpnn::load(&data("rpnn-tiny-sky.onnx")).unwrap();
    assert!(unsupported(&s, &sky_model, SkySh::of(&s, 4, 16).as_ref(), 0).is_none());
    assert!(unsupported(&env, &sky_model, SkySh::of(&env, 4, 16).as_ref(), 0).is_none());
    let mut mie = scene("irradiance = [1.0, 1.0, 1.0]", "");
    mie.medium.phase = nimbus_scene::Phase::Tabulated(std::sync::Arc::new(
        nimbus_scene::phase::TabulatedPhase::from_angles(&[0.0, 90.0, 180.0], &[2.0, 1.0, 0.5]),
    ));
    let why = unsupported(&mie, &plain, None, 4).unwrap();
    assert!(why.contains("tabulated"), "{why}");
}

/// The f16 network (weights and hidden activations in half floats, f32 accumulation) renders
/// the shared references' cumulus as the f32 network does: the same samples (same seed), so
/// the images differ only by the network's rounding. Over the cloud pixels (reference
/// luminance > 10⁻³ × max, `nimbus_scene::compare`) the relative RMSE is ≤ 0.2 % and the mean
/// ratio within 0.1 % of 1 (measured at 32 spp: 0.03 % and 1.0003; the f32 network's own error
/// against Mitsuba there is 3 % over 4×4 blocks, so f16 adds nothing a user could see).
#[test]
fn f16_network_renders_the_refs_cumulus_as_f32_does() {
    let Some(gpu) =
        nimbus_gpu::testing::gpu("gpu_sample::f16_network_renders_the_refs_cumulus_as_f32_does")
    else {
        return;
    };
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let s = Scene::load(root.join("scenes/refs/cumulus_side.toml")).unwrap();
    let model = Rpnn::load(&shipped("rpnn-hg.onnx")).unwrap();
    let pyr = Pyramid::new(&s.volume).unwrap();
    let image = |precision| {
        let settings = SamplerSettings {
            max_batch: 1 << 14,
            precision,
            ..Default::default()
        };
        let mut g = GpuSampler::with_settings(&gpu, &s, &pyr, &model, None, &settings).unwrap();
        g.reset(3);
        g.add(2).unwrap();
        g.image().unwrap().0
    };
    let (a, b) = (image(Precision::F32), image(Precision::F16));
    let m = nimbus_scene::compare::compare(&b, &a, None);
    assert!(m.cloud_pixels > 1000, "{m:?}");
    assert!(m.rel_rmse_cloud <= 2e-3, "{m:?}");
    assert!((m.mean_lum_ratio - 1.0).abs() <= 1e-3, "{m:?}");
    assert!(a.pixels != b.pixels, "f16 rounds");
}
