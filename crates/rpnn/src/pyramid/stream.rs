//! The pyramid's filters, streamed plane by plane (Kallweit 2017 §4.2; see the parent module).
//!
//! A level is produced one z-plane at a time by a chain of [`Planes`] stages: the grid's planes
//! ([`GridPlanes`], scaled), the σ = 1 blur of level 0 ([`Blur`]) and, per coarser level, the
//! σ = √3 blur followed by halving ([`Down`]). Each stage keeps only the window of input planes
//! its kernel reaches, so a level that no stencil reads is streamed through and never stored,
//! and the peak memory is the stored levels plus a few planes. The arithmetic (operands and
//! their order) is that of whole-grid separable blurs followed by the downsampling: the values
//! are the same to the bit (tests in the parent module).

use std::collections::BTreeMap;

use nimbus_scene::{DensityGrid, FieldError};
use rayon::prelude::*;

pub(super) fn gauss_kernel(sigma: f64) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as i64;
    let w: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = w.iter().sum();
    w.into_iter().map(|v| (v / s) as f32).collect()
}

/// Inclusive x and y bounds of a plane's non-zero values (a bound: it may hold zeros too).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Rect {
    x: [usize; 2],
    y: [usize; 2],
}

impl Rect {
    /// The exact bounds of the non-zero values of a plane `nx` wide (None: all zero).
    fn of(data: &[f32], nx: usize) -> Option<Rect> {
        Self::of_within(data, nx, [0, nx - 1], [0, data.len() / nx - 1])
    }

    /// The exact bounds of the non-zero values within columns `xs` and rows `ys` (inclusive)
    /// of a plane `nx` wide.
    fn of_within(data: &[f32], nx: usize, xs: [usize; 2], ys: [usize; 2]) -> Option<Rect> {
        let mut r: Option<Rect> = None;
        for y in ys[0]..=ys[1] {
            let row = &data[y * nx + xs[0]..=y * nx + xs[1]];
            let Some(x0) = row.iter().position(|&v| v != 0.0) else {
                continue;
            };
            let x1 = row
                .iter()
                .rposition(|&v| v != 0.0)
                .expect("a non-zero value");
            let (x0, x1) = (x0 + xs[0], x1 + xs[0]);
            r = Some(match r {
                None => Rect {
                    x: [x0, x1],
                    y: [y, y],
                },
                Some(q) => Rect {
                    x: [q.x[0].min(x0), q.x[1].max(x1)],
                    y: [q.y[0], y],
                },
            });
        }
        r
    }

    /// Grown by `r` cells on every side, clamped to `nx` × `ny`.
    fn grow(self, r: usize, nx: usize, ny: usize) -> Rect {
        Rect {
            x: [self.x[0].saturating_sub(r), (self.x[1] + r).min(nx - 1)],
            y: [self.y[0].saturating_sub(r), (self.y[1] + r).min(ny - 1)],
        }
    }

    fn union(a: Option<Rect>, b: Option<Rect>) -> Option<Rect> {
        match (a, b) {
            (Some(a), Some(b)) => Some(Rect {
                x: [a.x[0].min(b.x[0]), a.x[1].max(b.x[1])],
                y: [a.y[0].min(b.y[0]), a.y[1].max(b.y[1])],
            }),
            (a, None) => a,
            (None, b) => b,
        }
    }
}

/// One z-plane of a level (x fastest) and a bound of where it is non-zero.
pub(super) struct Plane {
    pub(super) data: Vec<f32>,
    rect: Option<Rect>,
    nx: usize,
    /// A bound of the values whose bits may differ from +0 (`rect` and any −0 the input held
    /// outside it): what a recycled buffer must clear.
    dirty: Option<Rect>,
}

// Recycled plane buffers. A level's planes are all one size; a dropped plane's buffer is
// zeroed again only within its `dirty` bound (where its bits can differ from +0), so a mostly
// empty plane of a large sparse box is not cleared whole for every z. Planes are made and
// dropped on the thread that drives the stream (never inside the rayon closures, which only
// fill rows), so one pool serves a build; `release_planes` empties it when the build ends.
/// A recycled buffer: its values, the plane's width and its `dirty` bound.
type Recycled = (Vec<f32>, usize, Option<Rect>);

