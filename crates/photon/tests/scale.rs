//! Photon mapping with light volumes coarser than the density (`mapper/light.rs`): the stages
//! against their CPU twins, sparse storage against dense, and what the coarser light volumes
//! change in the image.

use glam::DVec3;
use nimbus_photon::{PhotonMapper, PmSettings, cpu};
use nimbus_scene::build::{self, SceneBuilder};
use nimbus_scene::{Aabb, Camera, DensityGrid, Image, Scene, Sun, Volume};

fn cloud(res: [usize; 3], sky: bool) -> Scene {
    let mut b = SceneBuilder::new(
        build::generated(nimbus_scene::CloudKind::Cumulus, 3, res, 20.0).unwrap(),
    )
    .sun(DVec3::new(1.0, 0.6, 0.3), DVec3::new(1.0, 0.9, 0.8))
    .look(DVec3::new(0.3, 0.3, 3.0), DVec3::ZERO, 40.0, 32, 24);
    if sky {
        b = b.sky(DVec3::new(0.1, 0.15, 0.3));
    }
    b.build().unwrap()
}

/// The same scene with the grid stored as bricks (offset lattice: bricks straddle the box's
/// planes differently from the dense layout).
fn as_sparse(s: &Scene) -> Scene {
    let g = s.volume.grid();
    let bricks =
        nimbus_scene::brick::from_dense(g.res(), g.as_dense().unwrap(), [3, 5, 1]).unwrap();
    let mut t = s.clone();
    t.volume = std::sync::Arc::new(
        Volume::new(
            DensityGrid::from_bricks(bricks),
            *s.volume.aabb(),
            s.volume.density_scale(),
        )
        .unwrap(),
    );
    t
}

fn settings(light_res: Option<[u32; 3]>, view: bool) -> PmSettings {
    PmSettings {
        beams_per_frame: 4096,
        ring: 4,
        cache_res: Some([6, 5, 6]),
        light_res,
        view_dependent: Some(view),
        ..Default::default()
    }
}

/// With J and T_sun at half the density's resolution: the work density is the grid's block
/// means, the sun pass and the ray marcher (lobes and view words) equal their CPU twins, which
/// read J at the light resolution and the density at the grid's.
#[test]
fn coarse_light_volumes_match_cpu() {
    let Some(gpu) = nimbus_gpu::testing::gpu("scale::coarse_light_volumes_match_cpu") else {
        return;
    };
    let s = cloud([24, 18, 24], true);
    // Half resolution, with lobes and view words; a factor of 1.5 (skip radius 2).
    for (light, view) in [
        ([12u32, 9, 12], false),
        ([12, 9, 12], true),
        ([16, 12, 16], false),
    ] {
        let mut pm = PhotonMapper::new(&gpu, &s, settings(Some(light), view)).unwrap();
        assert!(pm.light_is_coarse());
        assert_eq!(pm.light_res(), light);
        assert_eq!(pm.params.near_radius, if light[0] == 16 { 2 } else { 1 });
        let [x, y, z] = light;
        assert!(
            pm.light_note()
                .unwrap()
                .starts_with(&format!("light volumes {x}×{y}×{z}"))
        );
        let img = pm.render(&s.camera).unwrap();
        let work = pm.read_density().unwrap();
        assert_eq!(
            work,
            nimbus_scene::downsample::block_means(s.volume.grid(), light.map(|v| v as usize))
        );
        let p = pm.params;
        let t_sun = pm.read_sun_transmittance().unwrap();
        assert_eq!(t_sun.len(), work.len());
        for (i, &g) in t_sun.iter().enumerate() {
            let c = cpu::sun_transmittance(&p, &work, i);
            assert!((g - c).abs() <= 1e-5, "{light:?} voxel {i}: {g} vs {c}");
        }
        let j = pm.read_j().unwrap();
        let dirs = pm.read_j_dirs().unwrap();
        assert_eq!((j.len(), dirs.len()), (work.len(), work.len()));
        let mp = pm.march_params();
        assert_eq!((mp.d_res, mp.light_res), ([24, 18, 24], light));
        let fine = s.volume.grid().as_dense().unwrap();
        let scale = img.pixels.iter().flatten().fold(0.0f32, |m, v| m.max(*v));
        for y in 0..img.height {
            for x in 0..img.width {
                let c = cpu::raymarch(&mp, fine, &j, &t_sun, &dirs, x as u32, y as u32);
                let g = img.get(x, y);
                for k in 0..3 {
                    // f32 sums of a few hundred steps in a different order: 1e-4 of the
                    // brightest pixel (as `gpu.rs` allows the full-resolution ray marcher).
                    assert!(
                        (g[k] - c[k]).abs() <= 1e-4 * scale,
                        "view {view}, pixel {x},{y}: {} vs {}",
                        g[k],
                        c[k]
                    );
                }
            }
        }
    }
}

