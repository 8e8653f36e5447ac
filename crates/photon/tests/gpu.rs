//! Photon mapping on the GPU (Mesa lavapipe on CI): GPU = CPU for the deterministic stages,
//! energy against an analytic slab, determinism, and agreement with the path tracer.

use std::path::Path;

use glam::{DVec3, Vec3, Vec4};
use nimbus_photon::{PhotonMapper, PmSettings, PmVariant, cpu};
use nimbus_scene::build::SceneBuilder;
use nimbus_scene::{Aabb, Camera, DensityGrid, Scene, Sky, Sun, Volume, generate};

use crate::common::small_cloud;

pub(crate) fn scene(
    volume: Volume,
    albedo: f64,
    g: f64,
    sun: Option<Sun>,
    sky: Option<Sky>,
    camera: Camera,
) -> Scene {
    let mut s = SceneBuilder::new(volume)
        .albedo(albedo)
        .hg(g)
        .camera(camera)
        .build()
        .unwrap();
    (s.sun, s.sky) = (sun, sky);
    s
}

#[test]
fn upsampling_and_raymarching_match_cpu() {
    for (noise, variant, other_readings, view) in [
        (0.0, PmVariant::Exact, false, true),
        (1.5, PmVariant::Exact, false, true),
        (0.0, PmVariant::Exact, false, false),
        (0.0, PmVariant::Elek2012, false, false),
        (0.0, PmVariant::Elek2012, true, false),
    ] {
        check_against_cpu(noise, variant, other_readings, view);
    }
}