thread_local! {
    static POOL: std::cell::RefCell<Vec<Recycled>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Most buffers the pool keeps (a few planes' worth beyond the filters' windows).
pub(super) const POOL_MAX: usize = 16;

/// A buffer of `nx × ny` zeros, recycled when the pool has one of that shape.
fn zeroed(nx: usize, ny: usize) -> Vec<f32> {
    let n = nx * ny;
    let got = POOL.with(|p| {
        let mut p = p.borrow_mut();
        let i = p.iter().position(|(b, w, _)| b.len() == n && *w == nx)?;
        Some(p.swap_remove(i))
    });
    match got {
        Some((mut b, _, rect)) => {
            if let Some(r) = rect {
                for y in r.y[0]..=r.y[1] {
                    b[y * nx + r.x[0]..=y * nx + r.x[1]].fill(0.0);
                }
            }
            debug_assert!(
                b.iter().all(|&v| v.to_bits() == 0),
                "a plane held values outside its dirty bound"
            );
            b
        }
        None => vec![0.0f32; n],
    }
}

/// Frees the recycled plane buffers of this thread.
pub(super) fn release_planes() {
    POOL.with(|p| p.borrow_mut().clear());
}

impl Drop for Plane {
    fn drop(&mut self) {
        let data = std::mem::take(&mut self.data);
        if data.is_empty() || self.nx == 0 {
            return;
        }
        let dirty = self.dirty;
        POOL.with(|p| {
            let mut p = p.borrow_mut();
            if p.len() < POOL_MAX {
                p.push((data, self.nx, dirty));
            }
        });
    }
}

impl Plane {
    /// A plane of any values (−0 included): the whole plane is dirty.
    pub(super) fn new(data: Vec<f32>, nx: usize) -> Self {
        let rect = Rect::of(&data, nx);
        let dirty = (!data.is_empty()).then(|| Rect {
            x: [0, nx - 1],
            y: [0, data.len() / nx - 1],
        });
        Self {
            data,
            rect,
            nx,
            dirty,
        }
    }

    /// A plane whose values are zero outside `bound` (inclusive x, y ranges; None: all zero):
    /// its exact bounds are found within `bound` only.
    fn within(data: Vec<f32>, nx: usize, bound: Option<([usize; 2], [usize; 2])>) -> Self {
        let rect = bound.and_then(|(bx, by)| Rect::of_within(&data, nx, bx, by));
        let dirty = bound.map(|(x, y)| Rect { x, y });
        Self {
            data,
            rect,
            nx,
            dirty,
        }
    }
}

/// Blurs one z-plane (`nx` × `ny`) along x, then along y, in place, computing only within `r`
/// cells of its non-zero values: elsewhere the blur is zero exactly (the densities are
/// non-negative, so every product is +0), which keeps mostly empty boxes cheap. Both passes
/// read and write only the bound's rows and columns; the y pass runs row by row (contiguous),
/// each output row the sum over the kernel's taps in kernel order, as `blur_span` sums them.
pub(super) fn blur_plane_xy(plane: &mut Plane, nx: usize, ny: usize, k: &[f32]) {
    let Some(rc) = plane.rect else {
        return;
    };
    let r = k.len() / 2;
    let g = rc.grow(r, nx, ny);
    // x pass: the row's non-zero span is within rc.x, so a copy of rc.x (zeros outside) is
    // the whole input the taps can read.
    plane
        .data
        .par_chunks_mut(nx)
        .skip(rc.y[0])
        .take(rc.y[1] + 1 - rc.y[0])
        .for_each(|row| {
            let src = &row[rc.x[0]..=rc.x[1]];
            if src.iter().any(|&v| v != 0.0) {
                let src = src.to_vec();
                blur_span(&src, rc.x[0], k, row, g.x[0], g.x[1]);
            }
        });
    // y pass: rows g.y of the result from rows rc.y of the x-blurred plane, columns g.x.
    let (x0, w) = (g.x[0], g.x[1] + 1 - g.x[0]);
    let plane_ro: &[f32] = &plane.data;
    let mut out = vec![0.0f32; (g.y[1] + 1 - g.y[0]) * w];
    out.par_chunks_mut(w).enumerate().for_each(|(i, acc)| {
        let y = g.y[0] + i;
        for (j, wgt) in k.iter().enumerate() {
            let o = y as i64 + j as i64 - r as i64;
            if o < rc.y[0] as i64 || o > rc.y[1] as i64 {
                continue; // a zero row (or outside the plane): every term +0
            }
            add_tap(
                acc,
                *wgt,
                &plane_ro[o as usize * nx + x0..o as usize * nx + x0 + w],
            );
        }
    });
    for (i, row) in out.chunks(w).enumerate() {
        let y = g.y[0] + i;
        plane.data[y * nx + x0..y * nx + x0 + w].copy_from_slice(row);
    }
    // Rows of rc outside g cannot exist (g contains rc); rows of g outside rc were zero and
    // now hold the blur. Values the plane held outside g (−0 at most) stay dirty.
    plane.rect = Some(g);
    plane.dirty = Rect::union(plane.dirty, Some(g));
}

/// `acc[i] += w · src[i]`: one tap of a blur over a contiguous run of outputs (vectorisable;
/// each output still adds its taps in the order the caller takes them).
#[inline]
fn add_tap(acc: &mut [f32], w: f32, src: &[f32]) {
    for (a, v) in acc.iter_mut().zip(src) {
        *a += w * v;
    }
}

/// Blurs a line, zero outside `src` (which starts at `at`), with kernel `k` and zero
/// padding into `dst[lo..=hi]` (the rest of `dst` is untouched). Taps in kernel order: the
/// accumulation order of every blur in this module; the zero taps are skipped (+0 changes no
/// sum of non-negative terms), so computing only where the result can be non-zero changes no
/// value.
#[inline]
fn blur_span(src: &[f32], at: usize, k: &[f32], dst: &mut [f32], lo: usize, hi: usize) {
    let r = k.len() as i64 / 2;
    let (a, b) = (at as i64, (at + src.len()) as i64);
    let out = &mut dst[lo..=hi];
    out.fill(0.0);
    // Tap by tap over the outputs it reaches (contiguous, vectorisable): every output still
    // adds its taps in kernel order.
    for (j, &w) in k.iter().enumerate() {
        let shift = j as i64 - r; // output c reads src position c + shift
        let c0 = (lo as i64).max(a - shift);
        let c1 = (hi as i64).min(b - 1 - shift);
        if c0 > c1 {
            continue;
        }
        let s0 = (c0 + shift - a) as usize;
        let len = (c1 - c0 + 1) as usize;
        let o0 = (c0 - lo as i64) as usize;
        add_tap(&mut out[o0..o0 + len], w, &src[s0..s0 + len]);
    }
}

/// Overlap weights resampling `n` cells onto `m` cells over the same extent: for each new cell,
/// the old cells it overlaps and their shares.
pub(super) fn down_weights(n: usize, m: usize) -> Vec<Vec<(usize, f32)>> {
    (0..m)
        .map(|j| {
            let a = j as f64 * n as f64 / m as f64;
            let b = (j + 1) as f64 * n as f64 / m as f64;
            let mut v = Vec::new();
            let mut i = a.floor() as usize;
            while (i as f64) < b && i < n {
                let lo = (i as f64).max(a);
                let hi = ((i + 1) as f64).min(b);
                if hi > lo {
                    v.push((i, ((hi - lo) / (b - a)) as f32));
                }
                i += 1;
            }
            v
        })
        .collect()
}

/// A level produced one z-plane at a time.
pub(super) trait Planes {
    /// The level's resolution.
    fn res(&self) -> [usize; 3];
    /// The next plane (z = 0, 1, … in order; each once).
    fn next_plane(&mut self) -> Plane;
}

/// Every plane of `p`, concatenated: the stored level.
pub(super) fn collect(p: &mut dyn Planes) -> Vec<f32> {
    let [nx, ny, nz] = p.res();
    let mut out = Vec::with_capacity(nx * ny * nz);
    for _ in 0..nz {
        out.extend_from_slice(&p.next_plane().data);
    }
    out
}

/// Every plane of `p` as 8³ bricks, eight planes at a time: only bricks holding a non-zero
/// value are stored (the planes' bounds skip the rest unread), each checked against the memory
/// budget as it is stored (`what` names the pyramid in the error).
pub(super) fn collect_bricks(p: &mut dyn Planes, what: &str) -> Result<DensityGrid, FieldError> {
    use nimbus_scene::brick::{BrickBuilder, DIM};
    let res = p.res();
    let [nx, ny, nz] = res;
    let mut b = BrickBuilder::new(res, [0; 3], 0, "volume", what)?;
    let [_, _, bz] = b.brick_res();
    let mut slab: Vec<Plane> = Vec::with_capacity(DIM);
    for k in 0..bz {
        slab.clear();
        for _ in k * DIM..((k + 1) * DIM).min(nz) {
            slab.push(p.next_plane());
        }
        let Some(r) = slab.iter().fold(None, |acc, pl| Rect::union(acc, pl.rect)) else {
            continue;
        };
        for j in r.y[0] / DIM..=r.y[1] / DIM {
            let ys = j * DIM..((j + 1) * DIM).min(ny);
            for i in r.x[0] / DIM..=r.x[1] / DIM {
                let xs = i * DIM..((i + 1) * DIM).min(nx);
                let span = |y: usize| y * nx + xs.start..y * nx + xs.end;
                let any = slab.iter().any(|pl| {
                    ys.clone()
                        .any(|y| pl.data[span(y)].iter().any(|&v| v != 0.0))
                });
                if !any {
                    continue;
                }
                let dst = b.stored_mut([i, j, k])?;
                for (l, pl) in slab.iter().enumerate() {
                    for y in ys.clone() {
                        let at = (l * DIM + y - ys.start) * DIM;
                        dst[at..at + xs.len()].copy_from_slice(&pl.data[span(y)]);
                    }
                }
            }
        }
    }
    Ok(DensityGrid::from_bricks(b.finish()?))
}

/// The planes of a density grid times `scale` (dense or bricks; nothing densified).
pub(super) struct GridPlanes<'a> {
    grid: &'a DensityGrid,
    scale: f32,
    z: usize,
}

