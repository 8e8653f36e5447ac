//! Training-record generation: the L_i estimator and its stopping rule, determinism, resuming,
//! bad clouds.

use glam::DVec3;
use nimbus_rpnn::data::datagen::{CloudData, LightSampling};
use nimbus_rpnn::data::dataset::{self, DatagenOptions};
use nimbus_scene::{Aabb, DensityGrid, Medium, Phase, Volume};
use nimbus_trace::Pcg32;

/// A homogeneous sphere of radius 0.45 in a 24³ grid over [−0.5, 0.5]³, σ_t = 6, albedo 0.9,
/// isotropic phase (a cheap configuration whose estimates converge in ~10⁴ samples).
fn sphere() -> CloudData {
    CloudData::new(
        "sphere",
        sphere_volume(6.0),
        Medium::new(0.9, Phase::Isotropic).unwrap(),
    )
    .unwrap()
}

/// A sphere of radius 0.45 in a 24³ grid over [−0.5, 0.5]³ with σ_t = `sigma` inside.
pub(crate) fn sphere_volume(sigma: f64) -> Volume {
    let n = 24;
    let data: Vec<f32> = (0..n * n * n)
        .map(|i| {
            let p = DVec3::new((i % n) as f64, ((i / n) % n) as f64, (i / (n * n)) as f64);
            let q = (p + DVec3::splat(0.5)) / n as f64 - DVec3::splat(0.5);
            if q.length() < 0.45 { 1.0 } else { 0.0 }
        })
        .collect();
    Volume::new(
        DensityGrid::new([n, n, n], data).unwrap(),
        Aabb::new(DVec3::splat(-0.5), DVec3::splat(0.5)).unwrap(),
        sigma,
    )
    .unwrap()
}

const X: DVec3 = DVec3::new(0.1, -0.05, 0.2);
const VIEW: DVec3 = DVec3::new(0.0, 0.0, -1.0);

fn light() -> DVec3 {
    DVec3::new(0.6, 0.7, 0.2).normalize()
}

/// The ±2 % / 95 % estimate agrees with a run 100× longer, and the rule's interval covers the
/// long-run value in close to 95 % of repeated runs (40 runs: at least 80 %, 4.4 binomial σ
/// below 95 %, so a correct rule fails this with probability < 10⁻⁴).
#[test]
fn stopping_rule_and_coverage() {
    let c = sphere();
    let e = c.estimate(X, VIEW, light(), 1 << 20, &mut Pcg32::new(1, 1));
    let (est, n, converged, rel) = (e.mean, e.samples, e.converged, e.rel_ci);
    assert!(converged && rel <= 0.02, "n = {n}, rel = {rel}");
    // 100× longer, with a fixed sample count (no stopping rule).
    let e = c.estimate_to(X, VIEW, light(), 100 * n, 0.0, &mut Pcg32::new(2, 2));
    let (long, done, long_rel) = (e.mean, e.samples, e.rel_ci);
    assert!(done >= 100 * n && long_rel < 0.003);
    assert!(
        (est / long - 1.0).abs() < 0.025,
        "estimate {est} vs long run {long} ({n} vs {done} samples)"
    );
    let runs = 40;
    let mut covered = 0;
    for s in 0..runs {
        let e = c.estimate(X, VIEW, light(), 1 << 20, &mut Pcg32::new(100 + s, 7));
        let (m, conv) = (e.mean, e.converged);
        assert!(conv);
        covered += ((m / long - 1.0).abs() <= 0.02) as usize;
    }
    assert!(covered >= 32, "only {covered}/{runs} estimates within ±2 %");
}

/// L_i excludes the uncollided light: a purely absorbing medium (albedo 0) has no indirect
/// in-scattered radiance.
#[test]
fn indirect_only() {
    let c0 = sphere();
    let vol = (*c0.scene.volume).clone();
    let c = CloudData::new(
        "absorbing",
        vol,
        Medium::new(0.0, Phase::Isotropic).unwrap(),
    )
    .unwrap();
    let m = c
        .estimate(X, VIEW, light(), 4096, &mut Pcg32::new(3, 3))
        .mean;
    assert_eq!(m, 0.0);
}

