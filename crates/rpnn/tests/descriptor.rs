//! Descriptor tests: CPU = GPU, rotation invariance, analytic densities, mass conservation,
//! degenerate frames.

use glam::{DVec3, Vec3};
use nimbus_rpnn::descriptor::{
    Config, DESCRIPTOR_LEN, LEVELS, POINTS, descriptor, descriptor_scaled, descriptors, frame,
};
use nimbus_rpnn::gpu::GpuDescriptor;
use nimbus_rpnn::{Pyramid, PyramidError};
use nimbus_scene::{Aabb, DensityGrid, Volume, generate};

fn rng(seed: u64) -> impl FnMut() -> f32 {
    let mut s = seed;
    move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((s >> 40) as f32) / (1u64 << 24) as f32
    }
}

fn dir(r: &mut impl FnMut() -> f32) -> Vec3 {
    let z = 1.0 - 2.0 * r();
    let phi = std::f32::consts::TAU * r();
    let s = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(s * phi.cos(), s * phi.sin(), z)
}

fn cloud(res: [usize; 3]) -> Volume {
    let g = generate::generate(nimbus_scene::CloudKind::Cumulus, 11, res).unwrap();
    let (lo, hi) = generate::default_aabb(res);
    Volume::new(g, Aabb::new(lo, hi).unwrap(), 20.0).unwrap()
}

#[test]
fn gpu_matches_cpu() {
    let vol = cloud([32, 24, 32]);
    let pyr = Pyramid::new(&vol).unwrap();
    let mut r = rng(5);
    let (lo, hi) = (vol.aabb().min.as_vec3(), vol.aabb().max.as_vec3());
    let mut configs: Vec<Config> = (0..96)
        .map(|_| Config {
            x: lo + (hi - lo) * Vec3::new(r(), r(), r()),
            view: dir(&mut r),
            to_light: dir(&mut r),
        })
        .collect();
    // Degenerate frames: view along and against the light.
    let l = Vec3::new(0.3, 0.8, -0.5).normalize();
    configs.push(Config {
        x: Vec3::ZERO,
        view: l,
        to_light: l,
    });
    configs.push(Config {
        x: Vec3::ZERO,
        view: -l,
        to_light: l,
    });
    let cpu = descriptors(&pyr, &configs);
    let Some(gpu) = nimbus_gpu::testing::gpu("descriptor::gpu_matches_cpu") else {
        return;
    };
    let gd = GpuDescriptor::new(&gpu, &pyr).unwrap();
    let out = gd.compute(&configs).unwrap();
    assert_eq!(out.len(), configs.len() * DESCRIPTOR_LEN);
    let scale = cpu.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    for (i, (a, b)) in out.iter().zip(&cpu).enumerate() {
        // 1e-5 relative; values near zero compare against 1e-5 of the largest value (trilinear
        // weights computed with and without fused multiply-add differ in the last bits).
        let tol = if i % DESCRIPTOR_LEN == DESCRIPTOR_LEN - 1 {
            // γ ∈ [0, π]: 1e-5 of its range (GPU atan2/normalize approximations).
            1e-5 * std::f32::consts::PI
        } else {
            1e-5 * a.abs().max(b.abs()).max(1e-2 * scale)
        };
        assert!(
            (a - b).abs() <= tol,
            "config {} index {}: GPU {a} vs CPU {b}",
            i / DESCRIPTOR_LEN,
            i % DESCRIPTOR_LEN
        );
        assert!(a.is_finite());
    }
}

