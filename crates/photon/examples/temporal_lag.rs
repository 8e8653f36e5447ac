//! Measures how far a photon map that follows a moving sun (0.5°/s, 30 frames/s) lags behind
//! the converged solution, at the paper's ring (m = 100, n_g = 8 192: 819 k beams), next to the
//! noise floor of two independent converged solutions (Elek 2012 §5, Fig. 11).
//!
//! `cargo run --release -p nimbus-photon --example temporal_lag`

use std::sync::Arc;

use glam::{DQuat, DVec3};
use nimbus_photon::animate::{AnimateOptions, DensitySequence, animate};
use nimbus_photon::{PhotonMapper, PmSettings};
use nimbus_scene::{
    Aabb, Camera, Image, Medium, Phase, RenderSettings, Scene, Sun, Volume, VolumeSource, generate,
    phase::HenyeyGreenstein,
};

fn scene(sun: DVec3) -> Scene {
    let res = [48, 36, 48];
    let grid = generate::generate(nimbus_scene::CloudKind::Cumulus, 3, res).expect("valid cloud");
    let (lo, hi) = generate::default_aabb(res);
    Scene {
        source: "temporal_lag".into(),
        volume: Arc::new(Volume::new(grid, Aabb::new(lo, hi).unwrap(), 30.0).unwrap()),
        volume_source: VolumeSource::Memory,
        medium: Medium::new(
            1.0,
            Phase::HenyeyGreenstein(HenyeyGreenstein::new(0.857).unwrap()),
        )
        .unwrap(),
        phase_desc: String::new(),
        sun: Some(Sun::new(sun, DVec3::ONE, 0.0).unwrap()),
        sky: None,
        camera: Camera::new(
            DVec3::new(0.3, 0.3, 3.0),
            DVec3::ZERO,
            DVec3::Y,
            40.0,
            96,
            72,
        )
        .unwrap(),
        render: RenderSettings::default(),
        atmosphere: None,
    }
}

/// (mean |a − b| / mean a over lit pixels, largest relative difference of a lit pixel).
fn diff(a: &Image, b: &Image) -> (f64, f64) {
    let max = (0..a.pixels.len())
        .map(|i| a.lum(i % a.width, i / a.width))
        .fold(0.0, f64::max);
    let (mut num, mut den, mut worst) = (0.0, 0.0, 0.0f64);
    for i in 0..a.pixels.len() {
        let (x, y) = (i % a.width, i / a.width);
        let (u, v) = (a.lum(x, y), b.lum(x, y));
        if u > 0.2 * max {
            num += (u - v).abs();
            den += u;
            worst = worst.max((u - v).abs() / u);
        }
    }
    (num / den, worst)
}

fn main() {
    let gpu = nimbus_gpu::Gpu::new().expect("a GPU adapter");
    let d0 = DVec3::new(1.0, 0.6, 0.3).normalize();
    let settings = PmSettings {
        ring: 100,
        beams_per_frame: 8192,
        ..Default::default()
    };
    let s = scene(d0);
    let frames = 300;
    let mut pm = PhotonMapper::new(&gpu, &s, settings.clone()).unwrap();
    let mut last = None;
    let opts = AnimateOptions {
        frames,
        sun_speed_deg_s: 0.5,
        fps: 30.0,
        density: DensitySequence::Static,
        impostors: None,
        half_res: false,
    };
    animate(&mut pm, &s, &opts, |img, _| {
        last = Some(img.clone());
        Ok(())
    })
    .unwrap();
    let angle = 0.5 * (frames - 1) as f64 / 30.0;
    let s_end = scene(DQuat::from_axis_angle(DVec3::Y, angle.to_radians()) * d0);
    let conv = |seed| {
        PhotonMapper::new(
            &gpu,
            &s_end,
            PmSettings {
                seed,
                ..settings.clone()
            },
        )
        .unwrap()
        .render(&s_end.camera)
        .unwrap()
    };
    let (a, b) = (conv(7), conv(8));
    let (lag, lag_max) = diff(&a, &last.unwrap());
    let (noise, noise_max) = diff(&a, &b);
    println!("device: {}", gpu.describe());
    println!(
        "moving sun vs converged: mean {:.2} %, max pixel {:.2} %",
        100.0 * lag,
        100.0 * lag_max
    );
    println!(
        "two converged solutions: mean {:.2} %, max pixel {:.2} %",
        100.0 * noise,
        100.0 * noise_max
    );
}