fn opts(seed: u64) -> DatagenOptions {
    DatagenOptions {
        records: 6,
        val_records: 0,
        test_records: 2,
        shard_size: 4,
        seed,
        max_samples: 2048,
        samples: 0,
        eval_samples: 0,
        eval_noise: 0.0,
        light: LightSampling::Sphere,
        albedo: 1.0,
        phase: "hg".into(),
        progress: false,
        gpu: false,
        part: None,
        f16_descriptors: false,
        sky_transfer: false,
    }
}

fn tmp(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("nimbus-datagen-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn deterministic_and_resumable() {
    let set: Vec<_> = dataset::generated_set(5, 1)
        .into_iter()
        .map(|mut c| {
            // Small clouds keep the test quick.
            if let dataset::CloudSource::Generated { resolution, .. } = &mut c.source {
                *resolution = [24, 18, 24];
            }
            c
        })
        .collect();
    assert_eq!(set.iter().filter(|c| c.split == "test").count(), 1);
    let (a, b) = (tmp("a"), tmp("b"));
    let ra = dataset::run(&set, &opts(4), &a).unwrap();
    assert_eq!((ra.records, ra.computed), (8, 8));
    dataset::run(&set, &opts(4), &b).unwrap();
    let files = [
        "train_00000_x.npy",
        "train_00001_y.npy",
        "train_00001_meta.npy",
        "test_00000_x.npy",
    ];
    for f in files {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f}"
        );
    }
    // Resume: a removed shard is recomputed identically; the rest is kept.
    let before = std::fs::read(a.join("train_00001_y.npy")).unwrap();
    std::fs::remove_file(a.join("train_00001_y.npy")).unwrap();
    let rr = dataset::run(&set, &opts(4), &a).unwrap();
    assert_eq!((rr.records, rr.computed), (8, 2));
    assert_eq!(std::fs::read(a.join("train_00001_y.npy")).unwrap(), before);
    // Values are finite; the manifest names clouds, splits and the layout.
    let y: Vec<f32> = npyz::NpyFile::new(&std::fs::read(a.join("train_00000_y.npy")).unwrap()[..])
        .unwrap()
        .into_vec()
        .unwrap();
    assert!(y.iter().all(|v| v.is_finite() && *v >= 0.0));
    let m = std::fs::read_to_string(a.join("manifest.json")).unwrap();
    assert!(m.contains("\"descriptor_len\": 2251") && m.contains("\"split\": \"test\""));
    // Another seed gives other records.
    let c = tmp("c");
    dataset::run(&set, &opts(5), &c).unwrap();
    assert_ne!(
        std::fs::read(a.join("train_00000_y.npy")).unwrap(),
        std::fs::read(c.join("train_00000_y.npy")).unwrap()
    );
}

#[test]
fn bad_clouds_are_named() {
    let vol = Volume::new(
        DensityGrid::constant([4, 4, 4], 0.0).unwrap(),
        Aabb::new(DVec3::ZERO, DVec3::ONE).unwrap(),
        1.0,
    )
    .unwrap();
    let e = CloudData::new(
        "empty_cloud",
        vol,
        Medium::new(1.0, Phase::Isotropic).unwrap(),
    )
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("empty_cloud") && e.contains("non-zero"), "{e}");
    let e = dataset::folder_set(std::path::Path::new("/nonexistent/clouds"), 1.0)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("/nonexistent/clouds"), "{e}");
}

