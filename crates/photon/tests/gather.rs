//! Final gathering from the photon map (`mapper/gather.rs`, `shaders/lib/photon_gather_core.wgsl`)
//! on lavapipe or any GPU: the GPU against its CPU twin path by path, k = 0 against the ray
//! marcher, unbounded k against the path tracer on the refs scenes, and progressive sums that
//! stay unbiased under restarts, and a ring renewed while gathering.

use std::path::Path;

use glam::Vec3;
use nimbus_photon::mapper::{GatherSettings, SunShadow, Terminal};
use nimbus_photon::{PhotonMapper, PmSettings, cpu};
use nimbus_scene::{Image, Scene};

use crate::common::small_cloud;

fn lum(p: [f32; 3]) -> f64 {
    (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0
}

/// The photon map of `gather` on `scene`, its ring full and J upsampled.
fn mapper<'g>(
    gpu: &'g nimbus_gpu::Gpu,
    scene: &Scene,
    gather: &GatherSettings,
    seed: u32,
) -> PhotonMapper<'g> {
    let g = match &scene.medium.phase {
        nimbus_scene::Phase::HenyeyGreenstein(h) => h.g(),
        _ => 0.0,
    };
    let settings = gather.pm_settings(
        &PmSettings {
            seed,
            ..Default::default()
        },
        g,
    );
    let mut pm = PhotonMapper::new(gpu, scene, settings).unwrap();
    pm.set_view(scene.camera.origin);
    pm.converge().unwrap();
    pm.upsample();
    pm
}

/// One sample per pixel on the GPU equals its CPU twin path by path: the same random numbers
/// and f32 arithmetic. Transcendental functions (ln, exp, sin, cos) may differ in their last
/// bits between lavapipe/LLVM and Rust's libm, and a path whose free flight or phase sample
/// lands on the other side of a decision from then on takes another course: such pixels are
/// allowed, up to 3 % of them (seen: none in any of the four settings on lavapipe); every other
/// pixel agrees to 1e-4 of the image's largest value.
#[test]
fn gather_matches_the_cpu_twin_path_by_path() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gather::gather_matches_the_cpu_twin_path_by_path")
    else {
        return;
    };
    let s = small_cloud();
    let base = GatherSettings {
        ring: 4,
        beams: 4096,
        ..Default::default()
    };
    for gs in [
        GatherSettings { bounces: 0, ..base },
        GatherSettings { bounces: 1, ..base },
        GatherSettings {
            bounces: 2,
            terminal: Terminal::Lobes,
            ..base
        },
        GatherSettings {
            bounces: 1,
            shadow: SunShadow::Rays,
            ..base
        },
    ] {
        let mut pm = mapper(&gpu, &s, &gs, 7);
        let g = pm.gather_params(&gs);
        assert_eq!(g.view_words, (gs.terminal == Terminal::View) as u32);
        pm.gather(&s.camera, &gs, 1).unwrap();
        let (img, _) = pm.gather_image().unwrap();
        let p = pm.march_params();
        let density = pm.read_density().unwrap();
        let j = pm.read_j().unwrap();
        let t_sun = pm.read_sun_transmittance().unwrap();
        let dirs = pm.read_j_dirs().unwrap();
        let fill = pm.read_cell_fill().unwrap();
        let inp = cpu::GatherInputs {
            density: &density,
            cell_fill: &fill,
            j: &j,
            t_sun: &t_sun,
            j_dirs: &dirs,
        };
        let scale = img
            .pixels
            .iter()
            .flatten()
            .fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(scale > 0.0);
        let (mut parted, mut lit) = (0, 0);
        for y in 0..img.height {
            for x in 0..img.width {
                let c = cpu::gather_sample(&p, &g, &inp, x as u32, y as u32, g.sample);
                let gp = Vec3::from_array(img.get(x, y));
                lit += (c.max_element() > 0.0) as usize;
                if (gp - c).abs().max_element() > 1e-4 * scale {
                    parted += 1;
                }
            }
        }
        let n = img.width * img.height;
        eprintln!("{gs:?}: {parted} of {n} pixels part from the twin, {lit} lit");
        assert!(lit > n / 4, "{gs:?}: {lit} of {n} pixels lit");
        assert!(
            parted * 100 <= 3 * n,
            "{gs:?}: {parted} of {n} pixels differ"
        );
    }
}

