//! Twin of `trace` in `shaders/photon_trace.wgsl`: one photon beam (Elek 2012 §4.1, Appendix
//! A) traced with Woodcock tracking against the global majorant, depositing into the cache
//! words of the cells it passes. Same random numbers (PCG32 stream per beam, drawn in the
//! same order), same f32 arithmetic; only the transcendental functions (`ln`, `sin`, `cos`,
//! `sqrt`) come from another library, so a beam can part from its GPU twin after a last-ulp
//! difference (the tests compare whole caches).

use super::*;
use nimbus_scene::phase::hg::sample_cos_f32 as hg_sample_cos;

/// The shaders' PCG32 stream (`shaders/lib/rng.wgsl`).
#[derive(Debug, Clone, Copy)]
pub struct Rng {
    state: u32,
}

impl Rng {
    /// `rng_new(a, b, c)`.
    pub fn new(a: u32, b: u32, c: u32) -> Self {
        Self {
            state: pcg_hash(a ^ pcg_hash(b ^ pcg_hash(c))),
        }
    }

    /// `rand`: 24 random bits → [0, 1).
    pub fn rand(&mut self) -> f32 {
        self.state = self.state.wrapping_mul(747796405).wrapping_add(2891336453);
        let s = self.state;
        let word = ((s >> ((s >> 28) + 4)) ^ s).wrapping_mul(277803737);
        let x = (word >> 22) ^ word;
        (x >> 8) as f32 * (1.0 / 16777216.0)
    }
}

/// `around` of `shaders/lib/math.wgsl`: unit vector at cosine `mu`, azimuth `phi` about `axis`.
pub(crate) fn around(axis: Vec3, mu: f32, phi: f32) -> Vec3 {
    let sign = if axis.z >= 0.0 { 1.0f32 } else { -1.0 };
    let a = -1.0 / (sign + axis.z);
    let b = axis.x * axis.y * a;
    let t = Vec3::new(1.0 + sign * axis.x * axis.x * a, sign * b, -sign * axis.x);
    let bb = Vec3::new(b, sign + axis.y * axis.y * a, -axis.y);
    let st = (1.0 - mu * mu).max(0.0).sqrt();
    (t * (st * phi.cos()) + bb * (st * phi.sin()) + axis * mu).normalize()
}

/// `cell_of`: the coarse cell holding p (clamped to the grid).
fn cell_of(p: &VolumeParams, x: Vec3) -> usize {
    let u =
        (x - v3(p.aabb_min)) / (v3(p.aabb_max) - v3(p.aabb_min)) * v3(p.i_res.map(|r| r as f32));
    let hi = Vec3::new(
        p.i_res[0] as f32 - 1.0,
        p.i_res[1] as f32 - 1.0,
        p.i_res[2] as f32 - 1.0,
    );
    let c = u.floor().clamp(Vec3::ZERO, hi);
    index(c.x as u32, c.y as u32, c.z as u32, p.i_res)
}

/// `skip_distance`: the distance that takes a beam at `x` along `d` out of its cell when the
/// cell is skippable (`skip[cell] != 0`), else −1.
fn skip_distance(p: &VolumeParams, skip: &[u32], x: Vec3, d: Vec3) -> f32 {
    let ext = v3(p.aabb_max) - v3(p.aabb_min);
    let res = v3(p.i_res.map(|r| r as f32));
    let size = ext / res;
    let u = (x - v3(p.aabb_min)) / ext * res;
    let c = u.floor().clamp(Vec3::ZERO, res - Vec3::ONE);
    if skip[index(c.x as u32, c.y as u32, c.z as u32, p.i_res)] == 0 {
        return -1.0;
    }
    let lo = v3(p.aabb_min) + c * size;
    let mut t = 3.0e38f32;
    for a in 0..3 {
        if d[a] > 0.0 {
            t = t.min((lo[a] + size[a] - x[a]) / d[a]);
        } else if d[a] < 0.0 {
            t = t.min((lo[a] - x[a]) / d[a]);
        }
    }
    t.max(0.0) + 1.0e-3 * size.x.min(size.y.min(size.z))
}