/// Rotating cloud, view and light together by 90° about y leaves the descriptor unchanged (the
/// rotation maps voxel centres onto voxel centres, so lookups are exact correspondences).
#[test]
fn invariant_under_joint_rotation() {
    let n = 32;
    let res = [n, 24, n];
    let vol = cloud(res);
    let g = vol.grid();
    // (x, y, z) → (z, y, −x): new[x' = z][y][z' = n−1−x] = old[x][y][z].
    let mut rot = vec![0.0f32; g.as_dense().unwrap().len()];
    for z in 0..n {
        for y in 0..res[1] {
            for x in 0..n {
                rot[((n - 1 - x) * res[1] + y) * n + z] = g.get(x, y, z);
            }
        }
    }
    let ext = vol.aabb().max;
    let vol_r = Volume::new(
        DensityGrid::new(res, rot).unwrap(),
        Aabb::new(
            DVec3::new(-ext.z, -ext.y, -ext.x),
            DVec3::new(ext.z, ext.y, ext.x),
        )
        .unwrap(),
        20.0,
    )
    .unwrap();
    let (pa, pb) = (Pyramid::new(&vol).unwrap(), Pyramid::new(&vol_r).unwrap());
    let rotate = |v: Vec3| Vec3::new(v.z, v.y, -v.x);
    let mut r = rng(9);
    for _ in 0..20 {
        let c = Config {
            x: Vec3::new(r() - 0.5, r() * 0.5 - 0.25, r() - 0.5),
            view: dir(&mut r),
            to_light: dir(&mut r),
        };
        let mut a = vec![0.0; DESCRIPTOR_LEN];
        let mut b = vec![0.0; DESCRIPTOR_LEN];
        descriptor(&pa, c.x, c.view, c.to_light, &mut a);
        descriptor(&pb, rotate(c.x), rotate(c.view), rotate(c.to_light), &mut b);
        for (i, (u, v)) in a.iter().zip(&b).enumerate() {
            assert!(
                (u - v).abs() <= 1e-4 * u.abs().max(1.0),
                "index {i}: {u} vs {v}"
            );
        }
    }
}

/// The scaled stencil (the A/B of `training/experiments/stencil_ab.py`): scale 1 is the paper's
/// descriptor bit for bit, and at scale ½ level k + 1 has level k's points and pyramid level,
/// so it reads the same values exactly.
#[test]
fn scaled_stencil_shifts_the_levels() {
    let vol = cloud([32, 24, 32]);
    let pyr = Pyramid::with_every_level(&vol).unwrap();
    let mut r = rng(5);
    for _ in 0..20 {
        let (x, view, l) = (
            Vec3::new(r() - 0.5, r() * 0.5 - 0.25, r() - 0.5),
            dir(&mut r),
            dir(&mut r),
        );
        let mut one = vec![0.0; DESCRIPTOR_LEN];
        let mut same = vec![0.0; DESCRIPTOR_LEN];
        let mut half = vec![0.0; DESCRIPTOR_LEN];
        descriptor(&pyr, x, view, l, &mut one);
        descriptor_scaled(&pyr, x, view, l, 1.0, &mut same);
        descriptor_scaled(&pyr, x, view, l, 0.5, &mut half);
        assert_eq!(one, same);
        assert_eq!(half[POINTS..LEVELS * POINTS], one[..(LEVELS - 1) * POINTS]);
        assert_eq!(half[LEVELS * POINTS], one[LEVELS * POINTS]);
        assert!(one.iter().any(|v| *v > 0.0));
    }
}