impl<'a> GridPlanes<'a> {
    pub(super) fn new(grid: &'a DensityGrid, scale: f32) -> Self {
        Self { grid, scale, z: 0 }
    }
}

impl Planes for GridPlanes<'_> {
    fn res(&self) -> [usize; 3] {
        self.grid.res()
    }
    fn next_plane(&mut self) -> Plane {
        let [nx, ny, _] = self.grid.res();
        // Only the bricks crossing the plane are written and scaled (0 × scale = 0 elsewhere):
        // a mostly empty plane of a huge sparse box costs what its cloud costs.
        let mut p = zeroed(nx, ny);
        let bound = self.grid.plane_into_zeroed(self.z, &mut p);
        if let Some((bx, by)) = bound {
            for row in p[by[0] * nx..(by[1] + 1) * nx].chunks_mut(nx) {
                row[bx[0]..=bx[1]].iter_mut().for_each(|v| *v *= self.scale);
            }
        }
        self.z += 1;
        Plane::within(p, nx, bound)
    }
}

/// The planes of a stored level.
pub(super) struct SlicePlanes<'a> {
    data: &'a [f32],
    res: [usize; 3],
    z: usize,
}

impl<'a> SlicePlanes<'a> {
    pub(super) fn new(data: &'a [f32], res: [usize; 3]) -> Self {
        Self { data, res, z: 0 }
    }
}