/// The GPU estimator (shaders/pt.wgsl, f32) and the CPU estimator estimate the same L_i: on the
/// sphere configuration, a fixed 2¹⁸-sample GPU estimate matches a 2¹⁸-sample CPU estimate within
/// 4.5 combined standard errors, and the GPU's progressive rule converges.
#[test]
fn gpu_estimator_matches_cpu() {
    let c = sphere();
    let Some(gpu) = nimbus_gpu::testing::gpu("datagen::gpu_estimator_matches_cpu") else {
        return;
    };
    let mut gpt = nimbus_trace::gpu::GpuPathTracer::new(&gpu, &c.scene).unwrap();
    let cfg = nimbus_trace::gpu::LiTask {
        x: X.as_vec3().extend(0.0).to_array(),
        view: VIEW.as_vec3().extend(0.0).to_array(),
        to_light: light().as_vec3().extend(0.0).to_array(),
    };
    let [s, s2, n] = gpt.indirect(&[cfg], 1 << 18, 0, 11).unwrap()[0];
    let g_mean = s / n;
    let g_var = (s2 / n - g_mean * g_mean) / n;
    let e = c.estimate_to(X, VIEW, light(), 1 << 18, 0.0, &mut Pcg32::new(5, 5));
    let (c_mean, cn, c_var) = (e.mean, e.samples, e.var_mean);
    assert!(n >= (1 << 18) as f64 && cn >= 1 << 18);
    assert!(
        (g_mean - c_mean).abs() < 4.5 * (g_var + c_var).sqrt(),
        "GPU {g_mean} vs CPU {c_mean}"
    );
    let est =
        nimbus_rpnn::data::datagen::estimate_gpu(&mut gpt, &[(X, VIEW, light())], 1 << 20, 0.02, 3)
            .unwrap();
    assert!(
        est[0].converged && est[0].rel_ci <= 0.02 && (est[0].mean / c_mean - 1.0).abs() < 0.03,
        "{:?}",
        est[0]
    );
    // Fixed count on the GPU: exactly the requested samples, not converged by definition.
    let fixed =
        nimbus_rpnn::data::datagen::estimate_gpu(&mut gpt, &[(X, VIEW, light())], 5000, 0.0, 4)
            .unwrap();
    assert_eq!((fixed[0].samples, fixed[0].converged), (5000, false));
}

/// A cloud so thin that no free flight ends inside it: a clear error after the try limit, not a
/// hang.
#[test]
fn cloud_that_is_never_hit() {
    let vol = Volume::new(
        DensityGrid::constant([4, 4, 4], 1.0).unwrap(),
        Aabb::new(DVec3::ZERO, DVec3::ONE).unwrap(),
        1e-12,
    )
    .unwrap();
    let c = CloudData::new("ghost", vol, Medium::new(1.0, Phase::Isotropic).unwrap()).unwrap();
    let e = c
        .sample_position(&mut Pcg32::new(1, 1))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("ghost") && e.contains("no ray entered"), "{e}");
}

/// Fixed-count estimates carry no stopping-rule bias: the mean of 200 independent 64-sample
/// estimates agrees with a 2²⁰-sample run, and their stored variance matches the spread between
/// them.
#[test]
fn fixed_count_estimates_are_unbiased_with_honest_variance() {
    let c = sphere();
    let long = c.estimate_to(X, VIEW, light(), 1 << 20, 0.0, &mut Pcg32::new(2, 2));
    let runs = 200;
    let est: Vec<_> = (0..runs)
        .map(|s| c.estimate_to(X, VIEW, light(), 64, 0.0, &mut Pcg32::new(900 + s, 3)))
        .collect();
    assert!(est.iter().all(|e| e.samples == 64 && !e.converged));
    let mean = est.iter().map(|e| e.mean).sum::<f64>() / runs as f64;
    let spread = est.iter().map(|e| (e.mean - mean).powi(2)).sum::<f64>() / (runs - 1) as f64;
    let stored = est.iter().map(|e| e.var_mean).sum::<f64>() / runs as f64;
    // 4.5 standard errors of the mean of 200 estimates (plus the long run's own error).
    let se = (spread / runs as f64 + long.var_mean).sqrt();
    assert!(
        (mean - long.mean).abs() < 4.5 * se,
        "mean of fixed-count estimates {mean} vs long run {} (se {se})",
        long.mean
    );
    // The average stored variance estimates the true variance of a 64-sample mean; with 200
    // runs the spread's own relative error is ≈ √(2/199) ≈ 10 % (more for a skewed
    // distribution), so 30 % allows for that.
    assert!(
        (stored / spread - 1.0).abs() < 0.3,
        "stored variance {stored} vs observed {spread}"
    );
}

