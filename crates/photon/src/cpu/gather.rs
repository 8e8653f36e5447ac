//! Twin of `gather` in `shaders/lib/photon_gather_core.wgsl`: the samples one invocation adds to
//! one pixel (the final gathering, `mapper/gather.rs`). Same random numbers (the shaders' PCG32
//! stream per pixel and sample, drawn in the same order), same f32 arithmetic; as for the beam
//! twin, a path can part from its GPU twin after a last-ulp difference of a transcendental
//! function (`ln`, `exp`, `sin`, `cos`, `sqrt`), so tests compare paths one by one and allow
//! for a few that part.

use super::trace::{Rng, around};
use super::*;
use crate::mapper::GatherParams;
use nimbus_scene::phase::hg::sample_cos_f32 as hg_sample_cos;

/// What the gather reads: the density at `p.d_res` and the light volumes at `p.light_res`
/// (dense, x fastest, without the pools' leading zeros), as the ray marcher's twin.
pub struct GatherInputs<'a> {
    pub density: &'a [f32],
    /// Each cache cell's fill (`mapper::light::cell_fills`).
    pub cell_fill: &'a [f32],
    pub j: &'a [[f32; 4]],
    pub t_sun: &'a [f32],
    /// The upsampled flux lobes (read by the lobes terminal).
    pub j_dirs: &'a [[Vec4; 2]],
}

fn t_sun_at(p: &VolumeParams, inp: &GatherInputs, x: Vec3) -> f32 {
    interp(p, x, p.light_res, |i| inp.t_sun[i])
}

/// `half_voxel` of `lib/tracking.wgsl`.
fn half_voxel(p: &VolumeParams) -> f32 {
    let v = (v3(p.aabb_max) - v3(p.aabb_min))
        / Vec3::new(p.d_res[0] as f32, p.d_res[1] as f32, p.d_res[2] as f32);
    0.5 * v.x.min(v.y.min(v.z))
}

/// `delta_track` of `lib/tracking.wgsl` over `span` = (t0, t1).
fn delta_track(
    p: &VolumeParams,
    inp: &GatherInputs,
    (o, d): (Vec3, Vec3),
    (t0, t1): (f32, f32),
    sigma_max: f32,
    rng: &mut Rng,
) -> f32 {
    let mut t = t0;
    loop {
        let mut next = t - (1.0 - rng.rand()).ln() / sigma_max;
        if next <= t {
            if density_at(p, inp.density, o + d * t) > 0.0 {
                return t;
            }
            next = t + half_voxel(p);
        }
        t = next;
        if t >= t1 {
            return -1.0;
        }
        if rng.rand() * sigma_max < p.density_scale * density_at(p, inp.density, o + d * t) {
            return t;
        }
    }
}

/// `ratio_track` of `lib/tracking.wgsl`.
fn ratio_track(
    p: &VolumeParams,
    inp: &GatherInputs,
    o: Vec3,
    d: Vec3,
    sigma_max: f32,
    rng: &mut Rng,
) -> f32 {
    let (h0, h1) = box_intersect(p, o, d);
    if h0 > h1 {
        return 1.0;
    }
    let mut tr = 1.0f32;
    let mut t = h0;
    loop {
        let mut next = t - (1.0 - rng.rand()).ln() / sigma_max;
        if next <= t {
            if density_at(p, inp.density, o + d * t) > 0.0 {
                return 0.0;
            }
            next = t + half_voxel(p);
        }
        t = next;
        if t >= h1 {
            break;
        }
        tr *= (1.0 - p.density_scale * density_at(p, inp.density, o + d * t) / sigma_max).max(0.0);
        if tr < 0.1 {
            if tr <= 0.0 || rng.rand() < 0.5 {
                return 0.0;
            }
            tr *= 2.0;
        }
    }
    tr
}