/// Detail noise of `noise` voxels (0 = off); `other_readings`: the upsampling's alternative
/// readings of Elek §4.3 (mean attenuation, extrapolated g'); `view`: view-dependent words
/// (J then holds the in-scattering towards the camera; the lobes are still computed).
fn check_against_cpu(noise: f32, variant: PmVariant, other_readings: bool, view: bool) {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::check_against_cpu") else {
        return;
    };
    let s = small_cloud();
    let mut pm = PhotonMapper::new(
        &gpu,
        &s,
        PmSettings {
            variant,
            beams_per_frame: 4096,
            ring: 4,
            cache_res: Some([6, 5, 6]),
            detail_noise: noise,
            upsample_mean: other_readings,
            upsample_g_extrapolate: other_readings,
            view_dependent: Some(view),
            ..Default::default()
        },
    )
    .unwrap();
    let img = pm.render(&s.camera).unwrap();
    // The view-dependent words are in use exactly when asked for (after a converged ring).
    assert_eq!(pm.params.view_mode, if view { 2 } else { 0 });
    let total = pm.read_total().unwrap();
    let density = pm.read_density().unwrap();
    let j = pm.read_j().unwrap();
    let p = pm.params;
    // Sun transmittance: GPU vs CPU per voxel (exp of the same midpoint sums, f32 both sides).
    let t_sun = if variant == PmVariant::Exact {
        let t = pm.read_sun_transmittance().unwrap();
        assert_eq!(t.len(), density.len());
        for (i, &g) in t.iter().enumerate() {
            let c = cpu::sun_transmittance(&p, &density, i);
            assert!(
                (0.0..=1.0).contains(&g) && (g - c).abs() <= 1e-5,
                "voxel {i}: {g} vs {c}"
            );
        }
        // Some voxels are shadowed, some see the sun almost unattenuated.
        assert!(t.iter().any(|&v| v < 0.5) && t.iter().any(|&v| v > 0.9));
        t
    } else {
        vec![]
    };
    assert!(total.iter().any(|&v| v > 0));
    // J: GPU vs CPU reference, per voxel and component. f32 on both sides; transcendental
    // functions (exp, log) may differ in the last bits between lavapipe/LLVM and Rust's libm, so
    // the tolerance is 1e-4 of the component's largest magnitude.
    let cpu: Vec<[f32; 4]> = (0..j.len())
        .map(|i| cpu::upsample(&p, &density, &total, i))
        .collect();
    for k in 0..4 {
        let scale = cpu
            .iter()
            .map(|v| v[k].abs())
            .fold(0.0f32, f32::max)
            .max(1e-20);
        for (a, b) in j.iter().zip(&cpu) {
            assert!(
                (a[k] - b[k]).abs() <= 1e-4 * scale,
                "component {k}: GPU {} vs CPU {}",
                a[k],
                b[k]
            );
        }
    }
    // Coarse cells' flux lobes and their upsampling (the exact variant's lobe axes, low and
    // high orders apart): GPU vs CPU; a mean of unit vectors is never longer than 1.
    assert_eq!(p.lobe_axis, (variant == PmVariant::Exact) as u32);
    let cell_dirs = pm.read_cell_dirs().unwrap();
    assert_eq!(cell_dirs.len(), total.len() / cpu::CELL_WORDS);
    for (i, [lo, hi]) in cell_dirs.iter().enumerate() {
        let c = cpu::cells(&p, &density, &total, i);
        let cpu = [
            c.dir.extend(c.has_lo as u32 as f32),
            c.dir_hi.extend(c.sun_hi),
        ];
        for (g, c) in [lo, hi].into_iter().zip(cpu) {
            assert!(
                (*g - c).abs().max_element() <= 1e-5 * c.w.abs().max(1.0),
                "cell {i}: {g} vs {c}"
            );
            assert!(g.truncate().length() <= 1.0 + 1e-3, "cell {i}: {g}");
        }
        // (With the view words `sun` is the in-scattering towards the camera, not a fluence.)
        assert!(
            p.view_mode == 2 || c.sun_hi <= c.sun * (1.0 + 1e-6),
            "cell {i}"
        );
    }
    let dirs = if p.lobe_axis != 0 {
        assert_eq!(p.lobe_split, nimbus_photon::settings::DEFAULT_LOBE_SPLIT);
        let dirs = pm.read_j_dirs().unwrap();
        assert_eq!(dirs.len(), density.len());
        let hi_scale = j.iter().map(|v| v[0]).fold(0.0f32, f32::max);
        for (i, d) in dirs.iter().enumerate() {
            let c = cpu::upsample_dirs(&p, &density, &total, i);
            for k in 0..2 {
                let tol = Vec4::new(1e-4, 1e-4, 1e-4, 1e-4 * hi_scale.max(1e-20));
                assert!(
                    (d[k] - c[k]).abs().cmple(tol).all(),
                    "voxel {i}, lobe {k}: {} vs {}",
                    d[k],
                    c[k]
                );
            }
        }
        // Directions vary over the cloud (a single constant axis would not pass), and both
        // orders hold light.
        let sun_prop = -Vec3::from_array(p.sun_dir);
        assert!(dirs.iter().any(|d| {
            let v = d[0].truncate();
            v.length() > 0.1 && v.normalize().dot(sun_prop) < 0.8
        }));
        assert!(
            dirs.iter()
                .any(|d| d[0].w > 0.0 && d[1].truncate().length() > 0.0)
        );
        dirs
    } else {
        vec![]
    };
    // Image: GPU vs CPU ray marcher on the GPU's J.
    let scale = img
        .pixels
        .iter()
        .flatten()
        .fold(0.0f32, |m, v| m.max(v.abs()));
    for y in 0..img.height {
        for x in 0..img.width {
            let c = cpu::raymarch(&p, &density, &j, &t_sun, &dirs, x as u32, y as u32);
            let g = img.get(x, y);
            for k in 0..3 {
                assert!(
                    (g[k] - c[k]).abs() <= 1e-4 * scale,
                    "pixel {x},{y}: {} vs {}",
                    g[k],
                    c[k]
                );
            }
        }
    }
}