/// `uniform-gamma` draws γ uniformly in [0, π] (10 bins within 5 σ of 1 000 each) and its
/// weights π sin γ / 2 average to 1 (∫₀^π (1/π)(π sin γ / 2) dγ = 1): the sphere's distribution
/// restored.
#[test]
fn uniform_gamma_light_sampling() {
    let mut rng = Pcg32::new(8, 8);
    let view = DVec3::new(0.3, -0.2, 0.9).normalize();
    let n = 10_000;
    let mut bins = [0usize; 10];
    let mut wsum = 0.0;
    for _ in 0..n {
        let l = LightSampling::UniformGamma.sample(view, rng.next2());
        assert!((l.length() - 1.0).abs() < 1e-9);
        let gamma = view.cross(l).length().atan2(view.dot(l));
        bins[((gamma / std::f64::consts::PI * 10.0) as usize).min(9)] += 1;
        wsum += LightSampling::UniformGamma.weight(view, l) as f64;
    }
    for b in bins {
        // Binomial σ = √(10 000 · 0.1 · 0.9) = 30.
        assert!((b as f64 - 1000.0).abs() < 150.0, "{bins:?}");
    }
    // The weight's standard deviation is ≈ 0.48, so the mean of 10⁴ has σ ≈ 0.005.
    assert!((wsum / n as f64 - 1.0).abs() < 0.025, "{}", wsum / n as f64);
    assert_eq!(LightSampling::Sphere.weight(view, view), 1.0);
}

/// A rerun in the same folder with different settings is refused, naming the setting; the
/// validation split comes from its own clouds.
#[test]
fn other_settings_refused_and_validation_split() {
    let set: Vec<_> = dataset::generated_set(5, 1)
        .into_iter()
        .map(|mut c| {
            if let dataset::CloudSource::Generated { resolution, .. } = &mut c.source {
                *resolution = [24, 18, 24];
            }
            c
        })
        .collect();
    assert_eq!(set[2].split, "val");
    let d = tmp("settings");
    let mut o = opts(1);
    o.records = 2;
    o.val_records = 2;
    o.test_records = 0;
    o.samples = 64;
    o.eval_samples = 256;
    let r = dataset::run(&set, &o, &d).unwrap();
    assert_eq!(r.records, 4);
    let meta: Vec<f32> =
        npyz::NpyFile::new(&std::fs::read(d.join("val_00000_meta.npy")).unwrap()[..])
            .unwrap()
            .into_vec()
            .unwrap();
    assert_eq!(meta.len(), 2 * dataset::META_COLUMNS);
    assert!(
        meta.chunks(dataset::META_COLUMNS)
            .all(|m| m[0] == 2.0 && m[10] == 256.0)
    );
    let mut other = o.clone();
    other.seed = 2;
    let e = dataset::run(&set, &other, &d).unwrap_err().to_string();
    assert!(
        e.contains("seed (was 1, now 2)") && e.contains("new --out"),
        "{e}"
    );
}

/// A second writer to the same folder is refused while the first holds the lock, naming the
/// holder; once the lock is released the folder can be used again.
#[test]
fn concurrent_writers_are_refused() {
    use std::io::Write;
    let d = tmp("lock");
    std::fs::create_dir_all(&d).unwrap();
    // Hold the lock as another process would.
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(true)
        .open(d.join(".lock"))
        .unwrap();
    f.try_lock().unwrap();
    write!(f, "4242").unwrap();
    let set: Vec<_> = dataset::generated_set(5, 1);
    let mut o = opts(1);
    o.records = 1;
    o.test_records = 0;
    let e = dataset::run(&set, &o, &d).unwrap_err().to_string();
    assert!(
        e.contains("process 4242") && e.contains("another --out"),
        "{e}"
    );
    f.unlock().unwrap();
    drop(f);
    let set: Vec<_> = set
        .into_iter()
        .map(|mut c| {
            if let dataset::CloudSource::Generated { resolution, .. } = &mut c.source {
                *resolution = [24, 18, 24];
            }
            c
        })
        .collect();
    o.max_samples = 256;
    assert_eq!(dataset::run(&set, &o, &d).unwrap().records, 1);
}

/// The small generated set of the tests above (5 clouds: 3 train, 1 validation, 1 test).
fn small_set() -> Vec<dataset::CloudSpec> {
    dataset::generated_set(5, 1)
        .into_iter()
        .map(|mut c| {
            if let dataset::CloudSource::Generated { resolution, .. } = &mut c.source {
                *resolution = [24, 18, 24];
            }
            c
        })
        .collect()
}