/// Sparse storage gives the image of dense storage, at full light resolution (the work density
/// is then the grid, densified within the budget) and at a coarser one (the ray marcher reads
/// the brick map): the same values through either layout, the same deterministic photons.
#[test]
fn sparse_and_dense_storage_give_the_same_image() {
    let Some(gpu) = nimbus_gpu::testing::gpu("scale::sparse_and_dense_storage_give_the_same_image")
    else {
        return;
    };
    let dense = cloud([24, 18, 24], true);
    let sparse = as_sparse(&dense);
    assert!(sparse.volume.grid().as_bricks().is_some());
    for light in [None, Some([10u32, 7, 9])] {
        let a = PhotonMapper::new(&gpu, &dense, settings(light, false))
            .unwrap()
            .render(&dense.camera)
            .unwrap();
        let b = PhotonMapper::new(&gpu, &sparse, settings(light, false))
            .unwrap()
            .render(&sparse.camera)
            .unwrap();
        assert!(a.pixels.iter().flatten().any(|&v| v > 0.0));
        assert_eq!(a.pixels, b.pixels, "light resolution {light:?}");
    }
}

/// 1 M beams with lobes: photon noise below the effects the image tests bound.
fn low_noise() -> PmSettings {
    PmSettings {
        beams_per_frame: 65536,
        ring: 16,
        view_dependent: Some(false),
        ..Default::default()
    }
}

/// Mean luminance over the pixels where the cloud is (above 1 % of the image's mean; no sky,
/// so the background is exactly 0) and the relative RMSE of `b` against `a` there.
fn cloud_mean_and_rmse(a: &Image, b: &Image) -> (f64, f64, f64) {
    let n = a.pixels.len();
    let lum = |img: &Image, i: usize| img.lum(i % img.width, i / img.width);
    let all = (0..n).map(|i| lum(a, i)).sum::<f64>() / n as f64;
    let px: Vec<usize> = (0..n).filter(|&i| lum(a, i) > 0.01 * all).collect();
    let ma = px.iter().map(|&i| lum(a, i)).sum::<f64>() / px.len() as f64;
    let mb = px.iter().map(|&i| lum(b, i)).sum::<f64>() / px.len() as f64;
    let se = px
        .iter()
        .map(|&i| (lum(a, i) - lum(b, i)).powi(2))
        .sum::<f64>()
        / px.len() as f64;
    (ma, mb, se.sqrt() / ma)
}

/// What halving the light volumes' resolution costs in the image (sun only, lobes, 1 M beams so
/// that photon noise is below the effect). Measured here: mean over cloud pixels 0.73 % lower,
/// relative RMSE 3.8 %, where two seeds at full resolution differ by 0.4 % and 2.8 % (photon
/// noise). Bounds: the mean within 1.5 % (the effect plus 2σ of seed-to-seed noise), the RMSE
/// below 6 % (noise alone is 2.8 %; a wrong lookup scale or a misplaced cell moves whole
/// regions and gives tens of per cent).
#[test]
fn half_light_resolution_changes_the_image_little() {
    let Some(gpu) =
        nimbus_gpu::testing::gpu("scale::half_light_resolution_changes_the_image_little")
    else {
        return;
    };
    let s = cloud([48, 36, 48], false);
    let run = |light: Option<[u32; 3]>, seed: u32| {
        let mut pm = PhotonMapper::new(
            &gpu,
            &s,
            PmSettings {
                light_res: light,
                seed,
                ..low_noise()
            },
        )
        .unwrap();
        pm.render(&s.camera).unwrap()
    };
    let full = run(None, 0);
    let (ma, mb, noise) = cloud_mean_and_rmse(&full, &run(None, 1));
    eprintln!("seed 0 {ma:.5}, seed 1 {mb:.5}: relative RMSE {noise:.4}");
    let (ma, mb, rmse) = cloud_mean_and_rmse(&full, &run(Some([24, 18, 24]), 0));
    eprintln!(
        "full {ma:.5}, half {mb:.5} (ratio {:.4}), relative RMSE {rmse:.4}",
        mb / ma
    );
    assert!((mb / ma - 1.0).abs() < 0.015, "mean {ma} vs {mb}");
    assert!(rmse < 0.06, "relative RMSE {rmse}");
}