/// Constant density: every level-1 point well inside the box reads ρ = 1 (σ_t equals the mean);
/// half-space: ρ at the plane is ½ and ρ(−z) + ρ(z) = 1 (the blurred step is antisymmetric).
#[test]
fn analytic_densities() {
    let n = 64;
    let vox = 1.0 / n as f64;
    let unit = Aabb::new(DVec3::splat(-0.5), DVec3::splat(0.5)).unwrap();
    // One mean free path = one voxel.
    let scale = 1.0 / vox;
    let vol = Volume::new(DensityGrid::constant([n, n, n], 1.0).unwrap(), unit, scale).unwrap();
    let pyr = Pyramid::new(&vol).unwrap();
    assert!((pyr.mean_sigma - scale).abs() < 1e-9);
    let mut d = vec![0.0; DESCRIPTOR_LEN];
    descriptor(&pyr, Vec3::ZERO, Vec3::X, Vec3::Z, &mut d);
    for (p, v) in d[..POINTS].iter().enumerate() {
        assert!((v - 1.0).abs() < 1e-5, "level 1 point {p}: {v}");
    }
    assert!((d[DESCRIPTOR_LEN - 1] - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
    // Half-space z < 0.
    let data: Vec<f32> = (0..n * n * n)
        .map(|i| if i / (n * n) < n / 2 { 1.0 } else { 0.0 })
        .collect();
    let vol = Volume::new(DensityGrid::new([n, n, n], data).unwrap(), unit, scale).unwrap();
    let pyr = Pyramid::new(&vol).unwrap();
    descriptor(&pyr, Vec3::ZERO, Vec3::X, Vec3::Z, &mut d);
    // Level-1 points with (ix, iy) = (2, 2) lie on the z axis at z = −1, −½, 0, …, 3 voxels.
    let on_axis = |iz: usize| d[2 + 5 * 2 + 25 * iz];
    assert!(
        (on_axis(2) - 0.5).abs() < 1e-5,
        "ρ at the plane: {}",
        on_axis(2)
    );
    assert!((on_axis(0) + on_axis(4) - 1.0).abs() < 1e-5);
    assert!((on_axis(1) + on_axis(3) - 1.0).abs() < 1e-5);
    assert!(on_axis(0) > on_axis(1) && on_axis(1) > on_axis(2) && on_axis(3) > on_axis(4));
    assert!(on_axis(8) < 3e-3); // Gaussian tail at 3σ: Φ(−3) ≈ 1.3e-3
}

/// Gaussian filtering and pair averaging conserve mass while the filter stays inside the box.
#[test]
fn pyramid_conserves_mass() {
    let n = 64;
    let c = n as f64 / 2.0;
    let data: Vec<f32> = (0..n * n * n)
        .map(|i| {
            let (x, y, z) = (
                (i % n) as f64 + 0.5,
                ((i / n) % n) as f64 + 0.5,
                (i / (n * n)) as f64 + 0.5,
            );
            let r2 = (x - c).powi(2) + (y - c).powi(2) + (z - c).powi(2);
            (-(r2 / 32.0)).exp() as f32
        })
        .collect();
    let vol = Volume::new(
        DensityGrid::new([n, n, n], data).unwrap(),
        Aabb::new(DVec3::ZERO, DVec3::ONE).unwrap(),
        5.0,
    )
    .unwrap();
    let pyr = Pyramid::with_every_level(&vol).unwrap();
    let raw: f64 = vol
        .grid()
        .as_dense()
        .unwrap()
        .iter()
        .map(|v| *v as f64)
        .sum::<f64>()
        / (n * n * n) as f64
        * vol.density_scale()
        / pyr.mean_sigma;
    // Levels 0–3 (σ ≤ 8 voxels; the blob and 3σ of filter fit in the 64³ box).
    for i in 0..4 {
        let m = pyr.mass(i);
        assert!((m / raw - 1.0).abs() < 1e-3, "level {i}: mass {m} vs {raw}");
    }
    assert_eq!(pyr.levels.last().unwrap().res, [1, 1, 1]);
}

#[test]
fn degenerate_inputs() {
    let l = Vec3::new(0.0, 1.0, 0.0);
    for v in [l, -l] {
        let (x, y, z) = frame(v, l);
        for a in [x, y, z] {
            assert!(a.is_finite() && (a.length() - 1.0).abs() < 1e-5);
        }
        assert!(x.dot(y).abs() < 1e-5 && x.dot(z).abs() < 1e-5);
    }
    let empty = Volume::new(
        DensityGrid::constant([4, 4, 4], 0.0).unwrap(),
        Aabb::new(DVec3::ZERO, DVec3::ONE).unwrap(),
        1.0,
    )
    .unwrap();
    assert!(matches!(Pyramid::new(&empty), Err(PyramidError::Empty)));
    // Rendering an empty cloud needs no descriptor: a unit-normalised, all-zero pyramid.
    let p = Pyramid::for_rendering(&empty).unwrap();
    assert_eq!(p.mean_sigma, 1.0);
    assert!(
        p.levels
            .iter()
            .all(|l| l.dense().is_none_or(|d| d.iter().all(|&v| v == 0.0)))
    );
}

/// Only the levels a stencil reads are stored, and they are the levels of the full build bit
/// for bit, from a dense grid and from the same grid as bricks; descriptors are unchanged.
#[test]
fn pyramid_stores_only_what_stencils_read() {
    // A 64×48×64 cumulus at density scale 2: a voxel is ≈ 0.01 mean free paths, so stencil
    // level 1 (h = 0.5 mean free paths ≈ 44 voxels) reads level 4.
    let res = [64, 48, 64];
    let g = generate::generate(nimbus_scene::CloudKind::Cumulus, 11, res).unwrap();
    let (lo, hi) = generate::default_aabb(res);
    let dense = Volume::new(g.clone(), Aabb::new(lo, hi).unwrap(), 2.0).unwrap();
    let data = g.as_dense().unwrap();
    let bricks =
        DensityGrid::from_bricks(nimbus_scene::brick::from_dense(res, data, [3, 0, 5]).unwrap());
    let sparse = Volume::new(bricks, Aabb::new(lo, hi).unwrap(), 2.0).unwrap();
    let full = Pyramid::with_every_level(&dense).unwrap();
    let first = full.level_for(1);
    assert!(first >= 2, "finest level read: {first}");
    for vol in [&dense, &sparse] {
        let p = Pyramid::new(vol).unwrap();
        assert_eq!(p.finest_stored(), first);
        assert_eq!(p.levels.len(), full.levels.len());
        for (i, (a, b)) in p.levels.iter().zip(&full.levels).enumerate() {
            assert_eq!(
                (a.res, a.sigma_voxels),
                (b.res, b.sigma_voxels),
                "level {i}"
            );
            if i < first {
                assert!(!a.is_stored(), "level {i} stored");
            } else {
                assert_eq!(a.cells, b.cells, "level {i}");
            }
        }
        // The finer levels held ≈ 8/7 of level 0's voxels; what is left is ≈ 1/7 of level
        // `first`'s share.
        assert!(
            p.bytes() * 50 < full.bytes(),
            "{} of {}",
            p.bytes(),
            full.bytes()
        );
        let mut r = rng(9);
        let (mut a, mut b) = (vec![0.0; DESCRIPTOR_LEN], vec![0.0; DESCRIPTOR_LEN]);
        for _ in 0..20 {
            let x = lo.as_vec3() + (hi - lo).as_vec3() * Vec3::new(r(), r(), r());
            let (v, l) = (dir(&mut r), dir(&mut r));
            descriptor(&p, x, v, l, &mut a);
            descriptor(&full, x, v, l, &mut b);
            assert_eq!(a, b);
        }
    }
}

/// A reused buffer: `descriptors_into` gives, row by row and bit for bit, what
/// `descriptor` gives for each configuration alone, whatever the buffer held before (NaN, or
/// the rows of other configurations) and however long it was (longer: cut; shorter: grown).
#[test]
fn descriptors_into_a_reused_buffer() {
    let vol = cloud([24, 16, 24]);
    let pyr = Pyramid::new(&vol).unwrap();
    let mut r = rng(9);
    let (lo, hi) = (vol.aabb().min.as_vec3(), vol.aabb().max.as_vec3());
    let configs: Vec<Config> = (0..72)
        .map(|_| Config {
            x: lo + (hi - lo) * Vec3::new(r(), r(), r()),
            view: dir(&mut r),
            to_light: dir(&mut r),
        })
        .collect();
    let mut buf = vec![f32::NAN; 30 * DESCRIPTOR_LEN];
    // 25 rows into 30 of NaN, then 40 other rows (grown), then 7 other rows (cut).
    for range in [0..25, 25..65, 65..72] {
        let batch = &configs[range.clone()];
        nimbus_rpnn::descriptor::descriptors_into(&pyr, batch, &mut buf);
        assert_eq!(buf.len(), batch.len() * DESCRIPTOR_LEN, "{range:?}");
        let mut want = vec![0.0f32; DESCRIPTOR_LEN];
        for (c, row) in batch.iter().zip(buf.chunks(DESCRIPTOR_LEN)) {
            descriptor(&pyr, c.x, c.view, c.to_light, &mut want);
            assert!(
                row.iter()
                    .zip(&want)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "{range:?}: a row of the reused buffer differs"
            );
        }
    }
}

/// The per-level sampler the descriptor reads against trilinear interpolation in f64 written
/// out here: on random points inside the box (and some outside: 0) of every stored level,
/// within 1e-5 of the level's largest value (f32 rounding of the weights, ≈ 1e-7). (That the
/// sampler is the earlier scalar lookup to the bit: `pyramid`'s unit test
/// `sparse_levels_hold_the_dense_values`.)
#[test]
fn level_sampler_is_trilinear_interpolation() {
    let vol = cloud([20, 12, 16]);
    let pyr = Pyramid::with_every_level(&vol).unwrap();
    let mut r = rng(21);
    let (lo, hi) = (vol.aabb().min, vol.aabb().max);
    for (i, l) in pyr.levels.iter().enumerate() {
        let Some(cells) = l.dense() else { continue };
        let top = cells.iter().fold(0.0f32, |m, v| m.max(*v)) as f64;
        let s = pyr.sampler(i);
        for _ in 0..400 {
            // ±10 % beyond the box on each side.
            let t = DVec3::new(r() as f64, r() as f64, r() as f64) * 1.2 - DVec3::splat(0.1);
            let p = (lo + (hi - lo) * t).as_vec3();
            let pd = p.as_dvec3();
            let inside = (0..3).all(|a| pd[a] >= lo[a] && pd[a] <= hi[a]);
            let want = if inside {
                let mut v = 0.0;
                let (mut c0, mut w) = ([0usize; 3], [0.0f64; 3]);
                for a in 0..3 {
                    let u = (pd[a] - lo[a]) / (hi[a] - lo[a]) * l.res[a] as f64 - 0.5;
                    let b = u.floor();
                    c0[a] = b as i64 as usize;
                    w[a] = u - b;
                    if b < 0.0 {
                        c0[a] = 0;
                        w[a] = 0.0;
                    }
                }
                for corner in 0..8 {
                    let mut weight = 1.0;
                    let mut idx = [0usize; 3];
                    for a in 0..3 {
                        let up = (corner >> a) & 1 == 1;
                        weight *= if up { w[a] } else { 1.0 - w[a] };
                        idx[a] = (c0[a] + up as usize).min(l.res[a] - 1);
                    }
                    v += weight * l.get(idx[0], idx[1], idx[2]) as f64;
                }
                v
            } else {
                0.0
            };
            let got = s.at(p) as f64;
            assert!(
                (got - want).abs() <= 1e-5 * top.max(1e-6),
                "level {i} at {p:?}: sampler {got}, trilinear {want}"
            );
        }
    }
}

/// One stencil level at a time (`LevelSampler::stencil_into`, AVX-512 gathers where the CPU has
/// them) equals the point-by-point lookups (`stencil_into_scalar` and `at` of each
/// `stencil_point`) to the bit: every stored level (down to one cell), random points, frames
/// and spacings from a hundredth of a cell to beyond the box (most points outside: 0). Exact
/// equality, because the vector code performs the same IEEE operations in the same order; on a
/// CPU without AVX-512 both calls take the scalar path and only the second comparison tests.
#[test]
fn stencil_levels_agree_with_point_lookups() {
    use nimbus_rpnn::descriptor::stencil_point;
    let vol = cloud([20, 12, 16]);
    let pyr = Pyramid::with_every_level(&vol).unwrap();
    let mut r = rng(33);
    let (lo, hi) = (vol.aabb().min.as_vec3(), vol.aabb().max.as_vec3());
    let size = (hi - lo).max_element();
    let (mut fast, mut slow) = ([0.0f32; POINTS], [0.0f32; POINTS]);
    let mut nonzero = 0;
    for (i, l) in pyr.levels.iter().enumerate() {
        assert!(l.dense().is_some(), "level {i} of a small cloud is dense");
        let s = pyr.sampler(i);
        for n in 0..200 {
            let t = Vec3::new(r(), r(), r()) * 1.2 - Vec3::splat(0.1);
            let x = lo + (hi - lo) * t;
            let (ex, ey, ez) = frame(dir(&mut r), dir(&mut r));
            let scale = size * 10f32.powf(-3.0 + 3.5 * r());
            s.stencil_into(x, [ex, ey, ez], scale, &mut fast);
            s.stencil_into_scalar(x, [ex, ey, ez], scale, &mut slow);
            for p in 0..POINTS {
                let q = stencil_point(p);
                let want = s.at(x + (ex * q.x + ey * q.y + ez * q.z) * scale);
                assert_eq!(
                    slow[p].to_bits(),
                    want.to_bits(),
                    "level {i}, case {n}, point {p}: scalar stencil {} against at() {want}",
                    slow[p]
                );
                assert_eq!(
                    fast[p].to_bits(),
                    want.to_bits(),
                    "level {i}, case {n}, point {p}: stencil {} against at() {want}",
                    fast[p]
                );
                nonzero += (want != 0.0) as usize;
            }
        }
    }
    // Most cases sample the cloud: the comparison is not one of zeros.
    assert!(nonzero > 100_000, "{nonzero} non-zero lookups");
    // Fixed cases random points miss: axis-aligned stencils whose points fall exactly on the
    // box's faces (x one spacing inside the low corner: its first points are at lo; one
    // spacing inside the high corner: some are at hi), and positions or spacings that are not
    // finite (every point 0 on both paths).
    let axes = [Vec3::X, Vec3::Y, Vec3::Z];
    let h = 1.0 / 16.0;
    let cases = [
        (lo + Vec3::splat(h), h),
        (hi - Vec3::splat(h), h),
        (hi - Vec3::new(h, h, 3.0 * h), h),
        (Vec3::splat(f32::NAN), h),
        (Vec3::ZERO, f32::INFINITY),
        (Vec3::ZERO, f32::NAN),
    ];
    let mut on_face = 0;
    for i in 0..pyr.levels.len() {
        let s = pyr.sampler(i);
        for (n, &(x, scale)) in cases.iter().enumerate() {
            s.stencil_into(x, axes, scale, &mut fast);
            for (p, got) in fast.iter().enumerate() {
                let q = stencil_point(p);
                let pt = x + (axes[0] * q.x + axes[1] * q.y + axes[2] * q.z) * scale;
                on_face += ((pt.cmpeq(lo) | pt.cmpeq(hi)).any()
                    && pt.cmpge(lo).all()
                    && pt.cmple(hi).all()) as usize;
                let want = s.at(pt);
                assert_eq!(
                    got.to_bits(),
                    want.to_bits(),
                    "level {i}, fixed case {n}, point {p} at {pt:?}: stencil {got} against at() {want}"
                );
            }
        }
    }
    assert!(on_face > 100, "{on_face} points on the box's faces");
    #[cfg(target_arch = "x86_64")]
    eprintln!(
        "stencil levels: AVX-512 {}",
        if std::arch::is_x86_feature_detected!("avx512f") {
            "used (the vector code was compared)"
        } else {
            "absent (scalar against scalar)"
        }
    );
}
