//! Procedural clouds with seeds (Kallweit 2017 §3.1 names the three families).
//!
//! - [`CloudKind::Cumulus`]: a heap of overlapping spheres on a flat base, eroded at the boundary
//!   by fractal Perlin noise and billowy (inverted Worley) detail — fluffy heaps with sharp edges.
//! - [`CloudKind::Stratus`]: a flat sheet whose top and bottom undulate with low-frequency noise,
//!   with gentle interior variation — a hazy, featureless layer.
//! - [`CloudKind::Cirrus`]: thin filaments: ridged multifractal noise stretched along a wind
//!   direction in a thin layer — wispy strands.
//! - [`CloudKind::Congestus`]: a towering cumulus with detail at every scale: a coarse heap of
//!   blobs (a base row and a tower) whose surface is displaced by Perlin–Worley noise and two
//!   finer octaves of cellular billows (cauliflower tops), eroded at the edges by fine cellular
//!   detail that is wispy near the flat base and billowy above — the production recipe of
//!   Schneider & Vos 2015 applied to a shape (see `cellular.rs`). `cumulus` keeps the smooth heap
//!   that the shipped network's first training set and the bench clouds were generated with
//!   (the network's last stage adds a set of a third congestus).
//!
//! All grids are normalised so that their maximum is 1 (the scene's `density_scale` then sets
//! σ_t), and the outermost voxel layer is zero so the cloud never touches its box. Generation is
//! deterministic for a given kind, seed and resolution (on any thread count). Grids of more than
//! [`SPARSE_ABOVE_VOXELS`] come out as 8³ bricks (`crate::brick`) holding only the bricks the
//! cloud reaches; the values are those of the dense path, bit for bit.

use std::str::FromStr;

use noise::{Fbm, MultiFractal, NoiseFn, Perlin, RidgedMulti, Worley};
use rayon::prelude::*;

use crate::error::FieldError;
use crate::grid::{DensityGrid, check_resolution};

mod cellular;
mod heap;
#[cfg(unix)]
mod stream;
#[cfg(unix)]
pub use stream::generate_vol;

/// [`generate`] written to a `.vol` file (streamed on unix, see `generate::stream`).
#[cfg(not(unix))]
pub fn generate_vol(
    kind: CloudKind,
    seed: u64,
    res: [usize; 3],
    path: &std::path::Path,
    bounds: (glam::DVec3, glam::DVec3),
) -> crate::error::Result<crate::grid::GridStats> {
    let grid = generate(kind, seed, res).map_err(|e| e.at(path))?;
    crate::io::vol::write(path, &grid, bounds)?;
    Ok(grid.stats())
}
use cellular::{Cellular, perlin_worley};
use heap::{Early, Heap, Measure, Octaves, Tile};

/// The cloud families of the generator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CloudKind {
    Cumulus,
    Stratus,
    Cirrus,
    Congestus,
}

impl CloudKind {
    pub const ALL: [CloudKind; 4] = [
        CloudKind::Cumulus,
        CloudKind::Stratus,
        CloudKind::Cirrus,
        CloudKind::Congestus,
    ];

    pub fn name(self) -> &'static str {
        match self {
            CloudKind::Cumulus => "cumulus",
            CloudKind::Stratus => "stratus",
            CloudKind::Cirrus => "cirrus",
            CloudKind::Congestus => "congestus",
        }
    }

    /// A resolution with the family's usual proportions and `n` voxels along x.
    pub fn default_resolution(self, n: usize) -> [usize; 3] {
        match self {
            CloudKind::Cumulus | CloudKind::Congestus => [n, n * 3 / 4, n],
            CloudKind::Stratus => [n, (n / 4).max(4), n],
            CloudKind::Cirrus => [n, (n / 4).max(4), n],
        }
    }
}