#[test]
fn same_seed_same_image() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::same_seed_same_image") else {
        return;
    };
    let s = small_cloud();
    let settings = PmSettings {
        beams_per_frame: 2048,
        ring: 3,
        cache_res: Some([6, 5, 6]),
        ..Default::default()
    };
    let a = PhotonMapper::new(&gpu, &s, settings.clone())
        .unwrap()
        .render(&s.camera)
        .unwrap();
    let b = PhotonMapper::new(&gpu, &s, settings.clone())
        .unwrap()
        .render(&s.camera)
        .unwrap();
    assert_eq!(a, b);
    let c = PhotonMapper::new(
        &gpu,
        &s,
        PmSettings {
            seed: 1,
            ..settings
        },
    )
    .unwrap()
    .render(&s.camera)
    .unwrap();
    assert_ne!(a, c);
}

/// Energy: a purely absorbing (albedo 0) homogeneous box lit along −z. Each deposit stands for
/// a path length 1/σ̄, so the deposits estimate ∫ Φ T ds = E A (1 − e^{−σL})/σ over the box,
/// A = face area. 2¹⁸ beams, of which ≈ 40 % hit the face: the standard error is ≈ 0.5 %;
/// tolerance 2.5 % (5σ).
#[test]
fn deposited_energy_matches_slab_solution() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::deposited_energy_matches_slab_solution") else {
        return;
    };
    let sigma = 2.0;
    let grid = DensityGrid::constant([8, 8, 8], 0.5).unwrap();
    let vol = Volume::new(
        grid,
        Aabb::new(DVec3::splat(-0.5), DVec3::splat(0.5)).unwrap(),
        2.0 * sigma,
    )
    .unwrap();
    let s = scene(
        vol,
        0.0,
        0.5,
        Some(Sun::new(DVec3::Z, DVec3::ONE, 0.0).unwrap()),
        None,
        Camera::new(DVec3::new(0.0, 0.0, 3.0), DVec3::ZERO, DVec3::Y, 30.0, 8, 8).unwrap(),
    );
    let settings = |variant| PmSettings {
        variant,
        beams_per_frame: 1 << 16,
        ring: 4,
        cache_res: Some([4, 4, 4]),
        ..Default::default()
    };
    // Exact single scattering: the cache holds only scattered light, and with albedo 0 nothing
    // scatters: no sun deposit at all.
    let mut pm = PhotonMapper::new(&gpu, &s, settings(PmVariant::Exact)).unwrap();
    pm.converge().unwrap();
    assert!(
        pm.read_total()
            .unwrap()
            .chunks(cpu::CELL_WORDS)
            .all(|c| c[0] == 0 && c[6] == 0)
    );
    // The paper's single cache deposits the unscattered beam: its sums are the estimator
    // checked here.
    let mut pm = PhotonMapper::new(&gpu, &s, settings(PmVariant::Elek2012)).unwrap();
    pm.converge().unwrap();
    let total = pm.read_total().unwrap();
    let w: f64 = total.chunks(cpu::CELL_WORDS).map(|c| c[0] as f64).sum();
    let (n_sun, _) = pm.ring_beams();
    let r = pm.params.bound_radius as f64;
    let deposited = w / nimbus_photon::mapper::W_SCALE / pm.params.sigma_max as f64
        * std::f64::consts::PI
        * r
        * r
        / n_sun as f64;
    let exact = 1.0 * (1.0 - (-sigma).exp()) / sigma;
    assert!(
        (deposited / exact - 1.0).abs() < 0.025,
        "deposited {deposited} vs exact {exact}"
    );
    // Beams never leave energy where there is no medium: no sky photons without a sky.
    assert!(total.chunks(cpu::CELL_WORDS).all(|c| c[1] == 0));
}

