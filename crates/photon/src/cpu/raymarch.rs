//! Twin of `raymarch` in `shaders/photon_raymarch.wgsl`: one pixel of the ray marcher (Elek
//! 2012 §4.4, Appendix C).

use super::*;

/// `interp` over the per-voxel flux entries (`interp_dir` in photon_raymarch.wgsl).
fn interp_dir(p: &VolumeParams, j_dirs: &[[Vec4; 2]], pos: Vec3, hi: bool) -> Vec4 {
    interp(p, pos, p.light_res, |i| j_dirs[i][hi as usize])
}

/// HG(· | g·|v|) for the lobe v (axis × g') towards the camera (−d) (`lobe_phase`).
fn lobe_phase(p: &VolumeParams, v: Vec3, d: Vec3) -> f32 {
    let gl = v.length();
    let mu = if gl > 1e-6 { (-d).dot(v / gl) } else { 0.0 };
    hg(p.g * gl.min(0.999), mu)
}

/// Sun fluence times the phase of its lobes towards the camera (`sun_in_scatter` in
/// photon_raymarch.wgsl): one lobe along the sun with J's g' (the paper), or per-voxel flux
/// lobes — one for all orders, or low and high orders apart (`p.lobe_split`).
pub fn sun_in_scatter(p: &VolumeParams, j_dirs: &[[Vec4; 2]], pos: Vec3, j: Vec4, d: Vec3) -> f32 {
    if p.lobe_axis == 0 {
        return j.x * lobe_phase(p, -v3(p.sun_dir) * j.z, d);
    }
    let lo = interp_dir(p, j_dirs, pos, false);
    if p.lobe_split == 0 {
        return j.x * lobe_phase(p, lo.truncate(), d);
    }
    let hi = interp_dir(p, j_dirs, pos, true);
    let f_hi = lo.w.clamp(0.0, j.x);
    (j.x - f_hi) * lobe_phase(p, lo.truncate(), d) + f_hi * lobe_phase(p, hi.truncate(), d)
}

/// Henyey–Greenstein reconstruction of the in-scattered radiance (Elek Appendix C): the
/// incident lobe HG(g') convolved with the medium's HG(g) is HG(g g'); `mu` is the cosine
/// between the lobe's axis and the direction towards the camera.
pub fn in_scattered(p: &VolumeParams, dens: f32, j: [f32; 4], mu: f32) -> Vec3 {
    p.albedo
        * p.density_scale
        * dens
        * (v3(p.sun_irradiance) * (j[0] * hg(p.g * j[2], mu))
            + v3(p.sky_radiance) * (j[1] / (4.0 * std::f32::consts::PI)))
}

/// Exact first-order sun light at density `dens` with sun transmittance `t_sun`:
/// σ_s E_sun T_sun p_HG(μ | g).
pub fn single_scattered(p: &VolumeParams, dens: f32, t_sun: f32, mu: f32) -> Vec3 {
    p.albedo * p.density_scale * dens * v3(p.sun_irradiance) * (t_sun * hg(p.g, mu))
}

fn lattice(c: [i32; 3]) -> Vec3 {
    let h = pcg_hash(c[0] as u32 ^ pcg_hash(c[1] as u32 ^ pcg_hash(c[2] as u32)));
    let h2 = pcg_hash(h);
    let h3 = pcg_hash(h2);
    Vec3::new((h >> 8) as f32, (h2 >> 8) as f32, (h3 >> 8) as f32) * (2.0 / 16777216.0) - Vec3::ONE
}

fn value_noise(q: Vec3) -> Vec3 {
    let b = q.floor();
    let f = q - b;
    let s = f * f * (Vec3::splat(3.0) - 2.0 * f);
    let c = [b.x as i32, b.y as i32, b.z as i32];
    let l = |dx: i32, dy: i32, dz: i32| lattice([c[0] + dx, c[1] + dy, c[2] + dz]);
    let x00 = lerp(l(0, 0, 0), l(1, 0, 0), s.x);
    let x10 = lerp(l(0, 1, 0), l(1, 1, 0), s.x);
    let x01 = lerp(l(0, 0, 1), l(1, 0, 1), s.x);
    let x11 = lerp(l(0, 1, 1), l(1, 1, 1), s.x);
    lerp(lerp(x00, x10, s.y), lerp(x01, x11, s.y), s.z)
}

/// Three-octave vector-noise displacement of a lookup position (Elek §4.4).
pub fn perturb(p: &VolumeParams, x: Vec3) -> Vec3 {
    if p.noise_amplitude <= 0.0 {
        return x;
    }
    let q = x * p.noise_frequency;
    let n = value_noise(q) + 0.5 * value_noise(2.0 * q) + 0.25 * value_noise(4.0 * q);
    x + p.noise_amplitude * n
}

/// The colour of pixel (x, y) (the pass of `photon_raymarch.wgsl`); `t_sun` is the
/// sun-transmittance volume (read when `p.single_scatter` is set), `j_dirs` the upsampled flux
/// lobes (read when `p.lobe_axis` is set).
pub fn raymarch(
    p: &VolumeParams,
    density: &[f32],
    j: &[[f32; 4]],
    t_sun: &[f32],
    j_dirs: &[[Vec4; 2]],
    x: u32,
    y: u32,
) -> Vec3 {
    let px = (x as f32 + 0.5) / p.width as f32 * 2.0 - 1.0;
    let py = 1.0 - (y as f32 + 0.5) / p.height as f32 * 2.0;
    let d = (v3(p.cam_forward)
        + v3(p.cam_right) * (px * p.tan_half * p.aspect)
        + v3(p.cam_up) * (py * p.tan_half))
        .normalize();
    let mut l = Vec3::ZERO;
    let mut tr = 1.0f32;
    let o = v3(p.cam_origin);
    let (t0, t1) = box_intersect(p, o, d);
    if t0 <= t1 {
        let offset = (pcg_hash(y * p.width + x) >> 8) as f32 * (1.0 / 16777216.0);
        let mut t = t0 + offset * p.step;
        let mu = d.dot(v3(p.sun_dir));
        while t < t1 && tr >= p.early_exit {
            let dt = p.step.min(t1 - t);
            let xp = perturb(p, o + d * (t + 0.5 * dt));
            let dens = density_at(p, density, xp);
            let sigma_t = p.density_scale * dens;
            if sigma_t > 0.0 {
                let jv = interp(p, xp, p.light_res, |i| glam::Vec4::from_array(j[i]));
                let mut ls = if p.view_mode == 2 {
                    p.albedo
                        * p.density_scale
                        * dens
                        * (v3(p.sun_irradiance) * jv.x + v3(p.sky_radiance) * jv.y)
                } else {
                    p.albedo
                        * p.density_scale
                        * dens
                        * (v3(p.sun_irradiance) * sun_in_scatter(p, j_dirs, xp, jv, d)
                            + v3(p.sky_radiance) * (jv.y / (4.0 * std::f32::consts::PI)))
                };
                if p.single_scatter != 0 {
                    let ts = interp(p, xp, p.light_res, |i| t_sun[i]);
                    ls += single_scattered(p, dens, ts, mu);
                }
                let ts = (-sigma_t * dt).exp();
                l += tr * ls * (1.0 - ts) / sigma_t;
                tr *= ts;
            }
            t += dt;
        }
    }
    if tr >= p.early_exit {
        let mut bg = v3(p.sky_radiance);
        if p.sun_disc_radiance > 0.0 && d.dot(v3(p.sun_dir)) >= p.sun_cos_max {
            bg += v3(p.sun_irradiance) * p.sun_disc_radiance;
        }
        l += tr * bg;
    }
    l
}