impl FromStr for CloudKind {
    type Err = FieldError;
    fn from_str(s: &str) -> Result<Self, FieldError> {
        match s.to_ascii_lowercase().as_str() {
            "cumulus" => Ok(CloudKind::Cumulus),
            "stratus" => Ok(CloudKind::Stratus),
            "cirrus" | "wispy" => Ok(CloudKind::Cirrus),
            "congestus" | "cumulus-congestus" => Ok(CloudKind::Congestus),
            other => Err(FieldError::new(
                "kind",
                format!(
                    "unknown cloud kind `{other}` (expected cumulus, stratus, cirrus or congestus)"
                ),
            )),
        }
    }
}

/// SplitMix64: seeds the layout randomness from the user's seed.
struct SplitMix(u64);
impl SplitMix {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e3779b97f4a7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58476d1ce4e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d049bb133111eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.next()
    }
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The density at a point of a tile (see [`Tile`]).
type Field = Box<dyn Fn([f64; 3], &Tile) -> f64>;

/// `plan(c, h, tile)`: true when the field is 0 everywhere within distance `h` of `c` (a bound
/// from the cloud's shape alone, so empty space costs no noise evaluation); otherwise fills
/// `tile` with what the shape says about that ball (see [`Tile`]).
type Plan = Box<dyn Fn([f64; 3], f64, &mut Tile) -> bool>;