/// A grid whose J would not fit one storage binding gets coarser light volumes by default
/// (each axis divided by the smallest integer at which the bricks near density fit: here every
/// brick, the grid being constant; `mapper::light::light_map`); asking for them
/// at full resolution is refused with the bytes, before any allocation.
#[test]
fn oversized_grids_get_coarser_light_volumes() {
    let Some(gpu) = nimbus_gpu::testing::gpu("scale::oversized_grids_get_coarser_light_volumes")
    else {
        return;
    };
    let limit = gpu
        .limits
        .max_storage_buffer_binding_size
        .min(gpu.limits.max_buffer_size);
    let n = ((limit / 16) as f64).cbrt().ceil() as usize + 1;
    if n > 700 {
        eprintln!("adapter allows {limit} bytes per binding; skipping the oversized-grid check");
        return;
    }
    let grid = DensityGrid::constant([n, n, n], 1.0).unwrap();
    let mut s = SceneBuilder::new(
        Volume::new(grid, Aabb::new(DVec3::ZERO, DVec3::ONE).unwrap(), 1.0).unwrap(),
    )
    .hg(0.5)
    .camera(Camera::new(DVec3::new(0.0, 0.0, 3.0), DVec3::ZERO, DVec3::Y, 40.0, 8, 8).unwrap())
    .build()
    .unwrap();
    s.sun = Some(Sun::new(DVec3::Y, DVec3::ONE, 0.0).unwrap());
    let pm = PhotonMapper::new(&gpu, &s, PmSettings::default()).unwrap();
    let k = n.div_ceil(pm.light_res()[0] as usize);
    assert!(
        pm.light_is_coarse() && k == 2,
        "{n}³ → {:?}",
        pm.light_res()
    );
    assert_eq!(pm.light_res(), [n.div_ceil(2) as u32; 3]);
    assert!(pm.light_res().iter().map(|&v| v as u64).product::<u64>() * 16 <= limit);
    drop(pm);
    let e = PhotonMapper::new(
        &gpu,
        &s,
        PmSettings {
            light_res: Some([n as u32; 3]),
            ..Default::default()
        },
    )
    .err()
    .expect("must be refused")
    .to_string();
    assert!(
        e.contains("upsampled cache J") && e.contains("allows at most"),
        "{e}"
    );
}

/// The 24×18×24 cloud in one corner of a 48×36×48 box (the rest empty, as in a large sparse
/// file).
fn cloud_in_a_corner() -> Scene {
    let small = cloud([24, 18, 24], false);
    let g = small.volume.grid().as_dense().unwrap();
    let mut data = vec![0.0f32; 48 * 36 * 48];
    for z in 0..24 {
        for y in 0..18 {
            let src = (z * 18 + y) * 24;
            let dst = (z * 36 + y) * 48;
            data[dst..dst + 24].copy_from_slice(&g[src..src + 24]);
        }
    }
    let aabb = small.volume.aabb();
    let grown = Aabb::new(aabb.min, aabb.min + 2.0 * aabb.extent()).unwrap();
    let mut s = small.clone();
    s.volume = std::sync::Arc::new(
        Volume::new(
            DensityGrid::new([48, 36, 48], data).unwrap(),
            grown,
            small.volume.density_scale(),
        )
        .unwrap(),
    );
    s.camera = Camera::new(
        aabb.center() + DVec3::new(0.3, 0.3, 3.0),
        aabb.center(),
        DVec3::Y,
        40.0,
        32,
        24,
    )
    .unwrap();
    s
}

