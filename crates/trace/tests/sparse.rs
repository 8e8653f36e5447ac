//! Sparse (brick) and dense storage of one grid give the same image, bit for bit, with the CPU
//! and the GPU path tracer at equal seeds: the bricks return the same values and the majorant
//! grid the same bounds, so every random decision is the same. On the GPU the sparse grid is a
//! brick map over a texture atlas (`shaders/lib/density_bricks.wgsl`), the dense one a buffer.

use std::path::Path;
use std::sync::Arc;

use nimbus_scene::{DensityGrid, Scene, Volume, brick};
use nimbus_trace::gpu::GpuPathTracer;
use nimbus_trace::{RenderOptions, render};

/// The scene with its grid stored as bricks on a lattice shifted by (3, 5, 1) voxels (so that
/// bricks straddle the cloud's features and the box's edges).
fn sparse_copy(scene: &Scene) -> Scene {
    let v = &scene.volume;
    let g = v.grid();
    let bricks = brick::from_dense(g.res(), &g.dense().unwrap(), [3, 5, 1]).unwrap();
    let mut s = scene.clone();
    s.volume = Arc::new(
        Volume::new(
            DensityGrid::from_bricks(bricks),
            *v.aabb(),
            v.density_scale(),
        )
        .unwrap(),
    );
    s
}

fn small(name: &str) -> Scene {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut scene = Scene::load(root.join("scenes/refs").join(name)).unwrap();
    let c = &scene.camera;
    scene.camera =
        nimbus_scene::Camera::new(c.origin, c.target(), c.up_hint(), c.vfov_deg(), 40, 30).unwrap();
    scene
}

#[test]
fn sparse_and_dense_render_the_same_image() {
    for name in ["cube_iso.toml", "cumulus_side.toml"] {
        let dense = small(name);
        let sparse = sparse_copy(&dense);
        assert!(sparse.volume.grid().as_bricks().is_some());
        let opts = RenderOptions {
            spp: 8,
            seed: 11,
            progress: false,
        };
        let (a, b) = (render(&dense, &opts), render(&sparse, &opts));
        assert!(
            a.image.pixels == b.image.pixels,
            "{name}: CPU images differ"
        );
        assert!(
            a.image.pixels.iter().any(|p| p[0] > 0.0),
            "{name}: black image"
        );
        let Some(gpu) = nimbus_gpu::testing::gpu("sparse::sparse_and_dense_render_the_same_image")
        else {
            return;
        };
        let (ga, _) = GpuPathTracer::new(&gpu, &dense)
            .unwrap()
            .render(8, 5)
            .unwrap();
        let (gb, _) = GpuPathTracer::new(&gpu, &sparse)
            .unwrap()
            .render(8, 5)
            .unwrap();
        assert!(ga.pixels == gb.pixels, "{name}: GPU images differ");
        // The dense grid forced into a brick map whose atlas is 16 blocks wide, so slots wrap
        // over the atlas's rows and layers (the path of boxes beyond one storage binding).
        let mut forced = GpuPathTracer::with_storage(
            &gpu,
            &dense,
            nimbus_trace::gpu::DensityStorage::Bricks { max_blocks: 16 },
        )
        .unwrap();
        let (gc, _) = forced.render(8, 5).unwrap();
        assert!(
            ga.pixels == gc.pixels,
            "{name}: GPU brick-map image differs"
        );
    }
}
