//! The sky's transfer labels (`nimbus_rpnn::sky`, `Estimate::sky`): a furnace identity, the
//! frame they live in, and their columns in a data set.

use glam::DVec3;
use nimbus_rpnn::data::datagen::{CloudData, LightSampling};
use nimbus_rpnn::data::dataset::{self, DatagenOptions};
use nimbus_rpnn::sky::{self, SH_COEFFS};
use nimbus_scene::{Medium, Phase};
use nimbus_trace::Pcg32;

use crate::datagen::sphere_volume;

/// A homogeneous sphere of radius 0.45 in a 24³ grid over [−0.5, 0.5]³, σ_t = `sigma`, albedo 1,
/// HG g = 0.5.
fn sphere(sigma: f64) -> CloudData {
    let vol = sphere_volume(sigma);
    let hg = nimbus_scene::phase::hg::HenyeyGreenstein::new(0.5).unwrap();
    CloudData::new(
        "sphere",
        vol,
        Medium::new(1.0, Phase::HenyeyGreenstein(hg)).unwrap(),
    )
    .unwrap()
    .with_sky_transfer(true)
}

const X: DVec3 = DVec3::new(0.1, -0.05, 0.2);
const VIEW: DVec3 = DVec3::new(0.0, 0.0, -1.0);

/// White furnace: a conservative cloud under a unit sky from every direction has unit radiance
/// everywhere, so at x the sky's indirect part (t₀₀ √(4π) for a constant sky) and its single
/// scattering (the mean transmittance to the box along phase-sampled directions) add up to 1:
/// 200 000 paths each (standard errors ≈ 1e-3), within 0.01.
#[test]
fn transfer_and_single_scattering_make_a_white_furnace() {
    let c = sphere(3.0);
    let e = c.estimate_to(X, VIEW, DVec3::Y, 200_000, 0.0, &mut Pcg32::new(1, 2));
    let t = e.sky.expect("sky transfer requested");
    let indirect = t[0] as f64 * (4.0 * std::f64::consts::PI).sqrt();
    // Single scattering of the sky: E[T(x, ω)] over ω from the phase function about VIEW.
    let (_, phase) = c.scene.medium.vertex(1);
    let majorants = nimbus_scene::MajorantGrid::with_block(&c.scene.volume, 8);
    let tracker = nimbus_trace::tracking::Tracker::new(&c.scene.volume, &majorants);
    let mut rng = Pcg32::new(3, 4);
    let n = 200_000;
    let (mut s, mut s2) = (0.0, 0.0);
    for _ in 0..n {
        let d = phase.sample(VIEW, rng.next2()).dir;
        let tr = match c.scene.volume.aabb().intersect(X, d) {
            Some((t0, t1)) => tracker.transmittance(X, d, t0, t1, 1.0, &mut rng),
            None => 1.0,
        };
        s += tr;
        s2 += tr * tr;
    }
    let direct = s / n as f64;
    let se = ((s2 / n as f64 - direct * direct) / n as f64).sqrt();
    let total = direct + indirect;
    eprintln!("furnace: direct {direct:.4} + indirect {indirect:.4} = {total:.4} (σ ≈ {se:.4})");
    assert!(indirect > 0.3 && direct > 0.1, "{direct} {indirect}");
    assert!((total - 1.0).abs() < 0.01, "{total}");
}

/// The transfer lives in the descriptor's frame: the same x and view with two light directions
/// (two frames rotated about the view) give coefficients that agree once both are rotated back
/// to the world, within the labels' noise (60 000 paths each; compared on the coefficients of
/// degree ≤ 2, relative to t₀₀: 0.03, seen 0.01).
#[test]
fn transfer_rotates_with_the_frame() {
    let c = sphere(6.0);
    let world = |to_light: DVec3, seed: u64| {
        let e = c.estimate_to(X, VIEW, to_light, 60_000, 0.0, &mut Pcg32::new(seed, 1));
        let t = e.sky.unwrap();
        let (ex, ey, ez) = nimbus_rpnn::descriptor::frame(VIEW.as_vec3(), to_light.as_vec3());
        let (ex, ey, ez) = (ex.as_dvec3(), ey.as_dvec3(), ez.as_dvec3());
        // Local → world: the frame whose columns are the rows of (ex ey ez).
        let rows = (
            DVec3::new(ex.x, ey.x, ez.x),
            DVec3::new(ex.y, ey.y, ez.y),
            DVec3::new(ex.z, ey.z, ez.z),
        );
        let mut c3 = [[0.0; 3]; SH_COEFFS];
        for (v, tj) in c3.iter_mut().zip(t) {
            *v = [tj as f64; 3];
        }
        sky::rotate_to_frame(&c3, rows)
    };
    let a = world(DVec3::new(0.6, 0.7, 0.2).normalize(), 5);
    let b = world(DVec3::new(-0.3, -0.2, 0.9).normalize(), 6);
    let scale = a[0][0];
    for j in 0..sky::coeffs(2) {
        assert!(
            (a[j][0] - b[j][0]).abs() < 0.03 * scale,
            "coefficient {j}: {} vs {}",
            a[j][0],
            b[j][0]
        );
    }
}

/// A data set with the sky's transfer has meta rows of 15 + 25 columns, named in its manifest,
/// and a resumed run keeps its shards (their converged counts read from the wider rows).
#[test]
fn sky_transfer_columns_in_a_data_set() {
    let d = std::env::temp_dir().join(format!("nimbus-sky-set-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let clouds = dataset::generated_set(5, 1);
    let opts = DatagenOptions {
        records: 4,
        val_records: 0,
        test_records: 0,
        shard_size: 4,
        seed: 1,
        max_samples: 256,
        samples: 256,
        eval_samples: 256,
        eval_noise: 0.0,
        light: LightSampling::Sphere,
        albedo: 1.0,
        phase: "hg".into(),
        progress: false,
        gpu: false,
        f16_descriptors: false,
        part: None,
        sky_transfer: true,
    };
    dataset::run(&clouds, &opts, &d).unwrap();
    let meta = std::fs::read(d.join("train_00000_meta.npy")).unwrap();
    let npy = npyz::NpyFile::new(&meta[..]).unwrap();
    assert_eq!(npy.shape(), &[4, 40]);
    let m: Vec<f32> = npy.into_vec().unwrap();
    // t₀₀ > 0 on every record (light leaves the cloud after scattering).
    assert!(
        m.chunks(40)
            .all(|r| r[15] > 0.0 && r.iter().all(|v| v.is_finite()))
    );
    let manifest = std::fs::read_to_string(d.join("manifest.json")).unwrap();
    assert!(manifest.contains("\"sky_sh_24\"") && manifest.contains("\"sky_transfer\": true"));
    let again = dataset::run(&clouds, &opts, &d).unwrap();
    assert_eq!(again.computed, 0, "the shard was kept");
    assert_eq!(
        std::fs::read_to_string(d.join("manifest.json")).unwrap(),
        manifest
    );
    std::fs::remove_dir_all(&d).ok();
}