impl Planes for SlicePlanes<'_> {
    fn res(&self) -> [usize; 3] {
        self.res
    }
    fn next_plane(&mut self) -> Plane {
        let n = self.res[0] * self.res[1];
        let p = self.data[self.z * n..(self.z + 1) * n].to_vec();
        self.z += 1;
        Plane::new(p, self.res[0])
    }
}

/// The window of x-y-blurred input planes a z filter reads: planes are pulled from the input
/// in order as they are needed and dropped once no later output reads them.
struct XyWindow<'a> {
    input: Box<dyn Planes + 'a>,
    k: Vec<f32>,
    planes: BTreeMap<usize, Plane>,
    pulled: usize,
}

impl<'a> XyWindow<'a> {
    fn new(input: Box<dyn Planes + 'a>, sigma: f64) -> Self {
        Self {
            input,
            k: gauss_kernel(sigma),
            planes: BTreeMap::new(),
            pulled: 0,
        }
    }

    /// Holds the x-y-blurred input planes `lo..=hi` (and none below `lo`).
    fn hold(&mut self, lo: usize, hi: usize) {
        self.planes.retain(|&z, _| z >= lo);
        let [nx, ny, _] = self.input.res();
        while self.pulled <= hi {
            let mut p = self.input.next_plane();
            blur_plane_xy(&mut p, nx, ny, &self.k);
            if self.pulled >= lo {
                self.planes.insert(self.pulled, p);
            }
            self.pulled += 1;
        }
    }

