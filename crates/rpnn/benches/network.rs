//! Network throughput: queries per second of the shipped sun model (`models/rpnn-hg.onnx`) in
//! ONNX Runtime and in WGSL (`shaders/rpnn_mlp.wgsl`, f32 and f16 storage, both kernels: `--net-tiles`), on one batch of
//! 4 096 real descriptors (random points inside the demo cumulus of
//! `scenes/bench/rpnn_720p.toml`, random views, its sun). Each WGSL iteration uploads the batch
//! and reads the predictions back, as `GpuMlp::predict` does.
//!
//! `XDG_RUNTIME_DIR=/tmp cargo bench -p nimbus-rpnn --bench network`

use std::path::Path;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::DVec3;
use nimbus_rpnn::descriptor::{Config, DESCRIPTOR_LEN, descriptors};
use nimbus_rpnn::gpu_mlp::{GpuMlp, NetOptions, Precision, Tiles};
use nimbus_rpnn::model::Rpnn;
use nimbus_rpnn::ort_backend::OrtModel;
use nimbus_rpnn::pyramid::Pyramid;
use nimbus_scene::Scene;
use nimbus_scene::frame::uniform_sphere;
use nimbus_trace::Pcg32;

const N: usize = 4096;

/// `N` descriptors at random points of positive density.
fn batch(root: &Path) -> Vec<f32> {
    let scene = Scene::load(root.join("scenes/bench/rpnn_720p.toml")).expect("demo scene");
    let vol = &scene.volume;
    let pyr = Pyramid::new(vol).expect("pyramid");
    let sun = scene.sun.as_ref().expect("the scene has a sun").dir;
    let (lo, hi) = (vol.aabb().min, vol.aabb().max);
    let mut rng = Pcg32::new(7, 0);
    let mut configs = Vec::with_capacity(N);
    while configs.len() < N {
        let (u, v) = (rng.next2(), rng.next2());
        let x = lo + (hi - lo) * DVec3::new(u[0], u[1], v[0]);
        if vol.lookup(x) <= 0.0 {
            continue;
        }
        configs.push(Config {
            x: x.as_vec3(),
            view: uniform_sphere(rng.next2()).as_vec3(),
            to_light: sun.as_vec3(),
        });
    }
    let d = descriptors(&pyr, &configs);
    assert_eq!(d.len(), N * DESCRIPTOR_LEN);
    d
}

fn bench(c: &mut Criterion) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let model_path = root.join("models/rpnn-hg.onnx");
    let x = batch(&root);
    let mut g = c.benchmark_group("rpnn_hg_4096_queries");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(10);
    let mut ort = OrtModel::load(&model_path, 0).expect("ONNX Runtime and the shipped model");
    g.bench_function("ort", |b| b.iter(|| ort.predict(&x, N).unwrap()));
    match nimbus_gpu::Gpu::new() {
        Ok(gpu) => {
            let model = Rpnn::load(&model_path).expect("the shipped model");
            for (name, precision, tiles) in [
                ("wgsl_f32_64x128", Precision::F32, Tiles::Wide),
                ("wgsl_f16_64x128", Precision::F16, Tiles::Wide),
                ("wgsl_f32_64x64", Precision::F32, Tiles::Square),
                ("wgsl_f16_64x64", Precision::F16, Tiles::Square),
            ] {
                let opts = NetOptions { precision, tiles };
                let mlp = GpuMlp::with_options(&gpu, &model, N, opts).expect("GPU network");
                g.bench_function(name, |b| b.iter(|| mlp.predict(&x, N).unwrap()));
            }
        }
        Err(e) => eprintln!("no GPU adapter ({e}): the WGSL network is not measured"),
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