/// Half-resolution ray marching plus bilinear upscaling stays close to the full-resolution
/// image: mean luminance within 2 % (the cloud's silhouette is blurred, its energy kept).
#[test]
fn half_resolution_is_close_to_full() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::half_resolution_is_close_to_full") else {
        return;
    };
    let s = small_cloud();
    let mut pm = PhotonMapper::new(
        &gpu,
        &s,
        PmSettings {
            beams_per_frame: 4096,
            ring: 4,
            cache_res: Some([6, 5, 6]),
            ..Default::default()
        },
    )
    .unwrap();
    let full = pm.render(&s.camera).unwrap();
    let half = pm.raymarch_half(&s.camera).unwrap();
    assert_eq!((half.width, half.height), (full.width, full.height));
    let mean = |img: &nimbus_scene::Image| {
        (0..img.pixels.len())
            .map(|i| img.lum(i % img.width, i / img.width))
            .sum::<f64>()
            / img.pixels.len() as f64
    };
    let (a, b) = (mean(&full), mean(&half));
    assert!((a / b - 1.0).abs() < 0.02, "full {a} vs half {b}");
}

/// Workgroup-memory and global-atomic accumulation are the same integer sums: identical caches.
#[test]
fn shared_and_global_accumulation_agree_exactly() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::shared_and_global_accumulation_agree_exactly")
    else {
        return;
    };
    let s = small_cloud();
    let run = |force| {
        let mut pm = PhotonMapper::new(
            &gpu,
            &s,
            PmSettings {
                beams_per_frame: 4096,
                ring: 2,
                cache_res: Some([6, 5, 6]),
                force_global_atomics: force,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(pm.uses_shared_memory(), !force);
        pm.converge().unwrap();
        pm.read_total().unwrap()
    };
    assert_eq!(run(false), run(true));
}

/// Equal cache and density resolution: no filtering, J is the cache in physical units.
#[test]
fn equal_resolution_skips_the_filter() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::equal_resolution_skips_the_filter") else {
        return;
    };
    let res = [10, 8, 10];
    let grid = generate::generate(nimbus_scene::CloudKind::Cumulus, 4, res).unwrap();
    let (lo, hi) = generate::default_aabb(res);
    let s = scene(
        Volume::new(grid, Aabb::new(lo, hi).unwrap(), 10.0).unwrap(),
        1.0,
        0.8,
        Some(Sun::new(DVec3::Y, DVec3::ONE, 0.0).unwrap()),
        None,
        Camera::new(DVec3::new(0.0, 0.0, 3.0), DVec3::ZERO, DVec3::Y, 40.0, 8, 8).unwrap(),
    );
    let mut pm = PhotonMapper::new(
        &gpu,
        &s,
        PmSettings {
            beams_per_frame: 2048,
            ring: 2,
            cache_res: Some([10, 8, 10]),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(pm.params.filtered, 0);
    pm.converge().unwrap();
    pm.upsample();
    let (j, total) = (pm.read_j().unwrap(), pm.read_total().unwrap());
    for (i, v) in j.iter().enumerate() {
        let c = cpu::cells(&pm.params, &[], &total, i);
        assert_eq!(*v, [c.sun, c.sky, c.g, c.gamma]);
    }
}

/// The per-frame budget may change (Elek §4.1.1) without changing the energy: the ring
/// normalises by its total beam count. Alternating 8 192 / 24 576 beams and a constant 16 384
/// give the same total sun fluence: each ring holds 131 k beams; the total deposited by one beam
/// varies with a coefficient of variation of ≈ 3 (most beams miss the small cloud), so two rings
/// differ by ≈ 1.2 % (1σ); 5 % fails on any normalisation error of the budgets (which would be
/// ≥ 25 % here).
#[test]
fn varying_budget_keeps_energy() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::varying_budget_keeps_energy") else {
        return;
    };
    let s = small_cloud();
    let fluence = |budgets: &[u32], seed: u32| {
        let mut pm = PhotonMapper::new(
            &gpu,
            &s,
            PmSettings {
                ring: 8,
                cache_res: Some([6, 5, 6]),
                seed,
                // The fluence words (the view words share their normalisation: view.rs tests).
                view_dependent: Some(false),
                ..Default::default()
            },
        )
        .unwrap();
        for b in budgets {
            pm.trace_frame(Some(*b));
        }
        pm.upsample();
        let t = pm.read_total().unwrap();
        (0..t.len() / cpu::CELL_WORDS)
            .map(|i| cpu::cells(&pm.params, &[], &t, i).sun as f64)
            .sum::<f64>()
    };
    let a = fluence(&[8192, 24576, 8192, 24576, 8192, 24576, 8192, 24576], 1);
    let b = fluence(&[16384; 8], 2);
    assert!((a / b - 1.0).abs() < 0.05, "varying {a} vs constant {b}");
}