#[test]
fn parts_merge_into_the_single_run() {
    use nimbus_rpnn::data::dataset::Part;
    use nimbus_rpnn::data::shards::merge;
    let set = small_set();
    let o = |part: Option<Part>| DatagenOptions {
        records: 7,
        val_records: 3,
        test_records: 3,
        shard_size: 2,
        samples: 32,
        eval_samples: 64,
        part,
        ..opts(9)
    };
    let single = tmp("single");
    dataset::run(&set, &o(None), &single).unwrap();
    // Three parts of 4 + 2 + 2 = 8 shards (global index mod 3).
    let parts: Vec<_> = (1..=3).map(|k| tmp(&format!("part{k}"))).collect();
    for (k, dir) in parts.iter().enumerate() {
        let part = Part {
            index: k + 1,
            count: 3,
        };
        dataset::run(&set, &o(Some(part)), dir).unwrap();
    }
    let merged = tmp("merged");
    let m = merge(&parts, &merged).unwrap();
    assert_eq!((m.parts, m.shards, m.records), (3, 8, 13));
    // Record for record: every shard file byte-identical, the same shard list (checksums
    // included) and the same settings.json.
    let manifest = |d: &std::path::Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(d.join("manifest.json")).unwrap()).unwrap()
    };
    let (ms, mm) = (manifest(&single), manifest(&merged));
    assert_eq!(ms["shards"], mm["shards"]);
    assert_eq!(ms["shards"].as_array().unwrap().len(), 8);
    for s in ms["shards"].as_array().unwrap() {
        for f in ["x", "y", "meta"] {
            let f = s[f].as_str().unwrap();
            assert_eq!(
                std::fs::read(single.join(f)).unwrap(),
                std::fs::read(merged.join(f)).unwrap(),
                "{f}"
            );
        }
    }
    assert_eq!(
        std::fs::read(single.join("settings.json")).unwrap(),
        std::fs::read(merged.join("settings.json")).unwrap()
    );
    fn msg<T: std::fmt::Debug>(r: Result<T, nimbus_rpnn::data::datagen::DatagenError>) -> String {
        r.unwrap_err().to_string()
    }
    // A part folder refuses to be resumed as another part.
    let e = msg(dataset::run(
        &set,
        &o(Some(Part { index: 2, count: 3 })),
        &parts[0],
    ));
    assert!(e.contains("part"), "{e}");
    // Gaps, overlaps, other settings and a changed file are refused, naming the culprit.
    let e = msg(merge(&parts[..2], &tmp("m1")));
    assert!(e.contains("part 3/3 is missing"), "{e}");
    let e = msg(merge(
        &[parts[0].clone(), parts[1].clone(), parts[1].clone()],
        &tmp("m2"),
    ));
    assert!(e.contains("each part is given once"), "{e}");
    let other = tmp("other");
    dataset::run(
        &set,
        &DatagenOptions {
            seed: 10,
            ..o(Some(Part { index: 3, count: 3 }))
        },
        &other,
    )
    .unwrap();
    let e = msg(merge(
        &[parts[0].clone(), parts[1].clone(), other.clone()],
        &tmp("m3"),
    ));
    assert!(e.contains("other settings") && e.contains("`seed`"), "{e}");
    // A merge does not overwrite a folder holding another set (it once replaced it silently).
    let e = msg(merge(&parts, &other));
    assert!(e.contains("holds another data set"), "{e}");
    // Records whose settings.json is gone are not resumed under new settings (they once kept
    // their labels under the new settings' name).
    std::fs::remove_file(merged.join("settings.json")).unwrap();
    let e = msg(dataset::run(
        &set,
        &DatagenOptions {
            samples: 8,
            ..o(None)
        },
        &merged,
    ));
    assert!(e.contains("no settings.json"), "{e}");
    let bad = parts[1].join("train_00001_y.npy");
    let mut bytes = std::fs::read(&bad).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    // Break the hard link first so that the merged copy stays intact.
    std::fs::remove_file(&bad).unwrap();
    std::fs::write(&bad, bytes).unwrap();
    let m4 = tmp("m4");
    let e = msg(merge(&parts, &m4));
    assert!(
        e.contains("train_00001_y.npy") && e.contains("SHA-256"),
        "{e}"
    );
    assert!(!m4.exists(), "nothing is written when a check fails");
    // A missing shard (a part that did not finish) is a gap naming its part.
    std::fs::remove_file(&bad).unwrap();
    let mut m: serde_json::Value = manifest(&parts[1]);
    m["shards"]
        .as_array_mut()
        .unwrap()
        .retain(|s| !(s["split"] == "train" && s["index"] == 1));
    std::fs::write(parts[1].join("manifest.json"), m.to_string()).unwrap();
    let e = msg(merge(&parts, &tmp("m5")));
    assert!(e.contains("train shard 1 is missing (part 2/3"), "{e}");
}

