//! The view-dependent cache words (`mapper/view.rs`): their normalisation against the
//! fluence words, and when the ray marcher may use them.

use glam::DVec3;
use nimbus_photon::{PhotonMapper, PmSettings, cpu};
use nimbus_scene::Scene;
use nimbus_scene::build::{self, SceneBuilder};

/// A small generated cumulus under sun and sky with phase `g`, seen from `origin`.
fn cloud(g: f64, origin: DVec3) -> Scene {
    SceneBuilder::new(
        build::generated(nimbus_scene::CloudKind::Cumulus, 3, [24, 18, 24], 20.0).unwrap(),
    )
    .hg(g)
    .sun(DVec3::new(1.0, 0.6, 0.3), DVec3::new(1.0, 0.9, 0.8))
    .sky(DVec3::new(0.1, 0.15, 0.3))
    .look(origin, DVec3::ZERO, 40.0, 32, 24)
    .build()
    .unwrap()
}

fn settings() -> PmSettings {
    PmSettings {
        beams_per_frame: 4096,
        ring: 4,
        cache_res: Some([6, 5, 6]),
        view_dependent: Some(true),
        ..Default::default()
    }
}

/// With isotropic scattering every deposit's phase value is 1/4π, so each cell's view words
/// are its sun and sky fluence words over 4π — up to the stochastic rounding of each deposit
/// (|error| < 1 unit per deposit, zero mean: the bound is 4σ of a sum of uniform errors, σ =
/// 0.29 √n, plus one unit).
#[test]
fn isotropic_view_words_are_the_fluence_over_four_pi() {
    let Some(gpu) =
        nimbus_gpu::testing::gpu("view::isotropic_view_words_are_the_fluence_over_four_pi")
    else {
        return;
    };
    let s = cloud(0.0, DVec3::new(0.3, 0.3, 3.0));
    let mut pm = PhotonMapper::new(&gpu, &s, settings()).unwrap();
    pm.converge().unwrap();
    let total = pm.read_total().unwrap();
    let four_pi = 4.0 * std::f64::consts::PI;
    let (mut cells_checked, mut sky_cells) = (0, 0);
    for c in total.chunks(cpu::CELL_WORDS) {
        let n = c[6] as f64; // deposits in the cell (sun and sky)
        let bound = 4.0 * 0.29 * n.sqrt() + 1.0;
        for (fluence, view) in [(c[0], c[11]), (c[1], c[12])] {
            // Each fluence deposit is floor(W w + u) with W w an integer here (albedo 1:
            // w = 1), so the fluence word is exact; the view word rounds W w / 4π.
            let want = fluence as f64 / four_pi;
            assert!(
                (view as f64 - want).abs() <= bound,
                "cell words {c:?}: view {view} vs {want:.1} ± {bound:.1}"
            );
        }
        cells_checked += (c[0] > 0) as usize;
        sky_cells += (c[1] > 0) as usize;
    }
    assert!(
        cells_checked > 20 && sky_cells > 20,
        "{cells_checked} / {sky_cells} cells lit"
    );
}