/// With k = 0 the gather is a Monte Carlo estimate of the ray marcher's integral over the same
/// J and T_sun (the view-dependent words, at the camera ray's collision): their cloud means agree to
/// 2 % (the marcher stops at 2 % transmittance where the gather plays Russian roulette, and
/// samples pixel centres where the gather jitters: seen 0.17 %) and their 4×4 blocks to 3 %
/// relative RMSE (256 samples: the gather's noise and the pixel jitter, seen 0.9 %).
#[test]
fn k0_is_the_ray_marchers_estimate() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gather::k0_is_the_ray_marchers_estimate") else {
        return;
    };
    let s = small_cloud();
    let gs = GatherSettings {
        bounces: 0,
        ring: 8,
        beams: 8192,
        ..Default::default()
    };
    let mut pm = mapper(&gpu, &s, &gs, 3);
    assert!(pm.j_holds_view());
    let marched = pm.raymarch(&s.camera).unwrap();
    pm.gather(&s.camera, &gs, 256).unwrap();
    let (gathered, _) = pm.gather_image().unwrap();
    let (ratio, rmse) = block_agreement(&gathered, &marched);
    eprintln!("k = 0 against the ray marcher: mean ratio {ratio:.4}, 4×4 relative RMSE {rmse:.4}");
    assert!((ratio - 1.0).abs() < 0.02, "mean ratio {ratio}");
    assert!(rmse < 0.03, "4×4 relative RMSE {rmse}");
}

/// Mean over the image and relative RMSE of 4×4 block means of `a` against `b`, over blocks
/// whose mean is at least 5 % of the brightest block (the cloud).
fn block_agreement(a: &Image, b: &Image) -> (f64, f64) {
    let block = |img: &Image, bx: usize, by: usize| {
        let mut s = 0.0;
        for y in by * 4..by * 4 + 4 {
            for x in bx * 4..bx * 4 + 4 {
                s += lum(img.get(x, y));
            }
        }
        s / 16.0
    };
    let (nx, ny) = (a.width / 4, a.height / 4);
    let blocks: Vec<(f64, f64)> = (0..ny)
        .flat_map(|by| (0..nx).map(move |bx| (bx, by)))
        .map(|(bx, by)| (block(a, bx, by), block(b, bx, by)))
        .collect();
    let top = blocks.iter().map(|b| b.1).fold(0.0, f64::max);
    let cloud: Vec<&(f64, f64)> = blocks.iter().filter(|b| b.1 >= 0.05 * top).collect();
    let ratio = cloud.iter().map(|b| b.0).sum::<f64>() / cloud.iter().map(|b| b.1).sum::<f64>();
    let rmse = (cloud
        .iter()
        .map(|b| ((b.0 - b.1) / b.1).powi(2))
        .sum::<f64>()
        / cloud.len() as f64)
        .sqrt();
    (ratio, rmse)
}

/// The refs scene at a quarter of its pixels (the same view).
fn refs_scene(name: &str) -> Scene {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut s = Scene::load(root.join("scenes/refs").join(format!("{name}.toml"))).unwrap();
    s.camera = s.camera.with_size(48, 36).unwrap();
    s
}

/// With more bounces than any path takes and shadow rays, the gather is the path tracer (the
/// cache is never read): on the refs scenes its mean over the cloud equals the CPU path
/// tracer's within 4 standard errors of their difference, estimated from the per-pixel
/// variances of both images.
#[test]
fn unbounded_gather_is_the_path_tracer_on_the_refs_scenes() {
    let Some(gpu) =
        nimbus_gpu::testing::gpu("gather::unbounded_gather_is_the_path_tracer_on_the_refs_scenes")
    else {
        return;
    };
    for name in ["cumulus_side", "cube_iso"] {
        let s = refs_scene(name);
        let gs = GatherSettings {
            bounces: 1 << 20,
            shadow: SunShadow::Rays,
            ring: 2,
            beams: 1024,
            ..Default::default()
        };
        let mut pm = mapper(&gpu, &s, &gs, 11);
        pm.gather(&s.camera, &gs, 256).unwrap();
        let (img, var) = pm.gather_image().unwrap();
        let pt = nimbus_trace::render(
            &s,
            &nimbus_trace::RenderOptions {
                spp: 256,
                seed: 5,
                progress: false,
            },
        );
        let tau = nimbus_scene::tau::optical_depth_image(&s);
        let mask = nimbus_scene::tau::cloud_mask(&tau);
        let (mut a, mut b, mut va, mut vb, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (i, &m) in mask.iter().enumerate() {
            if m {
                a += lum(img.pixels[i]);
                b += lum(pt.image.pixels[i]);
                va += var[i] as f64;
                vb += pt.variance[i] as f64;
                n += 1.0;
            }
        }
        let se = (va + vb).sqrt();
        eprintln!(
            "{name}: gather {:.5} path tracer {:.5} (σ {:.5})",
            a / n,
            b / n,
            se / n
        );
        assert!(n > 100.0, "{name}: {n} cloud pixels");
        assert!(
            (a - b).abs() < 4.0 * se,
            "{name}: {} vs {} (σ {})",
            a / n,
            b / n,
            se / n
        );
    }
}

/// Restarting the running sums drops the samples and draws new ones: the mean of four restarted
/// runs of 16 samples agrees with one run of 64 within 4 standard errors over the cloud, and
/// the restarted images differ (each restart its own random numbers).
#[test]
fn restarts_keep_the_running_sums_unbiased() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gather::restarts_keep_the_running_sums_unbiased")
    else {
        return;
    };
    let s = small_cloud();
    let gs = GatherSettings {
        ring: 4,
        beams: 4096,
        ..Default::default()
    };
    let mut pm = mapper(&gpu, &s, &gs, 5);
    let mut runs = Vec::new();
    for _ in 0..4 {
        pm.gather_reset();
        pm.gather(&s.camera, &gs, 16).unwrap();
        assert_eq!(pm.gather_samples(), 16);
        runs.push(pm.gather_image().unwrap());
    }
    assert_ne!(runs[0].0.pixels, runs[1].0.pixels);
    pm.gather_reset();
    pm.gather(&s.camera, &gs, 64).unwrap();
    let (one, one_var) = pm.gather_image().unwrap();
    let (mut a, mut b, mut v) = (0.0, 0.0, 0.0);
    for (i, (px, pv)) in one.pixels.iter().zip(&one_var).enumerate() {
        let m = runs.iter().map(|r| lum(r.0.pixels[i])).sum::<f64>() / 4.0;
        let mv = runs.iter().map(|r| r.1[i] as f64).sum::<f64>() / 16.0;
        a += m;
        b += lum(*px);
        v += mv + *pv as f64;
    }
    assert!(b > 0.0);
    eprintln!("restarted {a:.4} one run {b:.4} σ {:.4}", v.sqrt());
    assert!(
        (a - b).abs() < 4.0 * v.sqrt(),
        "{a} vs {b} (σ {})",
        v.sqrt()
    );
}

