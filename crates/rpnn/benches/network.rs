//! Network throughput: queries per second of the shipped sun model (`models/rpnn-hg.onnx`) in
//! ONNX Runtime (f32, and its int8 copy: `--backend ort-int8`; one session with its own
//! threads, and one single-threaded session per core as a render runs them: `_workers`) and in
//! WGSL (`shaders/rpnn_mlp.wgsl`, f32 and f16 storage, both kernels: `--net-tiles`), on one
//! batch of 4 096 real descriptors (random points inside the demo cumulus of
//! `scenes/bench/rpnn_720p.toml`, random views, its sun). Each WGSL iteration uploads the batch
//! and reads the predictions back, as `GpuMlp::predict` does.
//!
//! `XDG_RUNTIME_DIR=/tmp cargo bench -p nimbus-rpnn --bench network`

mod common;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nimbus_rpnn::descriptor::{DESCRIPTOR_LEN, descriptors};
use nimbus_rpnn::gpu_mlp::{GpuMlp, NetOptions, Precision, Tiles};
use nimbus_rpnn::model::Rpnn;
use nimbus_rpnn::ort_backend::{Cores, OrtModel};

const N: usize = 4096;

/// The descriptors of `N` configurations in the demo cumulus.
fn batch() -> Vec<f32> {
    let (pyr, configs) = common::demo_configs(N);
    let d = descriptors(&pyr, &configs);
    assert_eq!(d.len(), N * DESCRIPTOR_LEN);
    d
}

fn bench(c: &mut Criterion) {
    let model_path = common::root().join("models/rpnn-hg.onnx");
    let x = batch();
    let mut g = c.benchmark_group("rpnn_hg_4096_queries");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(10);
    let mut ort = OrtModel::load(&model_path, 0).expect("ONNX Runtime and the shipped model");
    g.bench_function("ort", |b| b.iter(|| ort.predict(&x, N).unwrap()));
    let mut int8 = OrtModel::load_int8(&model_path, 0).expect("the shipped model's int8 copy");
    g.bench_function("ort_int8", |b| b.iter(|| int8.predict(&x, N).unwrap()));
    // As a render runs it: one single-threaded session per core, each on its share of the
    // batch in pieces of at most `ROWS_PER_RUN` (an int8 copy: pieces of at most
    // `INT8_ROWS_PER_RUN`, cut by the batch's size; the rows copied from the same descriptors).
    let copy = |i: usize, row: &mut [f32]| {
        row.copy_from_slice(&x[i * DESCRIPTOR_LEN..(i + 1) * DESCRIPTOR_LEN])
    };
    let mut workers = OrtModel::load(&model_path, Cores::Workers(0)).expect("ONNX Runtime");
    g.bench_function("ort_workers", |b| {
        b.iter(|| workers.predict_rows(N, DESCRIPTOR_LEN, copy).unwrap())
    });
    let mut int8_workers =
        OrtModel::load_int8(&model_path, Cores::Workers(0)).expect("the int8 copy");
    g.bench_function("ort_int8_workers", |b| {
        b.iter(|| int8_workers.predict_rows(N, DESCRIPTOR_LEN, copy).unwrap())
    });
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