    /// Σ_j k_j · plane(z + j − r) over the planes inside the box, taps in kernel order,
    /// computed where some tap is non-zero (elsewhere every term is +0).
    fn blur_z(&mut self, z: usize) -> Plane {
        let [nx, ny, nz] = self.input.res();
        let r = self.k.len() / 2;
        self.hold(z.saturating_sub(r), (z + r).min(nz - 1));
        let taps: Vec<(f32, &Plane)> = (0..self.k.len())
            .filter_map(|j| {
                let zz = z as i64 + j as i64 - r as i64;
                (zz >= 0 && zz < nz as i64).then(|| (self.k[j], &self.planes[&(zz as usize)]))
            })
            .filter(|(_, p)| p.rect.is_some())
            .collect();
        let rect = taps.iter().fold(None, |u, (_, p)| Rect::union(u, p.rect));
        let mut data = zeroed(nx, ny);
        if let Some(u) = rect {
            data.par_chunks_mut(nx)
                .enumerate()
                .skip(u.y[0])
                .take(u.y[1] + 1 - u.y[0])
                .for_each(|(y, row)| {
                    // Tap by tap over the row (contiguous): each value sums its taps in order.
                    let acc = &mut row[u.x[0]..=u.x[1]];
                    for (w, t) in &taps {
                        add_tap(acc, *w, &t.data[y * nx + u.x[0]..=y * nx + u.x[1]]);
                    }
                });
        }
        // Sums from +0 in a clean buffer: +0 or positive, written within `rect` only.
        Plane {
            data,
            rect,
            nx,
            dirty: rect,
        }
    }
}

/// A Gaussian blur of σ voxels (zero padding) at the input's resolution: level 0.
pub(super) struct Blur<'a> {
    window: XyWindow<'a>,
    z: usize,
}

impl<'a> Blur<'a> {
    pub(super) fn new(input: Box<dyn Planes + 'a>, sigma: f64) -> Self {
        Self {
            window: XyWindow::new(input, sigma),
            z: 0,
        }
    }
}

impl Planes for Blur<'_> {
    fn res(&self) -> [usize; 3] {
        self.window.input.res()
    }
    fn next_plane(&mut self) -> Plane {
        let p = self.window.blur_z(self.z);
        self.z += 1;
        p
    }
}

/// The next pyramid level: the input blurred with σ voxels, then halved in resolution (ceil)
/// by averaging the input cells overlapping each new cell (an odd last cell pairs with zero
/// padding weighted by its share of the box).
pub(super) struct Down<'a> {
    window: XyWindow<'a>,
    weights: [Vec<Vec<(usize, f32)>>; 3],
    res: [usize; 3],
    /// z-blurred input planes by input z.
    blurred: BTreeMap<usize, Plane>,
    z: usize,
}

impl<'a> Down<'a> {
    pub(super) fn new(input: Box<dyn Planes + 'a>, sigma: f64) -> Self {
        let res_in = input.res();
        let res = res_in.map(|v| v.div_ceil(2));
        Self {
            weights: std::array::from_fn(|a| down_weights(res_in[a], res[a])),
            window: XyWindow::new(input, sigma),
            res,
            blurred: BTreeMap::new(),
            z: 0,
        }
    }
}