/// A live view whose J changes every frame averages over the last few samples only: the sums'
/// weight stays at the window while the sample count grows.
#[test]
fn a_window_bounds_the_running_sums() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gather::a_window_bounds_the_running_sums") else {
        return;
    };
    let s = small_cloud();
    let gs = GatherSettings {
        ring: 2,
        beams: 1024,
        ..Default::default()
    };
    let mut pm = mapper(&gpu, &s, &gs, 5);
    for _ in 0..20 {
        pm.gather_window(&s.camera, &gs, 4).unwrap();
    }
    assert_eq!(pm.gather_samples(), 20);
    let (img, _) = pm.gather_image().unwrap();
    // Still the image's brightness, not 20/4 of it: compare with a plain 16-sample mean.
    pm.gather_reset();
    pm.gather(&s.camera, &gs, 16).unwrap();
    let (plain, _) = pm.gather_image().unwrap();
    let m = |i: &Image| i.pixels.iter().map(|p| lum(*p)).sum::<f64>();
    let r = m(&img) / m(&plain);
    eprintln!("windowed / plain mean {r:.4}");
    assert!((r - 1.0).abs() < 0.1, "{r}");
}

/// A ring renewed while gathering (`GatherSettings::ring_refresh`) averages the photon map's
/// noise, which a fixed ring keeps at any sample count. Two renders from independent rings
/// (seeds 1 and 2; 64 samples each; a ring of 4 × 1 024 beams, so the ring's noise dominates
/// the difference) are compared per 4×4 block: renewing the ring every 2 samples uses 35
/// generations instead of 4 (on lavapipe the difference fell from 0.30 to 0.046). The test
/// asks for 2×, far from both the fixed ring's 0.30 and the gather's own noise at 64 samples.
/// Each render's cloud mean is that of the fixed ring with the same seed within 10 % (seen:
/// 0.996 and 1.026; a fixed ring of 4 096 beams is itself off by a few per cent in mean).
#[test]
fn a_renewed_ring_averages_the_photon_maps_noise() {
    let Some(gpu) =
        nimbus_gpu::testing::gpu("gather::a_renewed_ring_averages_the_photon_maps_noise")
    else {
        return;
    };
    let s = small_cloud();
    let fixed = GatherSettings {
        ring: 4,
        beams: 1024,
        ..Default::default()
    };
    let renewed = GatherSettings {
        ring_refresh: 2,
        ..fixed
    };
    let render = |gs: &GatherSettings, seed: u32| {
        let mut pm = mapper(&gpu, &s, gs, seed);
        let ring_s = pm.gather_refreshing(&s.camera, gs, 64).unwrap();
        assert_eq!(pm.gather_samples(), 64);
        assert_eq!(ring_s > 0.0, gs.ring_refresh > 0);
        assert_eq!(pm.frames(), 4 + (64 / 2 - 1) * (gs.ring_refresh > 0) as u32);
        pm.gather_image().unwrap().0
    };
    let (f1, f2) = (render(&fixed, 1), render(&fixed, 2));
    let (r1, r2) = (render(&renewed, 1), render(&renewed, 2));
    let (_, fixed_diff) = block_agreement(&f1, &f2);
    let (_, renewed_diff) = block_agreement(&r1, &r2);
    let (m1, _) = block_agreement(&r1, &f1);
    let (m2, _) = block_agreement(&r2, &f2);
    eprintln!(
        "4x4 difference of two rings: fixed {fixed_diff:.4}, renewed {renewed_diff:.4}; mean renewed/fixed {m1:.4} {m2:.4}"
    );
    assert!(
        renewed_diff * 2.0 < fixed_diff,
        "{renewed_diff} vs {fixed_diff}"
    );
    for m in [m1, m2] {
        assert!((m - 1.0).abs() < 0.1, "{m}");
    }
}