/// Builds the density function of a cloud in normalised coordinates (x in [−1, 1], y ≥ 0, z
/// centred; cubic voxels), and its empty-space test. `noise` types are not `Sync`, so each
/// worker builds its own.
/// `fast` turns on the shortcuts that skip noise where it cannot change the value (off: every
/// voxel evaluates the whole formula; the same grid, as `generate_with`'s test checks).
fn make_field(kind: CloudKind, seed: u64, res: [usize; 3], fast: bool) -> (Field, Option<Plan>) {
    let s32 = (seed ^ (seed >> 32)) as u32;
    let mut rng = SplitMix(seed);
    // Normalised coordinates: x, z in [−1, 1]; y in [0, ry/rx × 2] (voxels are cubes).
    let scale = 2.0 / res[0] as f64;
    let height = res[1] as f64 * scale;
    let depth = res[2] as f64 * scale;
    match kind {
        CloudKind::Cumulus => {
            let n_blobs = 6 + (rng.next() * 6.0) as usize;
            let mut blobs = Vec::new();
            let base = 0.12 * height;
            for i in 0..n_blobs {
                // Larger blobs low and central, smaller ones on top and at the sides.
                let t = i as f64 / n_blobs as f64;
                let r = rng.range(0.28, 0.45) * (1.0 - 0.35 * t) * height.min(depth).min(2.0) / 1.5;
                let cx = rng.range(-0.55, 0.55) * (1.0 - 0.3 * t);
                let cz = rng.range(-0.45, 0.45) * depth / 2.0 * (1.0 - 0.3 * t);
                let cy = base + r * rng.range(0.6, 1.0) + t * 0.35 * height;
                blobs.push(([cx, cy, cz], r));
            }
            let octaves = Octaves::new(s32, 5, 2.5);
            let worley = Worley::new(s32.wrapping_add(7)).set_frequency(6.0);
            // v = shape + 0.35 n + 0.12 (billow − ½) with |n| ≤ 1 (Perlin is clamped to
            // [−1, 1] and fBm divides by the sum of its amplitudes) and billow in [0, 1]: v ≤
            // shape + 0.41, so where shape < −0.45 the density is exactly 0, and where shape >
            // ⅓ + 0.41 it is `flat` (v × 3 is clamped to [0, 1]).
            const DEEP: f64 = 1.0 / 3.0 + 0.41 + 1e-9;
            let bound = Heap {
                blobs: blobs.clone(),
                measure: Measure::Shape,
            };
            let plan: Plan = Box::new(move |c: [f64; 3], h: f64, tile: &mut Tile| {
                if c[1] + h < base - 0.02 {
                    return true; // below the flat base
                }
                let (lower, upper) = bound.plan(c, h, tile);
                tile.inside = lower > DEEP + 1e-9;
                upper < -0.45
            });
            let heap = Heap {
                blobs,
                measure: Measure::Shape,
            };
            let field: Field = Box::new(move |p: [f64; 3], tile: &Tile| {
                // Flat base: fade out below the base plane.
                let flat = smoothstep(base - 0.02, base + 0.04, p[1]);
                if fast && tile.inside {
                    return flat;
                }
                let shape = heap.at(p, tile);
                // The noise only matters where it can move v across [0, ⅓]; |0.35 n| ≤ 0.35
                // and |0.12 (billow − ½)| ≤ 0.06, so far outside and deep inside the heap the
                // value is known without evaluating them, and the fBm's octaves stop once the
                // rest cannot move u across [−0.06, ⅓ + 0.06] (margins of 10⁻⁹ keep this exact
                // under rounding; `generate_with` tests it).
                if fast && (flat == 0.0 || shape < -0.41 - 1e-9) {
                    return 0.0;
                }
                if fast && shape > DEEP {
                    return flat;
                }
                let (below, above) = (-0.06 - 1e-9, 1.0 / 3.0 + 0.06 + 1e-9);
                let n = if fast {
                    match octaves.get_unless(p, shape, 0.35, below, above) {
                        Early::Below => return 0.0,
                        Early::Above => return flat,
                        Early::Value(n) => n,
                    }
                } else {
                    octaves.get(p)
                };
                let u = shape + 0.35 * n;
                if fast && u < below {
                    return 0.0;
                }
                if fast && u > above {
                    return flat;
                }
                let billow = 1.0 - worley.get(p).abs().min(1.0);
                let v = u + 0.12 * (billow - 0.5);
                (v * 3.0).clamp(0.0, 1.0) * flat
            });
            (field, Some(plan))
        }
        CloudKind::Congestus => {
            // A base row of wide blobs sitting on the flat base, and a tower of shrinking blobs
            // drifting upward from it (radii relative to the box's smaller side).
            let span = height.min(depth).min(2.0);
            let base = 0.08 * height;
            // Distances below are in the normalised units (x spans 2). The billows move the
            // surface by at most NOISE (the halves of their weights); EDGE is the width over
            // which the density rises from 0 to 1 at the surface.
            const NOISE: f64 = 0.12 + 0.06 + 0.03;
            const EDGE: f64 = 0.03;
            let mut blobs = Vec::new();
            for _ in 0..4 + (rng.next() * 3.0) as usize {
                let r = rng.range(0.2, 0.3) * span;
                let cx = rng.range(-0.6, 0.6) * (1.0 - r);
                let cz = rng.range(-0.3, 0.3) * depth / 2.0;
                blobs.push(([cx, base + 0.6 * r, cz], r));
            }
            let n_tower = 3 + (rng.next() * 4.0) as usize;
            let (mut tx, mut tz) = (rng.range(-0.2, 0.2), rng.range(-0.1, 0.1) * depth);
            for i in 0..n_tower {
                let t = (i + 1) as f64 / n_tower as f64;
                let r = (0.27 - 0.12 * t) * span;
                tx += rng.range(-0.1, 0.1);
                tz += rng.range(-0.06, 0.06) * depth;
                // The top blob's crown, bulges included, stays below 95 % of the box height.
                let top = 0.95 * height - r - NOISE;
                let cy = (base + 0.6 * r + t * (top - base)).min(top);
                blobs.push(([tx, cy, tz], r));
            }
            let perlin = Fbm::<Perlin>::new(s32).set_octaves(3).set_frequency(2.0);
            let cells = [1u64, 2, 3, 4].map(|k| Cellular::new(seed.wrapping_add(k)));
            let bound = Heap {
                blobs: blobs.clone(),
                measure: Measure::Depth,
            };
            let plan: Plan = Box::new(move |c: [f64; 3], h: f64, tile: &mut Tile| {
                if c[1] + h < base - 0.01 {
                    return true;
                }
                let (lower, upper) = bound.plan(c, h, tile);
                tile.inside = lower > EDGE + NOISE + 2e-9;
                upper < -NOISE - 0.01
            });
            let heap = Heap {
                blobs,
                measure: Measure::Depth,
            };
            let field: Field = Box::new(move |p: [f64; 3], tile: &Tile| {
                let flat = smoothstep(base - 0.01, base + 0.03, p[1]);
                if fast && tile.inside {
                    return flat;
                }
                let depth_in = heap.at(p, tile);
                // v = depth + the billows; density v / EDGE clamped to [0, 1], then eroded by
                // `(d − e) / (1 − e)`, which leaves d = 1 at 1: where the depth alone puts v
                // beyond EDGE whatever the noise, the value is `flat` (exact shortcut).
                if fast && (flat == 0.0 || depth_in < -NOISE - 1e-9) {
                    return 0.0;
                }
                if fast && depth_in > EDGE + NOISE + 1e-9 {
                    return flat;
                }
                let at = |f: f64| p.map(|v| v * f);
                // Coarse: Perlin–Worley (connected billowy masses); then cauliflower billows
                // at two finer scales, each bulging by about half its cell.
                let pw = perlin_worley(
                    (0.5 + 0.5 * perlin.get(p)).clamp(0.0, 1.0),
                    cells[0].billow(at(4.0)),
                );
                let v = depth_in
                    + 0.24 * (pw - 0.5)
                    + 0.12 * (cells[1].billow(at(8.0)) - 0.5)
                    + 0.06 * (cells[2].billow(at(16.0)) - 0.5);
                let d = (v / EDGE).clamp(0.0, 1.0);
                if d == 0.0 {
                    return 0.0;
                }
                // Edge erosion by fine cellular detail: wispy (F1) near the base, billowy
                // (1 − F1²) higher up (Schneider 2015).
                let hf = smoothstep(0.0, 0.4 * height, p[1] - base);
                let b = cells[3].billow(at(24.0));
                let e = 0.35 * ((1.0 - b) * (1.0 - hf) + b * hf);
                ((d - e) / (1.0 - e)).clamp(0.0, 1.0) * flat
            });
            (field, Some(plan))
        }
        CloudKind::Stratus => {
            let top = Fbm::<Perlin>::new(s32).set_octaves(4).set_frequency(1.5);
            let bottom = Fbm::<Perlin>::new(s32.wrapping_add(1))
                .set_octaves(3)
                .set_frequency(1.2);
            let inner = Fbm::<Perlin>::new(s32.wrapping_add(2))
                .set_octaves(4)
                .set_frequency(4.0);
            let mid = 0.5 * height;
            let thick = 0.3 * height;
            let field: Field = Box::new(move |p: [f64; 3], _: &Tile| {
                let t = mid + thick * (0.55 + 0.35 * top.get([p[0], 0.0, p[2]]));
                let b = mid - thick * (0.55 + 0.25 * bottom.get([p[0], 5.0, p[2]]));
                let edge = 0.04 * height;
                let v = smoothstep(b - edge, b + edge, p[1])
                    * (1.0 - smoothstep(t - edge, t + edge, p[1]));
                let rim = 1.0 - smoothstep(0.8, 0.98, p[0].abs().max(p[2].abs() * 2.0 / depth));
                v * rim * (0.75 + 0.25 * inner.get(p)).clamp(0.0, 1.0)
            });
            (field, None)
        }
        CloudKind::Cirrus => {
            let angle = rng.range(0.0, std::f64::consts::PI);
            let (ca, sa) = (angle.cos(), angle.sin());
            let ridged = RidgedMulti::<Perlin>::new(s32)
                .set_octaves(4)
                .set_frequency(1.0);
            let warp = Fbm::<Perlin>::new(s32.wrapping_add(3))
                .set_octaves(3)
                .set_frequency(1.5);
            let layer = Fbm::<Perlin>::new(s32.wrapping_add(4))
                .set_octaves(2)
                .set_frequency(1.0);
            let mid = 0.5 * height;
            let field: Field = Box::new(move |p: [f64; 3], _: &Tile| {
                // Streak frame: stretched along the wind direction (u), thin across (v) and in y.
                let u = ca * p[0] + sa * p[2];
                let v = -sa * p[0] + ca * p[2];
                let w = warp.get([u, p[1], v]);
                let q = [u * 0.8, (p[1] - mid) * 6.0, v * 6.0 + 0.8 * w];
                let r = ridged.get(q);
                let centre = mid + 0.25 * height * layer.get([p[0], 0.0, p[2]]);
                let thin = 1.0 - smoothstep(0.0, 0.3 * height, (p[1] - centre).abs());
                let rim = 1.0 - smoothstep(0.75, 0.98, p[0].abs().max(p[2].abs() * 2.0 / depth));
                (smoothstep(0.55, 1.0, r) * thin * rim).clamp(0.0, 1.0)
            });
            (field, None)
        }
    }
}