/// `view_phase`: the phase function for light travelling along `d` at `x` scattered towards
/// `p.view_origin` (isotropic at the view point itself).
pub fn view_phase(p: &VolumeParams, x: Vec3, d: Vec3) -> f32 {
    let v = v3(p.view_origin) - x;
    let l = v.length();
    // (`!(l > ε)` in the shader: a NaN length counts as the view point too.)
    if l.is_nan() || l <= 1e-20 {
        return 1.0 / (4.0 * std::f32::consts::PI);
    }
    hg(if p.view_g == 0.0 { p.g } else { p.view_g }, d.dot(v / l))
}

/// Adds `v` to word `slot` of `h`; `true` when the u32 sum wraps (the shader's overflow flag).
fn deposit(h: &mut [u32], slot: usize, v: u32) -> bool {
    if v == 0 {
        return false;
    }
    let (sum, wrapped) = h[slot].overflowing_add(v);
    h[slot] = sum;
    wrapped
}

/// Traces beam `index` of frame `p.frame` (sun beams are `0 .. p.n_sun`, sky beams follow)
/// into the cache words `h` (`CELL_WORDS` per coarse cell, as `h_new`); with `p.skip_empty`,
/// `skip` holds a flag per cell (`mapper::light::skippable_cells`). Returns whether a word
/// wrapped.
pub fn trace(p: &VolumeParams, density: &[f32], skip: &[u32], index: u32, h: &mut [u32]) -> bool {
    let mut rng = Rng::new(p.seed, p.frame, index);
    let pi = std::f32::consts::PI;
    let is_sun = index < p.n_sun;
    let c = v3(p.bound_center);
    let r = p.bound_radius;
    let sun_dir = v3(p.sun_dir);
    let (o, mut d) = if is_sun {
        let rad = r * rng.rand().sqrt();
        let phi = 2.0 * pi * rng.rand();
        let q = around(sun_dir, 0.0, phi) * rad;
        (c + q + sun_dir * (2.0 * r), -sun_dir)
    } else {
        let z = 1.0 - 2.0 * rng.rand();
        let phi = 2.0 * pi * rng.rand();
        let s = (1.0 - z * z).max(0.0).sqrt();
        let n = Vec3::new(s * phi.cos(), s * phi.sin(), z);
        let mu = rng.rand().sqrt();
        let psi = 2.0 * pi * rng.rand();
        (c + n * r, around(-n, mu, psi))
    };
    let hit = box_intersect(p, o, d);
    if hit.0 > hit.1 {
        return false;
    }
    let mut x = o + d * hit.0;
    let mut w = 1.0f32;
    let mut order = 0u32;
    let mut steps = 0u32;
    let mut stalled = 0u32;
    let mut overflow = false;
    let words = CELL_WORDS;
    loop {
        steps += 1;
        if steps > 1_000_000 {
            break;
        }
        if p.skip_empty != 0 {
            let s = skip_distance(p, skip, x, d);
            if s >= 0.0 {
                x += d * s;
                if !inside(p, x) {
                    break;
                }
                continue;
            }
        }
        let exit = box_intersect(p, x, d);
        let t = -(1.0 - rng.rand()).ln() / p.sigma_max;
        if exit.0 > exit.1 || t >= exit.1 {
            break;
        }
        let x_next = x + d * t;
        if x_next == x {
            stalled += 1;
            if stalled >= 8 {
                break;
            }
        } else {
            stalled = 0;
        }
        x = x_next;
        if p.skip_empty != 0 && skip_distance(p, skip, x, d) >= 0.0 {
            continue;
        }
        let skip = is_sun && order == 0 && p.single_scatter != 0;
        let cell = cell_of(p, x) * words;
        let sigma_here = p.density_scale * density_at(p, density, x);
        let dw = if p.density_weighted != 0 {
            sigma_here / p.sigma_max
        } else {
            1.0
        };
        let wu = (w * dw * cache_scale() + rng.rand()).floor() as u32;
        if is_sun {
            let jitter = Vec3::new(rng.rand(), rng.rand(), rng.rand());
            let cu = (wu as f32 * 0.5 * (d + Vec3::ONE) + jitter).floor();
            let cu = [cu.x as u32, cu.y as u32, cu.z as u32];
            if !skip {
                overflow |= deposit(h, cell, wu);
                overflow |= deposit(h, cell + 2, cu[0]);
                overflow |= deposit(h, cell + 3, cu[1]);
                overflow |= deposit(h, cell + 4, cu[2]);
                if p.lobe_split != 0 && order >= p.lobe_split {
                    overflow |= deposit(h, cell + 7, wu);
                    overflow |= deposit(h, cell + 8, cu[0]);
                    overflow |= deposit(h, cell + 9, cu[1]);
                    overflow |= deposit(h, cell + 10, cu[2]);
                }
            }
        } else {
            overflow |= deposit(h, cell + 1, wu);
        }
        if p.view_mode != 0 && !skip {
            let vu = (w * dw * cache_scale() * view_phase(p, x, d) + rng.rand()).floor() as u32;
            overflow |= deposit(h, cell + if is_sun { 11 } else { 12 }, vu);
        }
        if !skip {
            overflow |= deposit(h, cell + 5, order.min(1023));
            overflow |= deposit(h, cell + 6, 1);
        }
        let reduced = order >= p.similarity_order;
        let sigma = if reduced {
            sigma_here * p.reduced_factor
        } else {
            sigma_here
        };
        if rng.rand() * p.sigma_max < sigma {
            w *= p.albedo;
            order += 1;
            if w < p.beam_threshold || order > p.max_order {
                break;
            }
            let u1 = rng.rand();
            let phi = 2.0 * pi * rng.rand();
            d = if order > p.similarity_order {
                around(d, 1.0 - 2.0 * u1, phi)
            } else {
                around(d, hg_sample_cos(p.g, u1), phi)
            };
        }
    }
    overflow
}