/// `cache_in_scatter`: the photon map's in-scattering per unit σ_s at x for light arriving
/// along d.
fn cache_in_scatter(
    p: &VolumeParams,
    g: &GatherParams,
    inp: &GatherInputs,
    x: Vec3,
    d: Vec3,
) -> Vec3 {
    let jv = interp(p, x, p.light_res, |i| Vec4::from_array(inp.j[i]));
    if g.view_words != 0 {
        return v3(p.sun_irradiance) * jv.x + v3(p.sky_radiance) * jv.y;
    }
    v3(p.sun_irradiance) * sun_in_scatter(p, inp.j_dirs, x, jv, d)
        + v3(p.sky_radiance) * (jv.y / (4.0 * std::f32::consts::PI))
}

/// `cache_resolves`: whether a path may end with the cache at x.
fn cache_resolves(
    p: &VolumeParams,
    g: &GatherParams,
    inp: &GatherInputs,
    x: Vec3,
    scat: u32,
) -> bool {
    if scat > g.bounces.saturating_add(g.max_extra) {
        return true;
    }
    let res = Vec3::new(p.i_res[0] as f32, p.i_res[1] as f32, p.i_res[2] as f32);
    let u = (x - v3(p.aabb_min)) / (v3(p.aabb_max) - v3(p.aabb_min)) * res;
    let c = u.floor().clamp(Vec3::ZERO, res - Vec3::ONE);
    inp.cell_fill[index(c.x as u32, c.y as u32, c.z as u32, p.i_res)] >= g.min_fill
}

/// `sun_nee`: the sun scattered at x towards −d (without the albedo).
fn sun_nee(
    p: &VolumeParams,
    g: &GatherParams,
    inp: &GatherInputs,
    x: Vec3,
    d: Vec3,
    rng: &mut Rng,
) -> Vec3 {
    let e = v3(p.sun_irradiance);
    if e.cmple(Vec3::ZERO).all() {
        return Vec3::ZERO;
    }
    let sun = v3(p.sun_dir);
    if g.shadow_rays == 0 {
        return e * (t_sun_at(p, inp, x) * hg(p.g, d.dot(sun)));
    }
    let pi = std::f32::consts::PI;
    let (mut wi, mut scale) = (sun, 1.0f32);
    if p.sun_disc_radiance > 0.0 {
        let omc = (1.0 / (pi * p.sun_disc_radiance)) / (1.0 + p.sun_cos_max);
        let mu = 1.0 - rng.rand() * omc;
        wi = around(sun, mu, 2.0 * pi * rng.rand());
        scale = p.sun_disc_radiance * 2.0 * pi * omc;
    }
    let ph = hg(p.g, d.dot(wi));
    if ph <= 0.0 {
        return Vec3::ZERO;
    }
    e * (ph * scale * ratio_track(p, inp, x, wi, g.sigma_max, rng))
}

/// `gather_path`: radiance along o + t d with the sun next-event estimated at every collision
/// but the first when `skip_first_sun`, the cache read at the (k + 1)-th.
fn gather_path(
    p: &VolumeParams,
    g: &GatherParams,
    inp: &GatherInputs,
    o0: Vec3,
    d0: Vec3,
    skip_first_sun: bool,
    rng: &mut Rng,
) -> Vec3 {
    let pi = std::f32::consts::PI;
    let (mut o, mut d) = (o0, d0);
    let mut beta = 1.0f32;
    let mut l = Vec3::ZERO;
    let mut scat = 0u32;
    loop {
        let (h0, h1) = box_intersect(p, o, d);
        let t = if h0 <= h1 {
            delta_track(p, inp, (o, d), (h0, h1), g.sigma_max, rng)
        } else {
            -1.0
        };
        if t < 0.0 {
            if scat > 0 || !skip_first_sun {
                l += beta * v3(p.sky_radiance);
                if scat == 0 && p.sun_disc_radiance > 0.0 && d.dot(v3(p.sun_dir)) >= p.sun_cos_max {
                    l += beta * v3(p.sun_irradiance) * p.sun_disc_radiance;
                }
            }
            break;
        }
        let x = o + d * t;
        scat += 1;
        beta *= p.albedo;
        if beta <= 0.0 {
            break;
        }
        if scat > 1 || !skip_first_sun {
            l += beta * sun_nee(p, g, inp, x, d, rng);
        }
        if scat > g.bounces && cache_resolves(p, g, inp, x, scat) {
            l += beta * cache_in_scatter(p, g, inp, x, d);
            break;
        }
        let mu = hg_sample_cos(p.g, rng.rand());
        d = around(d, mu, 2.0 * pi * rng.rand());
        o = x;
        if scat > 8 && beta < 1.0 {
            if rng.rand() >= beta {
                break;
            }
            beta = 1.0;
        }
    }
    l
}