pub use crate::brick::SPARSE_ABOVE_VOXELS;

/// Generates a cloud of `kind` with `seed` at resolution `res` (voxels along x, y, z), dense or
/// as bricks (see [`SPARSE_ABOVE_VOXELS`]).
pub fn generate(kind: CloudKind, seed: u64, res: [usize; 3]) -> Result<DensityGrid, FieldError> {
    let sparse = res
        .iter()
        .try_fold(1usize, |n, &r| n.checked_mul(r))
        .is_none_or(|n| n > SPARSE_ABOVE_VOXELS);
    generate_with(kind, seed, res, true, sparse)
}

/// Tiles of T×T voxels in x, y: a tile whose every voxel the shape puts in empty space is
/// skipped without evaluating noise (cumulus: most of the box).
const T: usize = 8;

/// Fills z slice `z` (x fastest, `slice.len()` = nx × ny, zero on entry) of a cloud.
fn fill_slice(field: &Field, plan: &Option<Plan>, res: [usize; 3], z: usize, slice: &mut [f32]) {
    let [nx, ny, nz] = res;
    if z == 0 || z == nz - 1 {
        return;
    }
    let scale = 2.0 / nx as f64;
    let depth = nz as f64 * scale;
    let half = (2.0 * (T as f64 / 2.0).powi(2) + 0.25).sqrt() * scale;
    let pz = (z as f64 + 0.5) * scale - depth / 2.0;
    // Without a plan, every voxel evaluates the whole formula.
    let mut tile = Tile::everything();
    for ty in (0..ny).step_by(T) {
        for tx in (0..nx).step_by(T) {
            if let Some(plan) = plan {
                let c = [
                    (tx as f64 + T as f64 / 2.0) * scale - 1.0,
                    (ty as f64 + T as f64 / 2.0) * scale,
                    pz,
                ];
                if plan(c, half, &mut tile) {
                    continue;
                }
            }
            for y in ty.max(1)..(ty + T).min(ny - 1) {
                for x in tx.max(1)..(tx + T).min(nx - 1) {
                    let p = [(x as f64 + 0.5) * scale - 1.0, (y as f64 + 0.5) * scale, pz];
                    slice[y * nx + x] = field(p, &tile).max(0.0) as f32;
                }
            }
        }
    }
}

