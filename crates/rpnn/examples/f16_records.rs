//! The WGSL network with f16 storage (`--net-precision f16`) against ONNX Runtime (f32) on the
//! held-out records of a record set (`nimbus datagen`, test split): the per-record difference
//! between the two, and each one's error against the records' path-traced labels (the sun's
//! indirect radiance, the records' `y`). With a sky-head model the sky's transfer is compared as
//! a render uses it: contracted with a clear sky in each record's frame.
//!
//!     cargo run --release -p nimbus-rpnn --example f16_records -- RECORD_SET MODEL.onnx

use glam::DVec3;
use nimbus_rpnn::gpu_mlp::{GpuMlp, Precision};
use nimbus_rpnn::model::Rpnn;
use nimbus_rpnn::ort_backend::OrtModel;
use nimbus_rpnn::sky::{self, SH_COEFFS, SkyModel};

fn read<T: npyz::Deserialize>(path: &std::path::Path) -> (Vec<u64>, Vec<T>) {
    let f = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let npy = npyz::NpyFile::new(std::io::BufReader::new(f)).unwrap();
    let shape = npy.shape().to_vec();
    (shape, npy.into_vec().unwrap())
}

fn quantile(mut v: Vec<f64>, q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (set, model_path) = (
        std::path::PathBuf::from(&args[1]),
        std::path::PathBuf::from(&args[2]),
    );
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(set.join("manifest.json")).unwrap()).unwrap();
    let (mut x, mut y, mut meta) = (Vec::<f32>::new(), Vec::<f32>::new(), Vec::<Vec<f32>>::new());
    for s in manifest["shards"].as_array().unwrap() {
        let (_, xs): (_, Vec<half::f16>) = read(&set.join(s["x"].as_str().unwrap()));
        x.extend(xs.iter().map(|v| v.to_f32()));
        let (_, ys): (_, Vec<f32>) = read(&set.join(s["y"].as_str().unwrap()));
        y.extend(ys);
        let (shape, m): (_, Vec<f32>) = read(&set.join(s["meta"].as_str().unwrap()));
        meta.extend(m.chunks(shape[1] as usize).map(<[f32]>::to_vec));
    }
    let n = y.len();
    let model = Rpnn::load(&model_path).unwrap();
    let per = model.outputs_per_query();
    let gpu = nimbus_gpu::Gpu::new().unwrap();
    let f16 = GpuMlp::with_precision(&gpu, &model, 4096, Precision::F16)
        .unwrap()
        .predict(&x, n)
        .unwrap();
    let mut ort = OrtModel::load(&model_path, 0).unwrap();
    let want = ort.predict(&x, n).unwrap();
    println!(
        "{n} records of {}, model {} on {}",
        set.display(),
        model_path.display(),
        gpu.describe()
    );
    // The sun head: f16 against ONNX Runtime, and both against the labels.
    let scale = want
        .iter()
        .step_by(per)
        .map(|v| v.abs() as f64)
        .sum::<f64>()
        / n as f64;
    let diff: Vec<f64> = (0..n)
        .map(|i| {
            (f16[i * per] - want[i * per]).abs() as f64 / (want[i * per].abs() as f64).max(scale)
        })
        .collect();
    let err = |p: &[f32]| -> Vec<f64> {
        (0..n)
            .filter(|&i| y[i] > 0.0)
            .map(|i| ((p[i * per] - y[i]) / y[i]).abs() as f64)
            .collect()
    };
    let mean = |p: &[f32]| (0..n).map(|i| p[i * per] as f64).sum::<f64>() / n as f64;
    println!(
        "sun head: f16 vs ONNX Runtime per record (relative to max(|y|, mean |y|)): median {:.2e}, p99 {:.2e}, max {:.2e}; mean ratio {:.6}",
        quantile(diff.clone(), 0.5),
        quantile(diff.clone(), 0.99),
        quantile(diff, 1.0),
        mean(&f16) / mean(&want)
    );
    println!(
        "sun head against the labels: median relative error ONNX Runtime {:.4}, f16 {:.4}; mean prediction / mean label {:.4} and {:.4}",
        quantile(err(&want), 0.5),
        quantile(err(&f16), 0.5),
        mean(&want) / (y.iter().map(|v| *v as f64).sum::<f64>() / n as f64),
        mean(&f16) / (y.iter().map(|v| *v as f64).sum::<f64>() / n as f64),
    );
    if per == model.outputs {
        return;
    }
    // The sky head contracted with a clear sky in each record's frame (meta columns 4..10:
    // view and light directions, as the records store them).
    let sky = SkyModel {
        sun_elevation_deg: 30.0,
        sun_azimuth_deg: 40.0,
        turbidity: 3.0,
        zenith: DVec3::new(0.08, 0.16, 0.36),
        ground: DVec3::new(0.06, 0.055, 0.05),
    };
    let c = sky::project(|d| sky.radiance(d), 32);
    let contract = |p: &[f32], i: usize| -> f64 {
        let r = &meta[i];
        let view = DVec3::new(r[4] as f64, r[5] as f64, r[6] as f64);
        let light = DVec3::new(r[7] as f64, r[8] as f64, r[9] as f64);
        let (ex, ey, ez) = nimbus_rpnn::descriptor::frame(view.as_vec3(), light.as_vec3());
        let t = &p[i * per + model.outputs..i * per + model.outputs + SH_COEFFS];
        sky::product_in_frame(t, &c, (ex.as_dvec3(), ey.as_dvec3(), ez.as_dvec3()), 4).y
    };
    let a: Vec<f64> = (0..n).map(|i| contract(&f16, i)).collect();
    let b: Vec<f64> = (0..n).map(|i| contract(&want, i)).collect();
    let s = b.iter().map(|v| v.abs()).sum::<f64>() / n as f64;
    let d: Vec<f64> = a
        .iter()
        .zip(&b)
        .map(|(p, q)| (p - q).abs() / q.abs().max(s))
        .collect();
    println!(
        "sky head under a clear sky: f16 vs ONNX Runtime per record: median {:.2e}, p99 {:.2e}, max {:.2e}; mean ratio {:.6}",
        quantile(d.clone(), 0.5),
        quantile(d.clone(), 0.99),
        quantile(d, 1.0),
        a.iter().sum::<f64>() / b.iter().sum::<f64>()
    );
}