#[test]
fn damaged_shards_are_recomputed_on_resume() {
    let mut set = small_set();
    // A density scale that serde_json's default (best-effort) float parser reads back one ulp
    // off: the manifest read back must still equal the one a run would write.
    set[0].density_scale = 101.843_308_458_458_41;
    let d = tmp("damaged");
    let o = DatagenOptions {
        samples: 64,
        ..opts(6)
    };
    dataset::run(&set, &o, &d).unwrap();
    let read = |f: &str| std::fs::read(d.join(f)).unwrap();
    // A run that finds every record in place leaves the manifest (whose hash cards name) as is.
    let manifest = read("manifest.json");
    assert_eq!(dataset::run(&set, &o, &d).unwrap().computed, 0);
    assert_eq!(read("manifest.json"), manifest);
    let (x0, y1, m0) = (
        read("train_00000_x.npy"),
        read("train_00001_y.npy"),
        read("test_00000_meta.npy"),
    );
    // A truncated descriptor file (rows in the header, bytes missing) ...
    std::fs::write(d.join("train_00000_x.npy"), &x0[..x0.len() - 1000]).unwrap();
    // ... a NaN written over a target, size unchanged ...
    let mut y = y1.clone();
    let at = y.len() - 4;
    y[at..].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(d.join("train_00001_y.npy"), &y).unwrap();
    // ... and an older run's shard (no checksum file) with a NaN in its metadata.
    std::fs::remove_file(d.join("test_00000.sha256")).unwrap();
    let mut m = m0.clone();
    let at = m.len() - 4;
    m[at..].copy_from_slice(&f32::NAN.to_le_bytes());
    std::fs::write(d.join("test_00000_meta.npy"), &m).unwrap();
    let r = dataset::run(&set, &o, &d).unwrap();
    // All three shards (4 + 2 training, 2 test records: all of them) are recomputed, byte for
    // byte as first written.
    assert_eq!((r.records, r.computed), (8, 8));
    assert_eq!(read("train_00000_x.npy"), x0);
    assert_eq!(read("train_00001_y.npy"), y1);
    assert_eq!(read("test_00000_meta.npy"), m0);
    assert!(d.join("test_00000.sha256").exists());
    // Intact shards of an older run (no checksum files) are kept, and get one.
    for f in [
        "train_00000.sha256",
        "train_00001.sha256",
        "test_00000.sha256",
    ] {
        std::fs::remove_file(d.join(f)).unwrap();
    }
    let r = dataset::run(&set, &o, &d).unwrap();
    assert_eq!(r.computed, 0);
    assert!(d.join("train_00001.sha256").exists());
    // A shard whose checksum file is gone and whose data changed to other finite values: the
    // manifest's checksums catch it (it was once kept, and its new checksum written).
    std::fs::remove_file(d.join("train_00001.sha256")).unwrap();
    let mut y = y1.clone();
    let last = y.len() - 1;
    y[last] ^= 1;
    std::fs::write(d.join("train_00001_y.npy"), &y).unwrap();
    let r = dataset::run(&set, &o, &d).unwrap();
    assert_eq!(r.computed, 2);
    assert_eq!(read("train_00001_y.npy"), y1);
}