/// The resolutions a generator accepts (`field` names the setting in errors): at least 4
/// voxels per axis, and within the dense or the sparse (brick) grid's limits.
pub fn check_generator_resolution(
    res: [i64; 3],
    sparse: bool,
    field: &str,
) -> Result<[usize; 3], FieldError> {
    let res = if sparse {
        crate::brick::check_sparse_resolution(res, field)?
    } else {
        check_resolution(res, field)?
    };
    if res.iter().any(|&r| r < 4) {
        return Err(FieldError::new(
            field,
            format!("procedural clouds need at least 4 voxels per axis, got {res:?}"),
        ));
    }
    Ok(res)
}

/// [`generate`], with the shortcuts that skip empty space and unneeded noise on or off, dense or
/// sparse (the same values every way).
fn generate_with(
    kind: CloudKind,
    seed: u64,
    res: [usize; 3],
    fast: bool,
    sparse: bool,
) -> Result<DensityGrid, FieldError> {
    let res = check_generator_resolution(res.map(|r| r as i64), sparse, "resolution")?;
    let [nx, ny, nz] = res;
    let what = format!("a {nx}×{ny}×{nz} grid");
    let init = || {
        let (field, plan) = make_field(kind, seed, res, fast);
        (field, plan.filter(|_| fast))
    };
    let empty = || {
        FieldError::new(
            "seed",
            format!(
                "{} with seed {seed} at {res:?} came out empty; try another seed",
                kind.name()
            ),
        )
    };
    if sparse {
        return generate_bricks(res, &what, init, empty);
    }
    let mut data = crate::memory::filled(nx * ny * nz, 0.0f32, "resolution", &what)?;
    // One z slice per task.
    data.par_chunks_mut(nx * ny)
        .enumerate()
        .for_each_init(init, |(field, plan), (z, slice)| {
            fill_slice(field, plan, res, z, slice)
        });
    let max = data.iter().cloned().fold(0.0f32, f32::max);
    if max <= 0.0 {
        return Err(empty());
    }
    data.iter_mut().for_each(|v| *v /= max);
    DensityGrid::new(res, data)
}

