//! Photon mapping against the path tracer where the angular model matters (issue: "an angular
//! test the furnace cannot pass by construction"): a homogeneous sphere, HG g = 0.857, albedo 1,
//! diameter optical depth τ ∈ {5, 20, 80}, seen at scattering angles ≈ 166° (front-lit: the
//! camera beside the sun), 99° (side) and 48° (back-lit: the silver lining), sun only.
//!
//! One photon map per τ (the cache does not depend on the view) ray marched for the three
//! cameras; the path tracer renders each view. The figure of merit is the mean luminance over
//! the cloud pixels (camera optical depth ≥ 0.1), the quantity a user judges first.
//!
//! Measured on lavapipe (2026-12-02; `BENCHMARKS.md` "Lobe axes"), mean ratio pm / pt of the
//! exact variant with two flux lobes per cell (low orders < 4 and high orders apart; the
//! default) | one flux lobe | the paper's sun-aligned lobe:
//!
//! | τ | 166° (front) | 99° (side) | 48° (back) |
//! |---|---|---|---|
//! | 5 | 0.969 \| 0.848 \| 0.947 | 0.978 \| 0.917 \| 0.804 | 0.959 \| 1.059 \| 0.820 |
//! | 20 | 0.983 \| 0.765 \| 0.978 | 1.020 \| 0.960 \| 0.677 | 1.072 \| 1.210 \| 0.785 |
//! | 80 | 1.015 \| 0.879 \| 1.161 | 1.050 \| 1.047 \| 0.673 | 1.044 \| 1.170 \| 0.769 |
//!
//! Mean |ln ratio|: 0.034 | 0.127 | 0.215. One HG lobe with the right mean cosine has too
//! little light far from its axis and too much at mid-forward angles when a cell holds
//! forward-peaked low-order light and diffuse light at once; two lobes hold each apart. Noise:
//! the path tracer's mean over the ≈ 300 cloud pixels at 256 spp is within ≈ 2 %, the photon
//! map's (40 × 8 192 beams) ≈ 1 %; the bounds add ≈ 0.04 to the measured extremes for them, so
//! the test fails when the angular model gets worse, not on noise.

use glam::DVec3;
use nimbus_photon::{LobeAxis, PhotonMapper, PmSettings};
use nimbus_scene::{
    Camera, DensityGrid, Scene,
    build::{self, SceneBuilder},
};
use nimbus_scene::{compare, tau};
use nimbus_trace::{RenderOptions, render};

const N: usize = 24;

/// A sphere of unit density (smooth over one voxel) filling an N³ grid in [−1, 1]³, scaled so
/// that the optical depth along a diameter is `tau`.
fn sphere(tau: f64, camera: Camera) -> Scene {
    let mut data = vec![0.0f32; N * N * N];
    for z in 0..N {
        for y in 0..N {
            for x in 0..N {
                let p = [x, y, z].map(|i| (i as f64 + 0.5) / N as f64 * 2.0 - 1.0);
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                // 1 inside r < 0.85 − half a voxel, 0 outside r > 0.85 + half a voxel.
                let v = ((0.85 - r) * N as f64 / 2.0 + 0.5).clamp(0.0, 1.0);
                data[(z * N + y) * N + x] = v as f32;
            }
        }
    }
    let grid = DensityGrid::new([N; 3], data).unwrap();
    let volume = build::volume(grid, DVec3::splat(-1.0), DVec3::splat(1.0), tau / 1.7).unwrap();
    SceneBuilder::new(volume)
        .label("sphere")
        .sun(SUN, DVec3::ONE)
        .camera(camera)
        .build()
        .unwrap()
}

/// Unit vector towards the sun (from +x, a little above).
const SUN: DVec3 = DVec3::new(0.97, 0.242_535_625, 0.0);

/// A 24×24 camera at distance 4 whose direction from the sphere makes scattering angle `theta`
/// (degrees) with the sun's propagation direction −SUN.
fn camera(theta_deg: f64) -> Camera {
    let prop = -SUN.normalize();
    let side = DVec3::Z;
    let t = theta_deg.to_radians();
    let dir = prop * t.cos() + side * t.sin();
    Camera::new(dir * 4.0, DVec3::ZERO, DVec3::Y, 34.0, 24, 24).unwrap()
}

fn mean_ratio(pm: &nimbus_scene::Image, pt: &nimbus_scene::Image, mask: &[bool]) -> f64 {
    compare::compare(pm, pt, Some(mask)).mean_lum_ratio
}