/// `W_SCALE` as the shader's f32 constant.
fn cache_scale() -> f32 {
    crate::cache_layout::W_SCALE as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The stream is the shader's: a fixed seed gives fixed numbers in [0, 1), and streams of
    /// neighbouring beams differ.
    #[test]
    fn rng_matches_the_shader_stream() {
        let mut a = Rng::new(1, 0, 0);
        let mut b = Rng::new(1, 0, 1);
        let xs: Vec<f32> = (0..4).map(|_| a.rand()).collect();
        assert!(xs.iter().all(|x| (0.0..1.0).contains(x)));
        assert_ne!(xs[0], b.rand());
        // Mean of many draws ≈ 1/2 (σ/√n = 0.29/√10⁵ ≈ 9e-4; bound 5σ).
        let mut r = Rng::new(7, 3, 11);
        let m: f64 = (0..100_000).map(|_| r.rand() as f64).sum::<f64>() / 1e5;
        assert!((m - 0.5).abs() < 5e-3, "{m}");
    }

    /// Beams whose disc lies beside the box never enter it and deposit nothing.
    #[test]
    fn a_beam_that_misses_the_box_deposits_nothing() {
        let p = VolumeParams {
            aabb_min: [0.0; 3],
            aabb_max: [1.0; 3],
            d_res: [2, 2, 2],
            i_res: [1, 1, 1],
            density_scale: 1.0,
            sigma_max: 1.0,
            sun_dir: [0.0, 1.0, 0.0],
            // A bounding sphere far from the box: every beam misses.
            bound_center: [10.0, 0.0, 0.0],
            bound_radius: 0.5,
            n_sun: 4,
            max_order: 10,
            ..Default::default()
        };
        let mut h = vec![0u32; CELL_WORDS];
        for i in 0..4 {
            assert!(!trace(&p, &[1.0; 8], &[], i, &mut h));
        }
        assert!(h.iter().all(|&v| v == 0));
    }
}