#[test]
fn f16_descriptors_halve_x_and_keep_everything_else() {
    let set = small_set();
    let (a, b) = (tmp("f32"), tmp("f16"));
    let o = |f16| DatagenOptions {
        samples: 32,
        f16_descriptors: f16,
        ..opts(3)
    };
    dataset::run(&set, &o(false), &a).unwrap();
    dataset::run(&set, &o(true), &b).unwrap();
    let x32 = npyz::NpyFile::new(&std::fs::read(a.join("train_00000_x.npy")).unwrap()[..])
        .unwrap()
        .into_vec::<f32>()
        .unwrap();
    let x16 = npyz::NpyFile::new(&std::fs::read(b.join("train_00000_x.npy")).unwrap()[..])
        .unwrap()
        .into_vec::<half::f16>()
        .unwrap();
    assert_eq!(x32.len(), x16.len());
    // Round to nearest: within half a float16 ulp (2⁻¹¹ relative) or below its smallest normal.
    for (p, q) in x32.iter().zip(&x16) {
        let q = q.to_f32();
        assert!((p - q).abs() <= p.abs() * 4.9e-4 + 6.2e-5, "{p} vs {q}");
    }
    for f in [
        "train_00000_y.npy",
        "train_00001_meta.npy",
        "test_00000_y.npy",
    ] {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f}"
        );
    }
    // The option is a setting of the set: a resume with the other one is refused.
    let e = dataset::run(&set, &o(false), &b).unwrap_err().to_string();
    assert!(e.contains("f16_descriptors"), "{e}");
}

/// `gen:N:KIND,…`: the default kinds give the default set cloud for cloud; a chosen list is
/// cycled (congestus clouds get cumulus proportions and build); unknown kinds name `--clouds`.
#[test]
fn generated_set_with_chosen_kinds() {
    let d = [10.0, 300.0];
    assert_eq!(
        dataset::generated_set_of(12, 3, d, &dataset::DEFAULT_KINDS).unwrap(),
        dataset::generated_set_in(12, 3, d)
    );
    let set = dataset::generated_set_of(6, 3, d, &["congestus", "stratus"]).unwrap();
    let names: Vec<_> = set.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "congestus_000",
            "stratus_001",
            "congestus_002",
            "stratus_003",
            "congestus_004",
            "stratus_005"
        ]
    );
    let dataset::CloudSource::Generated { resolution, .. } = &set[2].source else {
        panic!("generated");
    };
    // The size advances once per cycle of kinds: the second congestus is 64 wide.
    assert_eq!(*resolution, [64, 48, 64]);
    let mut small = set[0].clone();
    if let dataset::CloudSource::Generated { resolution, .. } = &mut small.source {
        *resolution = [24, 18, 24];
    }
    assert!(dataset::build_volume(&small).is_ok());
    for bad in [&["fog"][..], &[][..]] {
        let e = dataset::generated_set_of(4, 3, d, bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("--clouds"), "{e}");
    }
}

/// The second stage's count: per-sample relative variance over the target's square, rounded up
/// to whole pilots, capped; a zero pilot mean gives one pilot's count.
#[test]
fn precise_count_from_the_pilot() {
    use nimbus_rpnn::data::datagen::{Estimate, precise_count};
    // 1 000 samples, mean 1, variance of the mean 0.01: per-sample relative variance 10; for a
    // relative error of 0.05 that is 10 / 0.0025 = 4 000 samples (four pilots).
    let p = |mean: f64, var_mean: f64| Estimate {
        mean,
        samples: 1000,
        converged: false,
        rel_ci: 0.0,
        var_mean,
        sky: None,
    };
    assert_eq!(precise_count(&p(1.0, 0.01), 0.05, 1 << 20), 4000);
    // 4 001 needed rounds up to 5 pilots.
    assert_eq!(precise_count(&p(1.0, 0.010_002_5), 0.05, 1 << 20), 5000);
    // Already precise: one pilot's count of fresh samples (never fewer).
    assert_eq!(precise_count(&p(1.0, 1e-6), 0.05, 1 << 20), 1000);
    assert_eq!(precise_count(&p(1.0, 0.01), 0.05, 3000), 3000);
    assert_eq!(precise_count(&p(0.0, 0.0), 0.05, 1 << 20), 1000);
}

