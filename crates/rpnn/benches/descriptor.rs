//! Descriptor throughput on the CPU (`nimbus_rpnn::descriptor::descriptors`, Kallweit 2017
//! §4.2): 4 096 stencils of 2 250 trilinear lookups at random points inside the demo cumulus
//! of `scenes/bench/rpnn_720p.toml`, random views, its sun — the stage that precedes ONNX
//! Runtime in every CPU-shaded RPNN sample.
//!
//! `cargo bench -p nimbus-rpnn --bench descriptor`

use std::path::Path;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use glam::DVec3;
use nimbus_rpnn::descriptor::{Config, descriptors, descriptors_into};
use nimbus_rpnn::pyramid::Pyramid;
use nimbus_scene::Scene;
use nimbus_scene::frame::uniform_sphere;
use nimbus_trace::Pcg32;

const N: usize = 4096;

fn bench(c: &mut Criterion) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
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