impl Planes for Down<'_> {
    fn res(&self) -> [usize; 3] {
        self.res
    }
    fn next_plane(&mut self) -> Plane {
        let z2 = self.z;
        self.z += 1;
        let [wx, wy, wz] = &self.weights;
        for &(iz, _) in &wz[z2] {
            if !self.blurred.contains_key(&iz) {
                let b = self.window.blur_z(iz);
                self.blurred.retain(|&z, _| z + 2 >= iz);
                self.blurred.insert(iz, b);
            }
        }
        let nx = self.window.input.res()[0];
        let nr = self.res;
        let blurred = &self.blurred;
        let mut out = zeroed(nr[0], nr[1]);
        let Some(u) = wz[z2]
            .iter()
            .fold(None, |u, (iz, _)| Rect::union(u, blurred[iz].rect))
        else {
            return Plane {
                data: out,
                rect: None,
                nx: nr[0],
                dirty: None,
            };
        };
        // The new cells whose footprint meets the input's non-zero bound.
        let span = |w: &[Vec<(usize, f32)>], lo: usize, hi: usize| {
            let meets = |c: &Vec<(usize, f32)>| c.iter().any(|&(i, _)| i >= lo && i <= hi);
            let a = w.iter().position(meets).expect("the bound lies in the box");
            let b = w
                .iter()
                .rposition(meets)
                .expect("the bound lies in the box");
            [a, b]
        };
        let rect = Rect {
            x: span(wx, u.x[0], u.x[1]),
            y: span(wy, u.y[0], u.y[1]),
        };
        out.par_chunks_mut(nr[0])
            .enumerate()
            .skip(rect.y[0])
            .take(rect.y[1] + 1 - rect.y[0])
            .for_each(|(y2, row)| {
                for (x2, v) in row
                    .iter_mut()
                    .enumerate()
                    .take(rect.x[1] + 1)
                    .skip(rect.x[0])
                {
                    let mut acc = 0.0f32;
                    for &(iz, az) in &wz[z2] {
                        let b = &blurred[&iz].data;
                        for &(iy, ay) in &wy[y2] {
                            for &(ix, ax) in &wx[x2] {
                                acc += az * ay * ax * b[iy * nx + ix];
                            }
                        }
                    }
                    *v = acc;
                }
            });
        Plane {
            data: out,
            rect: Some(rect),
            nx: nr[0],
            dirty: Some(rect),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A recycled buffer comes back with every bit zero: a −0 the plane held inside what it
    /// wrote but outside its non-zero values is cleared too (the pool clears `dirty`, not
    /// `rect`).
    #[test]
    fn recycled_planes_come_back_all_zero_bits() {
        release_planes();
        let (nx, ny) = (16, 12);
        let mut data = zeroed(nx, ny);
        data[3 * nx + 4] = 2.0; // the plane's only non-zero value
        data[10 * nx + 14] = -0.0; // written, but not a non-zero value
        let ptr = data.as_ptr();
        let p = Plane::within(data, nx, Some(([2, 15], [1, 11])));
        assert_eq!(
            p.rect,
            Some(Rect {
                x: [4, 4],
                y: [3, 3]
            })
        );
        drop(p);
        let b = zeroed(nx, ny);
        assert_eq!(b.as_ptr(), ptr, "the dropped plane's buffer is reused");
        assert!(b.iter().all(|v| v.to_bits() == 0));
        // A blurred plane keeps what it held outside its new bound dirty as well.
        let mut data = b;
        data[5 * nx + 6] = 1.0;
        data[0] = -0.0;
        let mut p = Plane::within(data, nx, Some(([0, 15], [0, 11])));
        blur_plane_xy(&mut p, nx, ny, &gauss_kernel(1.0));
        assert!(
            p.rect.is_some_and(|r| r.x[0] > 0 && r.y[0] > 0),
            "{:?}",
            p.rect
        );
        drop(p);
        assert!(zeroed(nx, ny).iter().all(|v| v.to_bits() == 0));
        release_planes();
    }
}