/// Sky-only white furnace: a non-absorbing cloud under a constant sky has radiance equal to the
/// sky everywhere, so the photon-mapped image must be uniform. Without the similarity switch
/// the image mean is within 1 % of the sky and the mean deviation below 1.5 % (photon noise of
/// the 6×5×6 cache, upsampling, the 2 % early exit; the worst pixel, at cache-cell edges, within
/// 8 %). With Elek's switch (σ' = σ√(1 − g), isotropic; `PmVariant::Elek2012`) the cloud
/// comes out brighter than the sky: the measured excess (≈ 2.4 %) is asserted to stay positive
/// and below 20 %, documenting the bias of that approximation. The corrected switch σ(1 − g)
/// of the default variant keeps the furnace within 1 % (seen: 0.9975).
#[test]
fn sky_only_furnace() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::sky_only_furnace") else {
        return;
    };
    let mut s = small_cloud();
    s.sun = None;
    s.sky = Some(Sky::Constant(DVec3::splat(0.5)));
    // Optically thick (density scale 80: ≈ 40 mean free paths across), so that beams scatter
    // more than the ≈ 19 bounces after which the similarity switch applies for g = 0.857.
    let grid = s.volume.grid().clone();
    s.volume = std::sync::Arc::new(Volume::new(grid, *s.volume.aabb(), 80.0).unwrap());
    let run = |t: f64, variant: PmVariant, view: bool| {
        let mut pm = PhotonMapper::new(
            &gpu,
            &s,
            PmSettings {
                variant,
                beams_per_frame: 16384,
                ring: 4,
                cache_res: Some([6, 5, 6]),
                similarity_t: t,
                view_dependent: Some(view),
                ..Default::default()
            },
        )
        .unwrap();
        let img = pm.render(&s.camera).unwrap();
        let lums: Vec<f64> = (0..img.pixels.len())
            .map(|i| img.lum(i % img.width, i / img.width) / 0.5)
            .collect();
        let worst = lums.iter().map(|v| (v - 1.0).abs()).fold(0.0, f64::max);
        let mean = lums.iter().sum::<f64>() / lums.len() as f64;
        let mad = lums.iter().map(|v| (v - 1.0).abs()).sum::<f64>() / lums.len() as f64;
        eprintln!(
            "similarity t = {t}: mean {mean:.4}, mean |deviation| {mad:.4}, worst {worst:.4}"
        );
        (worst, mean, mad)
    };
    let (worst, mean, mad) = run(0.0, PmVariant::Exact, false);
    assert!(
        (mean - 1.0).abs() < 0.01 && mad < 0.015 && worst < 0.08,
        "no similarity: {mean} {mad} {worst}"
    );
    let (worst, mean, mad) = run(0.05, PmVariant::Exact, false);
    assert!(
        (mean - 1.0).abs() < 0.01 && mad < 0.015 && worst < 0.08,
        "similarity σ(1 − g): {mean} {mad} {worst}"
    );
    // The view words (the default) estimate the same radiance with each deposit weighted by
    // its phase value towards the camera (up to HG(1) · 4π ≈ 90 × the isotropic weight at
    // g = 0.857): the mean is held as tightly, single pixels are noisier (seen: mean 0.993,
    // mean deviation 0.009, worst 0.139 on this 6×5×6 cache and ring of 4 × 16 384 beams).
    let (worst, mean, mad) = run(0.05, PmVariant::Exact, true);
    assert!(
        (mean - 1.0).abs() < 0.015 && mad < 0.02 && worst < 0.25,
        "view words: {mean} {mad} {worst}"
    );
    let (_, mean, _) = run(0.05, PmVariant::Elek2012, false);
    eprintln!("sky furnace with Elek's similarity switch: image mean / sky = {mean:.4}");
    assert!(
        mean > 1.0 && mean < 1.2,
        "similarity switch σ√(1 − g): mean {mean}"
    );
}