/// Two-stage labels are unbiased (their mean over 100 independent labels agrees with a 2²⁰
/// sample run to 4.5 standard errors) and meet their noise target: the spread between them is
/// within 30 % of the target (100 labels: the spread's own relative error is ≈ 7 %, the
/// pilot's variance estimate adds its own), and each reports its count and whether it met it.
#[test]
fn precise_labels_are_unbiased_and_meet_their_noise() {
    let c = sphere();
    let long = c.estimate_to(X, VIEW, light(), 1 << 20, 0.0, &mut Pcg32::new(2, 2));
    let rel = 0.03;
    let runs = 100;
    let est: Vec<_> = (0..runs)
        .map(|s| {
            let rng = &mut Pcg32::new(500 + s, 9);
            c.estimate_precise(X, VIEW, light(), 256, rel, 1 << 20, rng)
        })
        .collect();
    // The sphere's per-sample relative σ is ≈ 1: (1 / 0.03)² ≈ 1 100 samples, 5 pilots.
    assert!(
        est.iter().all(|e| e.samples % 256 == 0 && e.samples >= 512),
        "{est:?}"
    );
    assert!(est.iter().all(|e| e.converged == (e.rel_noise() <= rel)));
    assert!(est.iter().filter(|e| e.converged).count() >= runs as usize / 2);
    let mean = est.iter().map(|e| e.mean).sum::<f64>() / runs as f64;
    let spread = est.iter().map(|e| (e.mean - mean).powi(2)).sum::<f64>() / (runs - 1) as f64;
    let se = (spread / runs as f64 + long.var_mean).sqrt();
    assert!(
        (mean - long.mean).abs() < 4.5 * se,
        "mean of precise labels {mean} vs long run {} (se {se})",
        long.mean
    );
    let observed = spread.sqrt() / long.mean;
    assert!(
        observed < 1.3 * rel,
        "relative spread {observed} vs target {rel}"
    );
}

/// `eval_noise` applies to the validation and test splits only, on the CPU and the GPU alike:
/// each label's count is a multiple of the pilot's, the meta records it and whether the target
/// was met; training labels keep their fixed count; without a pilot count it is refused.
#[test]
fn precise_validation_and_test_labels_in_a_set() {
    let set = small_set();
    let mut o = opts(4);
    o.records = 2;
    o.val_records = 2;
    o.test_records = 2;
    o.samples = 32;
    o.eval_samples = 128;
    o.eval_noise = 0.05;
    o.max_samples = 1 << 16;
    let mut runs = vec![(tmp("precise_cpu"), false)];
    if nimbus_gpu::testing::gpu("datagen::precise_validation_and_test_labels_in_a_set").is_some() {
        runs.push((tmp("precise_gpu"), true));
    }
    for (d, gpu) in runs {
        let mut o = o.clone();
        o.gpu = gpu;
        dataset::run(&set, &o, &d).unwrap();
        let meta = |name: &str| -> Vec<f32> {
            npyz::NpyFile::new(&std::fs::read(d.join(name)).unwrap()[..])
                .unwrap()
                .into_vec()
                .unwrap()
        };
        for m in meta("train_00000_meta.npy").chunks(dataset::META_COLUMNS) {
            assert_eq!((m[10], m[11]), (32.0, 0.0), "gpu {gpu}");
        }
        for split in ["val", "test"] {
            let y = npyz::NpyFile::new(
                &std::fs::read(d.join(format!("{split}_00000_y.npy"))).unwrap()[..],
            )
            .unwrap()
            .into_vec::<f32>()
            .unwrap();
            let m = meta(&format!("{split}_00000_meta.npy"));
            for (m, y) in m.chunks(dataset::META_COLUMNS).zip(&y) {
                let (n, met, var) = (m[10] as u64, m[11], m[13] as f64);
                assert!(n >= 128 && n % 128 == 0 && n <= 1 << 16, "gpu {gpu}: {n}");
                // The stored variance is the fresh stage's: it decides the flag (f32 columns).
                let noise = var.sqrt() / *y as f64;
                assert!(*y > 0.0, "gpu {gpu}");
                if (noise - 0.05).abs() > 1e-4 {
                    assert_eq!(met == 1.0, noise <= 0.05, "gpu {gpu}: {n} samples, {noise}");
                }
            }
        }
    }
    let mut no_pilot = o.clone();
    no_pilot.eval_samples = 0;
    let e = dataset::run(&set, &no_pilot, &tmp("precise_no_pilot"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("pilot"), "{e}");
}