/// The sparse path of [`generate_with`]: one slab of 8 z slices per task, cut into 8³ bricks
/// of which only those holding a non-zero voxel are kept; then normalised by the maximum (the
/// same f32 division as the dense path) into a [`BrickBuilder`](crate::brick::BrickBuilder).
fn generate_bricks(
    res: [usize; 3],
    what: &str,
    init: impl Fn() -> (Field, Option<Plan>) + Sync + Send,
    empty: impl Fn() -> FieldError,
) -> Result<DensityGrid, FieldError> {
    use crate::brick::{BrickBuilder, DIM, VOXELS};
    let [nx, ny, nz] = res;
    let (bx, by, bz) = (nx.div_ceil(DIM), ny.div_ceil(DIM), nz.div_ceil(DIM));
    // Before any noise: the bricks the cloud can reach at most (those the shape's bound does
    // not rule out; every brick for kinds without one), held twice at the end (the slabs' copies
    // and the grid), plus the index, against the memory budget.
    let scale = 2.0 / nx as f64;
    let depth = nz as f64 * scale;
    let half = (3.0 * (DIM as f64 / 2.0).powi(2)).sqrt() * scale;
    let reachable: usize = (0..bz)
        .into_par_iter()
        .map_init(
            || (init().1, Tile::default()),
            |(plan, tile), k| {
                let Some(plan) = plan else {
                    return bx * by;
                };
                let mut n = 0;
                for j in 0..by {
                    for i in 0..bx {
                        let c = [
                            (i as f64 + 0.5) * DIM as f64 * scale - 1.0,
                            (j as f64 + 0.5) * DIM as f64 * scale,
                            (k as f64 + 0.5) * DIM as f64 * scale - depth / 2.0,
                        ];
                        n += usize::from(!plan(c, half, tile));
                    }
                }
                n
            },
        )
        .sum();
    crate::memory::check(
        (bx * by * bz) as u128 * 4 + 2 * reachable as u128 * (VOXELS as u128 * 4),
        "resolution",
        &format!(
            "{what} (as 8³ bricks: {reachable} the cloud can reach, of {})",
            bx * by * bz
        ),
    )?;
    // Each slab: the non-zero bricks (their x, y brick coordinates and values) and its maximum.
    // Each slab: the x, y brick coordinates of its non-zero bricks, their values (512 per
    // brick, one allocation per slab) and its maximum.
    type Slab = (Vec<(usize, usize)>, Vec<f32>, f32);
    let mut slabs: Vec<Slab> = (0..bz)
        .into_par_iter()
        .map_init(
            || (init(), Vec::new()),
            |((field, plan), slab), k| {
                // One slab buffer per worker, zeroed here (cheaper than fresh pages per slab).
                slab.clear();
                slab.resize(nx * ny * DIM, 0.0f32);
                for (l, slice) in slab.chunks_mut(nx * ny).enumerate() {
                    let z = k * DIM + l;
                    if z < nz {
                        fill_slice(field, plan, res, z, slice);
                    }
                }
                let (mut kept, mut values) = (Vec::new(), Vec::new());
                let mut max = 0.0f32;
                for j in 0..by {
                    for i in 0..bx {
                        let start = values.len();
                        values.resize(start + VOXELS, 0.0f32);
                        let v = &mut values[start..];
                        let mut any = false;
                        for l in 0..DIM {
                            for y in j * DIM..((j + 1) * DIM).min(ny) {
                                let row = (l * ny + y) * nx;
                                let x0 = i * DIM;
                                let x1 = ((i + 1) * DIM).min(nx);
                                let dst = (l * DIM + (y - j * DIM)) * DIM;
                                for (d, &s) in v[dst..dst + x1 - x0]
                                    .iter_mut()
                                    .zip(&slab[row + x0..row + x1])
                                {
                                    *d = s;
                                    any |= s != 0.0;
                                    max = max.max(s);
                                }
                            }
                        }
                        if any {
                            kept.push((i, j));
                        } else {
                            values.truncate(start);
                        }
                    }
                }
                (kept, values, max)
            },
        )
        .collect();
    let max = slabs.iter().map(|s| s.2).fold(0.0f32, f32::max);
    if max <= 0.0 {
        return Err(empty());
    }
    let kept = slabs.iter().map(|s| s.0.len()).sum();
    let mut builder = BrickBuilder::new(res, [0; 3], kept, "resolution", what)?;
    // Normalised in parallel, then copied into the builder in brick order.
    slabs
        .par_iter_mut()
        .for_each(|(_, values, _)| values.iter_mut().for_each(|x| *x /= max));
    for (k, (kept, values, _)) in slabs.into_iter().enumerate() {
        for (&(i, j), v) in kept.iter().zip(values.chunks_exact(VOXELS)) {
            builder.stored_mut([i, j, k])?.copy_from_slice(v);
        }
    }
    Ok(DensityGrid::from_bricks(builder.finish()?))
}