#[test]
fn settings_are_checked() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::settings_are_checked") else {
        return;
    };
    let s = small_cloud();
    let bad = |st: PmSettings| {
        PhotonMapper::new(&gpu, &s, st)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    };
    assert!(
        bad(PmSettings {
            ring: 0,
            ..Default::default()
        })
        .contains("ring")
    );
    assert!(
        bad(PmSettings {
            cache_res: Some([0, 4, 4]),
            ..Default::default()
        })
        .contains("cache_res")
    );
    assert!(
        bad(PmSettings {
            cache_res: Some([100, 4, 4]),
            ..Default::default()
        })
        .contains("cache_res")
    );
    let _ = Path::new(".");
}

/// Density-weighted deposits: the ray marcher's input J equals the CPU twin's (per-cell mean
/// density as divisor), and a homogeneous medium filling every cell is unaffected by the
/// weighting (σ(x)/σ̄ = 1 everywhere: the same sums, divisor 1).
#[test]
fn density_weighted_deposits_match_cpu_and_are_neutral_in_a_homogeneous_box() {
    let Some(gpu) = nimbus_gpu::testing::gpu(
        "gpu::density_weighted_deposits_match_cpu_and_are_neutral_in_a_homogeneous_box",
    ) else {
        return;
    };
    let s = small_cloud();
    let mut pm = PhotonMapper::new(
        &gpu,
        &s,
        PmSettings {
            variant: PmVariant::Exact,
            density_weighted: Some(true),
            beams_per_frame: 4096,
            ring: 4,
            cache_res: Some([6, 5, 6]),
            ..Default::default()
        },
    )
    .unwrap();
    pm.render(&s.camera).unwrap();
    let (total, density, j) = (
        pm.read_total().unwrap(),
        pm.read_density().unwrap(),
        pm.read_j().unwrap(),
    );
    let p = pm.params;
    let cpu: Vec<[f32; 4]> = (0..j.len())
        .map(|i| cpu::upsample(&p, &density, &total, i))
        .collect();
    let scale = cpu
        .iter()
        .map(|v| v[0].abs())
        .fold(0.0f32, f32::max)
        .max(1e-20);
    for (a, b) in j.iter().zip(&cpu) {
        assert!(
            (a[0] - b[0]).abs() <= 1e-4 * scale,
            "GPU {} vs CPU {}",
            a[0],
            b[0]
        );
    }
    // Homogeneous box: weighted and unweighted caches agree exactly (same random numbers,
    // weights σ/σ̄ = 1).
    let grid = DensityGrid::constant([8, 8, 8], 0.5).unwrap();
    let vol = Volume::new(
        grid,
        Aabb::new(DVec3::splat(-0.5), DVec3::splat(0.5)).unwrap(),
        6.0,
    )
    .unwrap();
    let h = scene(
        vol,
        0.9,
        0.5,
        Some(Sun::new(DVec3::Z, DVec3::ONE, 0.0).unwrap()),
        None,
        Camera::new(DVec3::new(0.0, 0.0, 3.0), DVec3::ZERO, DVec3::Y, 30.0, 8, 8).unwrap(),
    );
    let run = |dw| {
        let mut pm = PhotonMapper::new(
            &gpu,
            &h,
            PmSettings {
                variant: PmVariant::Exact,
                density_weighted: Some(dw),
                beams_per_frame: 4096,
                ring: 2,
                cache_res: Some([4, 4, 4]),
                ..Default::default()
            },
        )
        .unwrap();
        pm.render(&h.camera).unwrap();
        (pm.read_total().unwrap(), pm.read_j().unwrap())
    };
    let (ta, ja) = run(false);
    let (tb, jb) = run(true);
    assert_eq!(ta, tb);
    for (a, b) in ja.iter().zip(&jb) {
        assert!(
            (a[0] - b[0]).abs() <= 1e-5 * a[0].abs().max(1e-12),
            "{a:?} vs {b:?}"
        );
    }
}