/// `march_single`: the camera ray's single scattering and background, ray marched.
fn march_single(p: &VolumeParams, inp: &GatherInputs, o: Vec3, d: Vec3, rng: &mut Rng) -> Vec3 {
    let mut l = Vec3::ZERO;
    let mut tr = 1.0f32;
    let (h0, h1) = box_intersect(p, o, d);
    let sun = v3(p.sun_dir);
    if h0 <= h1 {
        let mut t = h0 + rng.rand() * p.step;
        let ph = hg(p.g, d.dot(sun));
        let sigma_s_scale = p.albedo * p.density_scale;
        while t < h1 {
            if tr < p.early_exit {
                if rng.rand() < 0.5 {
                    tr = 0.0;
                    break;
                }
                tr *= 2.0;
            }
            let dt = p.step.min(h1 - t);
            let x = o + d * (t + 0.5 * dt);
            let dens = density_at(p, inp.density, x);
            let sigma_t = p.density_scale * dens;
            if sigma_t > 0.0 {
                let ls = sigma_s_scale * dens * v3(p.sun_irradiance) * (t_sun_at(p, inp, x) * ph);
                let ts = (-sigma_t * dt).exp();
                l += tr * ls * (1.0 - ts) / sigma_t;
                tr *= ts;
            }
            t += dt;
        }
    }
    let mut bg = v3(p.sky_radiance);
    if p.sun_disc_radiance > 0.0 && d.dot(sun) >= p.sun_cos_max {
        bg += v3(p.sun_irradiance) * p.sun_disc_radiance;
    }
    l + tr * bg
}

/// One sample of pixel (x, y): the radiance the invocation adds for sample index `sample`
/// (`G.sample + s` in the shader's loop).
pub fn gather_sample(
    p: &VolumeParams,
    g: &GatherParams,
    inp: &GatherInputs,
    x: u32,
    y: u32,
    sample: u32,
) -> Vec3 {
    let i = y * p.width + x;
    let mut rng = Rng::new(g.seed, i, sample);
    let fx = (x as f32 + rng.rand()) / p.width as f32 * 2.0 - 1.0;
    let fy = 1.0 - (y as f32 + rng.rand()) / p.height as f32 * 2.0;
    let d = (v3(p.cam_forward)
        + v3(p.cam_right) * (fx * p.tan_half * p.aspect)
        + v3(p.cam_up) * (fy * p.tan_half))
        .normalize();
    let o = v3(p.cam_origin);
    let l = if g.shadow_rays == 0 {
        march_single(p, inp, o, d, &mut rng) + gather_path(p, g, inp, o, d, true, &mut rng)
    } else {
        gather_path(p, g, inp, o, d, false, &mut rng)
    };
    if !l.is_finite() || l.abs().max_element() > 3.0e38 {
        Vec3::ZERO
    } else {
        l
    }
}

/// The sums one invocation adds to pixel (x, y): Σ (R, G, B, lum²) over its `g.count`
/// samples (before the decay of the running sums).
pub fn gather(p: &VolumeParams, g: &GatherParams, inp: &GatherInputs, x: u32, y: u32) -> Vec4 {
    let mut sum = Vec4::ZERO;
    for s in 0..g.count {
        let l = gather_sample(p, g, inp, x, y, g.sample.wrapping_add(s));
        let lum = (l.x + l.y + l.z) / 3.0;
        sum += l.extend(lum * lum);
    }
    sum
}