/// The world box a generated grid fills by default: centred at the origin, 2 units along x,
/// with cubic voxels.
pub fn default_aabb(res: [usize; 3]) -> (glam::DVec3, glam::DVec3) {
    let s = 2.0 / res[0] as f64;
    let half = glam::DVec3::new(1.0, res[1] as f64 * s / 2.0, res[2] as f64 * s / 2.0);
    (-half, half)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deterministic_and_distinct() {
        for kind in CloudKind::ALL {
            let res = kind.default_resolution(32);
            let a = generate(kind, 3, res).unwrap();
            let b = generate(kind, 3, res).unwrap();
            let c = generate(kind, 4, res).unwrap();
            assert_eq!(a, b);
            assert_ne!(a, c);
            let s = a.stats();
            assert_eq!(s.max, 1.0);
            // Clouds, not fog: part of the box is empty, part is filled.
            assert!(
                s.nonzero_fraction > 0.01 && s.nonzero_fraction < 0.9,
                "{kind:?} {s:?}"
            );
        }
    }

    #[test]
    fn skipping_empty_space_changes_nothing() {
        // The shape bound is exact (|noise| ≤ 1 by construction), so the grids are equal
        // bit for bit, while most of a cumulus box is skipped.
        for seed in [1, 7, 42] {
            let res = [72, 54, 72];
            for kind in [CloudKind::Cumulus, CloudKind::Congestus] {
                let a = generate_with(kind, seed, res, true, false).unwrap();
                let b = generate_with(kind, seed, res, false, false).unwrap();
                assert!(a == b, "{kind:?} seed {seed}");
            }
        }
    }

    #[test]
    fn sparse_generation_gives_the_same_values() {
        // Resolutions not multiples of 8 exercise the edge bricks.
        for kind in CloudKind::ALL {
            let res = [44, 21, 37];
            let d = generate_with(kind, 5, res, true, false).unwrap();
            let s = generate_with(kind, 5, res, true, true).unwrap();
            assert!(d.as_dense().is_some() && s.as_bricks().is_some());
            for z in 0..res[2] {
                for y in 0..res[1] {
                    for x in 0..res[0] {
                        assert_eq!(
                            d.get(x, y, z).to_bits(),
                            s.get(x, y, z).to_bits(),
                            "{kind:?}"
                        );
                    }
                }
            }
            assert_eq!(d.stats().max, s.stats().max);
            // The heaps leave most of their box empty, which is absent: fewer bytes than the
            // dense grid (a thin sheet or filaments reach most bricks of so small a box).
            if matches!(kind, CloudKind::Cumulus | CloudKind::Congestus) {
                assert!(
                    s.bytes() < d.bytes(),
                    "{kind:?}: {} vs {}",
                    s.bytes(),
                    d.bytes()
                );
            }
        }
    }

    #[test]
    fn congestus_sits_on_a_flat_base() {
        // The lowest filled layer (density > ½) of a congestus is nearly as wide as its widest
        // layer (≥ 0.6×; measured 0.79–0.85 on seeds 1–3), while the sphere heap of `cumulus`
        // rests on the base with a few caps (0.06–0.15).
        let layers = |kind, seed| {
            let g = generate(kind, seed, [64, 48, 64]).unwrap();
            let mut per = [0usize; 48];
            for z in 0..64 {
                for (y, n) in per.iter_mut().enumerate() {
                    *n += (0..64).filter(|&x| g.get(x, y, z) > 0.5).count();
                }
            }
            let first = per.iter().copied().find(|&n| n > 0).unwrap();
            first as f64 / *per.iter().max().unwrap() as f64
        };
        for seed in 1..=3 {
            let (co, cu) = (
                layers(CloudKind::Congestus, seed),
                layers(CloudKind::Cumulus, seed),
            );
            assert!(
                co >= 0.6 && cu < 0.3,
                "seed {seed}: congestus {co}, cumulus {cu}"
            );
        }
    }

    #[test]
    fn families_have_their_shapes() {
        // Cumulus is heaped (much taller than a stratus sheet relative to its filled area);
        // cirrus is sparse.
        let cu = generate(CloudKind::Cumulus, 1, [32, 24, 32])
            .unwrap()
            .stats();
        let ci = generate(CloudKind::Cirrus, 1, [32, 8, 32]).unwrap().stats();
        let st = generate(CloudKind::Stratus, 1, [32, 8, 32])
            .unwrap()
            .stats();
        assert!(st.nonzero_fraction > ci.nonzero_fraction);
        assert!(st.mean > ci.mean);
        assert!(cu.nonzero_fraction > 0.02);
        assert!("wispy".parse::<CloudKind>().unwrap() == CloudKind::Cirrus);
        assert!("fog".parse::<CloudKind>().is_err());
        assert!(generate(CloudKind::Cumulus, 1, [2, 8, 8]).is_err());
    }
}