/// Beam tracing and the ring update, GPU against their CPU twins (`cpu::trace`, `cpu::update`):
/// three frames into a ring of two on the small cloud, replayed on the CPU with the same seeds
/// and frame numbers, give the same ring total.
#[test]
fn tracing_and_ring_update_match_cpu() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::tracing_and_ring_update_match_cpu") else {
        return;
    };
    let s = small_cloud();
    let mut pm = PhotonMapper::new(
        &gpu,
        &s,
        PmSettings {
            beams_per_frame: 4096,
            ring: 2,
            cache_res: Some([6, 5, 6]),
            view_dependent: Some(true),
            ..Default::default()
        },
    )
    .unwrap();
    for _ in 0..3 {
        pm.trace_frame(None);
    }
    let gpu_total = pm.read_total().unwrap();
    let density = pm.read_density().unwrap();
    let words = gpu_total.len();
    let mut ring = vec![0u32; 2 * words];
    let mut total = vec![0u32; words];
    for frame in 0..3u32 {
        let p = nimbus_gpu::params::VolumeParams { frame, ..pm.params };
        let mut h = vec![0u32; words];
        for beam in 0..p.n_sun + p.n_sky {
            assert!(!cpu::trace(&p, &density, &[], beam, &mut h));
        }
        let slot = (frame as usize % 2) * words;
        for i in 0..words {
            assert!(!cpu::update(&h, &mut ring, &mut total, slot, i));
        }
    }
    assert!(pm.params.n_sun > 0 && pm.params.n_sky > 0);
    // Per word class (sun Σw, sky Σw, flux sums, orders, counts, high-order sums): the same
    // random numbers and the same f32 arithmetic; only ln/sin/cos come from different
    // libraries, so a beam may part from its twin after a last-ulp difference. On lavapipe
    // 1 976 of 1 980 words are identical and the worst class differs by 1.2e-7 in L1; the
    // bounds (1e-4 of each class's sum, 99 % identical words) leave room for other drivers'
    // transcendentals and still fail on any change of stream, order or arithmetic.
    let mut worst = 0.0f64;
    for k in 0..cpu::CELL_WORDS {
        let (mut diff, mut sum) = (0.0f64, 0.0f64);
        for c in 0..words / cpu::CELL_WORDS {
            let (a, b) = (
                gpu_total[c * cpu::CELL_WORDS + k] as f64,
                total[c * cpu::CELL_WORDS + k] as f64,
            );
            diff += (a - b).abs();
            sum += a;
        }
        assert!(sum > 0.0 || k == 0, "word {k}: nothing deposited");
        if sum > 0.0 {
            worst = worst.max(diff / sum);
        }
    }
    // Words 0–10 (fluences, flux, orders, counts); the view words 11 and 12 round a phase value
    // (a power and a square root, whose last bits may differ between libraries) per deposit,
    // so a few of them differ by a unit: they are held by the L1 bound alone.
    let fixed = |i: &usize| i % cpu::CELL_WORDS < 11;
    let (mut identical, mut compared) = (0, 0);
    for i in (0..words).filter(fixed) {
        compared += 1;
        identical += (gpu_total[i] == total[i]) as usize;
    }
    assert!(
        worst <= 1e-4 && identical * 100 >= compared * 99,
        "worst relative L1 over word classes {worst:.2e}; {identical} of {compared} words identical"
    );
    println!("trace twin: worst class L1 {worst:.2e}, {identical}/{compared} words 0–10 identical");
}