#[test]
fn photon_mapping_follows_the_path_tracer_at_every_angle() {
    let Some(gpu) = nimbus_gpu::testing::gpu(
        "pm_angular::photon_mapping_follows_the_path_tracer_at_every_angle",
    ) else {
        return;
    };
    let views = [166.0, 99.0, 48.0];
    // (view-dependent words, lobe axis, split order): the default (view-dependent words), the
    // two flux lobes, one flux lobe, the sun axis.
    let configs = [
        (true, LobeAxis::Flux, None),
        (false, LobeAxis::Flux, None),
        (false, LobeAxis::Flux, Some(0)),
        (false, LobeAxis::Sun, None),
    ];
    let mut sums = [0.0f64; 4];
    let mut ratios = Vec::new();
    for tau_d in [5.0, 20.0, 80.0] {
        let scenes: Vec<Scene> = views.iter().map(|&v| sphere(tau_d, camera(v))).collect();
        let mut mappers: Vec<PhotonMapper> = configs
            .iter()
            .map(|&(view, axis, split)| {
                let settings = PmSettings {
                    view_dependent: Some(view),
                    lobe_axis: Some(axis),
                    lobe_split: split,
                    beams_per_frame: 8192,
                    ring: 40,
                    seed: 3,
                    ..Default::default()
                };
                let mut pm = PhotonMapper::new(&gpu, &scenes[0], settings).unwrap();
                pm.converge().unwrap();
                pm.upsample();
                pm
            })
            .collect();
        for (s, &view) in scenes.iter().zip(&views) {
            let mask = tau::cloud_mask(&tau::optical_depth_image(s));
            let pt = render(
                s,
                &RenderOptions {
                    spp: 256,
                    seed: 11,
                    progress: false,
                },
            );
            // The view-dependent words belong to a camera: retraced for each (the lobes'
            // cache serves every view).
            let pm0 = &mut mappers[0];
            pm0.set_view(s.camera.origin);
            pm0.converge().unwrap();
            pm0.upsample();
            assert!(pm0.view_ready());
            let r: Vec<f64> = mappers
                .iter_mut()
                .map(|pm| mean_ratio(&pm.raymarch(&s.camera).unwrap(), &pt.image, &mask))
                .collect();
            eprintln!(
                "tau {tau_d:>4}, scattering angle {view:>3}°: pm/pt view-dependent {:.3}, two flux lobes {:.3}, one flux lobe {:.3}, sun axis {:.3}",
                r[0], r[1], r[2], r[3]
            );
            for k in 0..4 {
                sums[k] += r[k].ln().abs();
            }
            ratios.push((tau_d, view, r[0], r[1]));
        }
    }
    let means = sums.map(|v| v / 9.0);
    eprintln!(
        "mean |ln ratio|: view-dependent {:.3}, two flux lobes {:.3}, one flux lobe {:.3}, sun axis {:.3}",
        means[0], means[1], means[2], means[3]
    );
    for (tau_d, view, r_view, r_lobes) in ratios {
        assert!(
            (0.90..=1.12).contains(&r_view) && (0.90..=1.12).contains(&r_lobes),
            "tau {tau_d}, {view}°: pm / pt = {r_view:.3} (view-dependent), {r_lobes:.3} (two flux lobes)"
        );
    }
    assert!(means[0] < 0.06, "mean |ln ratio| {:.3}", means[0]);
    assert!(means[1] < 0.06, "mean |ln ratio| {:.3}", means[1]);
    assert!(
        means[1] < means[2] && means[2] < means[3],
        "two flux lobes ({:.3}) must beat one ({:.3}), which must beat the sun axis ({:.3})",
        means[1],
        means[2],
        means[3]
    );
}

/// Front-lit (the camera beside the sun) the camera sees the light that flows back out of a
/// lit surface, which one HG lobe per cell and order group cannot hold alongside the light
/// flowing in (BENCHMARKS.md: the held-out stratus, mean 0.79 of the path tracer with the
/// lobes, 0.96 with the view words). A generated stratus at the bench's density and view, sun
/// only. Measured on lavapipe (2026-12-03): pm / pt = 0.902 with the view words, 0.796 with the
/// lobes (the cache at half the grid's resolution, 32×8×32 cells, is coarser in world units
/// than the bench stratus's: the rest is spatial). Bounds: the view words within [0.85, 1.1]
/// and closer to 1 than the lobes; noise: the path tracer's mean at 256 spp over the cloud
/// pixels is within ≈ 1 %, the photon map's (ring 50 × 8 192 beams) ≈ 1 %, so the test fails
/// when the view words lose half of their gain, not on noise.
#[test]
fn front_lit_view_words_follow_the_path_tracer() {
    let Some(gpu) =
        nimbus_gpu::testing::gpu("pm_angular::front_lit_view_words_follow_the_path_tracer")
    else {
        return;
    };
    let s = SceneBuilder::new(
        build::generated(nimbus_scene::CloudKind::Stratus, 9, [64, 16, 64], 23.56).unwrap(),
    )
    .sun(DVec3::new(0.25, 0.5, 1.0), DVec3::ONE)
    .look(DVec3::new(0.0, 1.25, 3.45), DVec3::ZERO, 38.0, 64, 36)
    .build()
    .unwrap();
    let mask = tau::cloud_mask(&tau::optical_depth_image(&s));
    let pt = render(
        &s,
        &RenderOptions {
            spp: 256,
            seed: 4,
            progress: false,
        },
    );
    let ratio = |view: bool| {
        let mut pm = PhotonMapper::new(
            &gpu,
            &s,
            PmSettings {
                view_dependent: Some(view),
                ring: 50,
                seed: 2,
                ..Default::default()
            },
        )
        .unwrap();
        let img = pm.render(&s.camera).unwrap();
        compare::compare(&img, &pt.image, Some(&mask)).mean_lum_ratio
    };
    let (view, lobes) = (ratio(true), ratio(false));
    eprintln!("front-lit stratus, pm / pt: view words {view:.3}, lobes {lobes:.3}");
    assert!((0.85..=1.1).contains(&view), "view words: {view:.3}");
    assert!(
        view.ln().abs() < lobes.ln().abs(),
        "view {view:.3}, lobes {lobes:.3}"
    );
}
