//! Descriptor throughput on the CPU (`nimbus_rpnn::descriptor::descriptors`, Kallweit 2017
//! §4.2): 4 096 stencils of 2 250 trilinear lookups at random points inside the demo cumulus
//! of `scenes/bench/rpnn_720p.toml`, random views, its sun — the stage that precedes ONNX
//! Runtime in every CPU-shaded RPNN sample.
//!
//! `cargo bench -p nimbus-rpnn --bench descriptor`

mod common;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nimbus_rpnn::descriptor::{descriptors, descriptors_into};

const N: usize = 4096;

fn bench(c: &mut Criterion) {
    let (pyr, configs) = common::demo_configs(N);
    let mut g = c.benchmark_group("rpnn_descriptors_4096");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(20);
    g.bench_function("cpu", |b| b.iter(|| descriptors(&pyr, &configs)));
    let mut buf = Vec::new();
    g.bench_function("cpu_reused_buffer", |b| {
        b.iter(|| descriptors_into(&pyr, &configs, &mut buf))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