/// A cloud in a corner of an otherwise empty box, on an adapter whose storage bindings hold J
/// for the bricks near the cloud but not for the whole box (the limit lowered to 1 MiB).
/// Where the whole box's bricks fit at half resolution and a light voxel there is optically
/// thin, that is the default (the layout and cost of a grid that fits); where it would be
/// thick, the light volumes keep the grid's resolution with only the bricks near density
/// stored. The sparse image is that of the whole-box layout bit for bit (the same work
/// density, deterministic photons, absent bricks read as the zeros the whole-box layout holds
/// there, the sun pass skipping absent bricks exactly).
#[test]
fn sparse_light_bricks_keep_the_grid_resolution() {
    let Some(mut gpu) =
        nimbus_gpu::testing::gpu("scale::sparse_light_bricks_keep_the_grid_resolution")
    else {
        return;
    };
    // A light voxel of half resolution is 3.3 mean free paths wide at the densest; at a
    // quarter of the density, 0.83.
    let thick = cloud_in_a_corner();
    let mut thin = thick.clone();
    thin.volume = std::sync::Arc::new(
        Volume::new(
            thick.volume.grid().clone(),
            *thick.volume.aabb(),
            0.25 * thick.volume.density_scale(),
        )
        .unwrap(),
    );
    let run = |gpu: &nimbus_gpu::Gpu, s: &Scene, light_res: Option<[u32; 3]>| {
        let mut pm = PhotonMapper::new(
            gpu,
            s,
            PmSettings {
                skip_empty: Some(true),
                ..settings(light_res, false)
            },
        )
        .unwrap();
        let img = pm.render(&s.camera).unwrap();
        let t_sun = pm.read_sun_transmittance().unwrap();
        let depth = pm.light_voxel_depth();
        (
            img,
            pm.light_res(),
            pm.light_bricks(),
            pm.light_note(),
            t_sun,
            depth,
        )
    };
    let (full, res_full, (stored_full, total), note_full, t_full, _) = run(&gpu, &thick, None);
    // 48×36×48 voxels: 6×5×6 bricks, J 1.48 MB with every brick.
    assert_eq!((res_full, stored_full, total), ([48, 36, 48], 180, 180));
    assert_eq!(note_full, None);
    gpu.limits.max_storage_buffer_binding_size = 1 << 20;
    let (_, res, (stored, total), _, _, depth) = run(&gpu, &thin, None);
    assert_eq!(
        (res, stored, total),
        ([24, 18, 24], 27, 27),
        "thin at half resolution"
    );
    assert!((depth - 0.8333).abs() < 1e-3, "{depth}");
    let (sparse, res, (stored, _), note, t_sparse, _) = run(&gpu, &thick, None);
    assert_eq!(res, [48, 36, 48]);
    // The cloud lies within the corner's 3×3×3 bricks; grown by the reach of the lookups,
    // at most 4×4×4 of the 180.
    assert!((8..=64).contains(&stored), "{stored} bricks stored");
    assert!(
        note.unwrap()
            .contains(&format!("{stored} of 180 8³ bricks stored"))
    );
    assert!(t_full == t_sparse, "sparse and whole-box T_sun differ");
    assert!(
        full.pixels == sparse.pixels,
        "sparse and whole-box light volumes differ"
    );
    // Asked for, the thin cloud's light volumes are sparse at full resolution too.
    let (_, res, (stored_thin, _), ..) = run(&gpu, &thin, Some([48, 36, 48]));
    assert_eq!((res, stored_thin), ([48, 36, 48], stored));
    // With a limit below even the bricks near the cloud, the light volumes get coarser.
    gpu.limits.max_storage_buffer_binding_size = 100 << 10;
    let (_, res, _, note, ..) = run(&gpu, &thick, None);
    assert!(res[0] < 48, "{res:?}");
    assert!(
        note.unwrap()
            .starts_with(&format!("light volumes {}×", res[0]))
    );
    // A density sequence on the sparse layout: a frame within the first frame's bricks is
    // taken (the same density: the same image), one that needs more bricks is refused.
    gpu.limits.max_storage_buffer_binding_size = 1 << 20;
    let mut pm = PhotonMapper::new(
        &gpu,
        &thick,
        PmSettings {
            skip_empty: Some(true),
            ..settings(None, false)
        },
    )
    .unwrap();
    let grid = thick.volume.grid().as_dense().unwrap().to_vec();
    pm.set_density(&grid).unwrap();
    assert!(pm.render(&thick.camera).unwrap().pixels == sparse.pixels);
    let e = pm
        .set_density(&vec![0.5; grid.len()])
        .expect_err("more bricks than the pools hold")
        .to_string();
    assert!(
        e.contains("light bricks") && e.contains("--light-res"),
        "{e}"
    );
    drop(pm);
    // Asked for a resolution whose brick index alone exceeds the binding: refused, naming it.
    gpu.limits.max_storage_buffer_binding_size = 512;
    let e = PhotonMapper::new(&gpu, &thick, settings(Some([48, 36, 48]), false))
        .err()
        .expect("must be refused")
        .to_string();
    assert!(
        e.contains("light_res") && e.contains("6×5×6 light bricks would not fit"),
        "{e}"
    );
}