/// The ray marcher uses the view words only when every ring slot was traced close to the
/// camera: a jump of the camera falls back to the lobes until m frames were traced for it; a
/// small move (within the impostor tolerance, 5°) keeps them; rendering a distant camera from a
/// J made for another upsamples the lobes instead of showing the wrong view's light.
#[test]
fn view_words_follow_the_camera_through_the_ring() {
    let Some(gpu) = nimbus_gpu::testing::gpu("view::view_words_follow_the_camera_through_the_ring")
    else {
        return;
    };
    let a = DVec3::new(0.3, 0.3, 3.0);
    let s = cloud(0.857, a);
    let mut pm = PhotonMapper::new(&gpu, &s, settings()).unwrap();
    assert!(!pm.view_ready(), "an empty ring holds no view words");
    // One traced slot of four: the ring normalises by the beams it holds, so the words serve
    // from the first frame.
    pm.trace_frame(None);
    assert!(pm.view_ready());
    pm.render(&s.camera).unwrap();
    assert!(pm.view_ready());
    assert_eq!(pm.params.view_mode, 2);
    // 2° about the cloud's centre (the box is centred at the origin): still close.
    let near = glam::DQuat::from_rotation_y(2f64.to_radians()) * a;
    pm.set_view(near);
    assert!(pm.view_ready());
    // 60° away: the lobes until the ring was traced for it.
    let far = glam::DQuat::from_rotation_y(60f64.to_radians()) * a;
    pm.set_view(far);
    assert!(!pm.view_ready());
    for k in 0..4 {
        assert!(!pm.view_ready(), "ready after {k} of 4 frames");
        pm.trace_frame(None);
    }
    assert!(pm.view_ready());
    // J upsampled for `far`, rendered from `a`: upsampled again with the lobes.
    pm.upsample();
    assert_eq!(pm.params.view_mode, 2);
    let cam_a = s.camera.clone();
    let img = pm.raymarch(&cam_a).unwrap();
    assert_eq!(
        pm.params.view_mode, 1,
        "lobes for a camera the ring was not traced for"
    );
    assert!(img.pixels.iter().flatten().all(|v| v.is_finite()));
    // And a converged render from `a` again uses its own words.
    pm.render(&cam_a).unwrap();
    assert_eq!(pm.params.view_mode, 2);
}

/// Without light nothing is deposited, so the view words can never be ready: a converged
/// render must still end (after m frames) and show the black background.
#[test]
fn a_scene_without_light_converges() {
    let Some(gpu) = nimbus_gpu::testing::gpu("view::a_scene_without_light_converges") else {
        return;
    };
    let mut s = cloud(0.857, DVec3::new(0.3, 0.3, 3.0));
    (s.sun, s.sky) = (None, None);
    let mut pm = PhotonMapper::new(&gpu, &s, settings()).unwrap();
    let img = pm.render(&s.camera).unwrap();
    assert!(!pm.view_ready() && !pm.view_pending());
    assert_eq!(pm.frames(), 4);
    assert!(img.pixels.iter().flatten().all(|&v| v == 0.0));
}

/// A cache too large for the ring update's one-dimensional dispatch is a clear error, and a
/// non-finite view point is ignored (it could never be close to any slot's).
#[test]
fn oversized_cache_and_non_finite_view_points_are_refused() {
    let Some(gpu) =
        nimbus_gpu::testing::gpu("view::oversized_cache_and_non_finite_view_points_are_refused")
    else {
        return;
    };
    let big = SceneBuilder::new(
        build::generated(nimbus_scene::CloudKind::Cumulus, 3, [80, 80, 64], 20.0).unwrap(),
    )
    .sun(DVec3::new(1.0, 0.6, 0.3), DVec3::ONE)
    .look(DVec3::new(0.3, 0.3, 3.0), DVec3::ZERO, 40.0, 8, 8)
    .build()
    .unwrap();
    // 409 600 cells × 13 words > 65 535 workgroups × 64 threads.
    let e = PhotonMapper::new(
        &gpu,
        &big,
        PmSettings {
            cache_res: Some([80, 80, 64]),
            ring: 1,
            ..settings()
        },
    )
    .err()
    .expect("refused")
    .to_string();
    assert!(
        e.contains("cache_res") && e.contains("dispatch limit"),
        "{e}"
    );
    let s = cloud(0.857, DVec3::new(0.3, 0.3, 3.0));
    let mut pm = PhotonMapper::new(&gpu, &s, settings()).unwrap();
    let before = pm.params.view_origin;
    pm.set_view(DVec3::new(f64::NAN, 0.0, 1.0));
    assert_eq!(pm.params.view_origin, before);
    pm.render(&s.camera).unwrap();
    assert!(pm.j_holds_view());
}
