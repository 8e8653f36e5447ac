//! Path-tracer throughput (camera paths per second) on the shared `cumulus_side` case at reduced
//! resolution, with and without empty-space skipping, and with the grid stored densely or as
//! sparse bricks (the same image; the cost of the brick lookup).
//!
//! `cargo bench -p nimbus-trace`

use std::path::Path;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nimbus_scene::{MajorantGrid, Scene};
use nimbus_trace::{PathTracer, RenderOptions, render_with};

fn load() -> Scene {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut s = Scene::load(root.join("scenes/refs/cumulus_side.toml"))
        .expect("scenes/refs/cumulus_side.toml needs ../shared/refs beside the checkout");
    // 64×48 pixels keeps one iteration short; the path statistics match the full image.
    s.camera = s.camera.with_size(64, 48).unwrap();
    s
}

fn bench(c: &mut Criterion) {
    let scene = load();
    let opts = RenderOptions {
        spp: 4,
        seed: 0,
        progress: false,
    };
    let paths = (64 * 48 * 4) as u64;
    let mut g = c.benchmark_group("cumulus_side_64x48x4spp");
    g.throughput(Throughput::Elements(paths));
    g.sample_size(10);
    let grid = PathTracer::new(&scene);
    g.bench_function("majorant_grid", |b| b.iter(|| render_with(&grid, &opts)));
    let global = PathTracer::with_majorants(&scene, MajorantGrid::new(&scene.volume, [1, 1, 1]));
    g.bench_function("global_majorant", |b| {
        b.iter(|| render_with(&global, &opts))
    });
    let mut sparse = scene.clone();
    let v = &scene.volume;
    let dense = v.grid().dense().unwrap();
    let bricks = nimbus_scene::brick::from_dense(v.grid().res(), &dense, [0; 3]).unwrap();
    sparse.volume = std::sync::Arc::new(
        nimbus_scene::Volume::new(
            nimbus_scene::DensityGrid::from_bricks(bricks),
            *v.aabb(),
            v.density_scale(),
        )
        .unwrap(),
    );
    let bricked = PathTracer::new(&sparse);
    g.bench_function("majorant_grid_sparse_bricks", |b| {
        b.iter(|| render_with(&bricked, &opts))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