/// Empty-space skipping in the trace: the GPU trace equals its CPU twin with skipping on (the
/// same word-class bounds as `gpu.rs`'s twin test), and the image with skipping equals the one
/// without to photon noise (1 M beams, lobes: two seeds differ by ≈ 3 % RMSE, see above; the
/// mean within 1.5 %).
#[test]
fn skipping_empty_cells_changes_only_the_noise() {
    let Some(gpu) = nimbus_gpu::testing::gpu("scale::skipping_empty_cells_changes_only_the_noise")
    else {
        return;
    };
    let s = cloud_in_a_corner();
    // Coarse light volumes: skipping is on by default.
    let coarse = PhotonMapper::new(&gpu, &s, settings(Some([24, 18, 24]), false)).unwrap();
    assert_eq!(coarse.params.skip_empty, 1);
    drop(coarse);
    // The twin, at full light resolution with skipping forced on.
    let mut pm = PhotonMapper::new(
        &gpu,
        &s,
        PmSettings {
            skip_empty: Some(true),
            cache_res: Some([12, 9, 12]),
            ..settings(None, true)
        },
    )
    .unwrap();
    pm.trace_frame(None);
    let gpu_total = pm.read_total().unwrap();
    let density = pm.read_density().unwrap();
    let p = pm.params;
    let work = nimbus_photon::light_map::LightMap::from_dense(
        p.light_res.map(|v| v as usize),
        &density,
        1,
        false,
    );
    let skip = nimbus_photon::mapper::light::skippable_cells(&work, p.i_res);
    assert!(skip.iter().filter(|&&v| v == 1).count() > skip.len() / 4);
    let mut h = vec![0u32; gpu_total.len()];
    for beam in 0..p.n_sun + p.n_sky {
        assert!(!cpu::trace(&p, &density, &skip, beam, &mut h));
    }
    let words = cpu::CELL_WORDS;
    for k in 0..11 {
        let (mut diff, mut sum) = (0.0f64, 0.0f64);
        for c in 0..h.len() / words {
            let (a, b) = (gpu_total[c * words + k] as f64, h[c * words + k] as f64);
            diff += (a - b).abs();
            sum += a;
        }
        assert!(diff <= 1e-4 * sum.max(1.0), "word {k}: L1 {diff} of {sum}");
    }
    // Skipped cells receive nothing.
    for (c, &sk) in skip.iter().enumerate() {
        if sk == 1 {
            assert!(
                gpu_total[c * words..(c + 1) * words]
                    .iter()
                    .all(|&v| v == 0)
            );
        }
    }
    // The image, with and without.
    let run = |skip: bool| {
        let mut pm = PhotonMapper::new(
            &gpu,
            &s,
            PmSettings {
                light_res: Some([24, 18, 24]),
                skip_empty: Some(skip),
                ..low_noise()
            },
        )
        .unwrap();
        pm.render(&s.camera).unwrap()
    };
    let (ma, mb, rmse) = cloud_mean_and_rmse(&run(false), &run(true));
    eprintln!(
        "without {ma:.5}, with {mb:.5} (ratio {:.4}), relative RMSE {rmse:.4}",
        mb / ma
    );
    assert!((mb / ma - 1.0).abs() < 0.015, "mean {ma} vs {mb}");
    assert!(rmse < 0.06, "relative RMSE {rmse}");
}
