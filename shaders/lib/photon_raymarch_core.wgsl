// Ray marching of D and J (Elek 2012 §4.4, Appendix C): the body of the stages
// `photon_raymarch_light.wgsl` (the work density: light and grid resolutions equal),
// `photon_raymarch.wgsl` (dense density) and `photon_raymarch_bricks.wgsl` (brick map), which
// bind the density. CPU twin: `nimbus_photon::cpu::raymarch`.
// J, its flux directions and T_sun are read at `P.light_res` from the light bricks' pools
// (`lib/light_bricks.wgsl`), the density at `P.d_res`: equal unless the active bricks of the
// grid's resolution would not fit one storage binding (the photon stages then run on a
// block-averaged density at `light_res`: `nimbus_photon::mapper::light`).
// Front to back with step `P.step` (default: box diagonal / 300), a per-pixel hashed start
// offset against banding, exact per-step attenuation, early exit below `P.early_exit`
// transmittance (2 %). In-scattered radiance at x for view direction ω (propagation):
//   L_s = σ_s(x) [ E_sun J_sun(x) p_HG(ω·ω_sun | g g'(x)) + L_sky J_sky(x) / 4π ],
// i.e. the incident HG lobe of anisotropy g' convolved with the medium's HG(g) (self-convolution
// property). Behind the cloud: the sky radiance and, for a sun disc, the sun.
// The lobe's axis ω_sun is the sun's propagation direction (the paper) or, with `P.lobe_axis`,
// the local mean sun-flux direction (`j_dir`, upsampled like J; Elek Appendix C: "storing the
// direction separately for each cell"). At the shadowed and the
// camera-facing sides of a cloud the scattered light flows outwards, not along the sun: with
// the sun axis a side view loses ≈ 1/3 of the multiply scattered light (BENCHMARKS.md).
// View mode (`P.view_mode` = 2, beyond the paper): J holds the radiance scattered towards the
// camera, deposited by the trace with the exact phase function (photon_trace.wgsl words 11,
// 12), and replaces both lobe reconstructions: L_s = σ_s(x) [E_sun J_x + L_sky J_y].
// Detail (Elek §4.4): when `noise_amplitude` > 0, the lookup positions of D and J are displaced
// by three octaves of vector value noise (amplitudes 1, ½, ¼; frequencies f, 2f, 4f), which
// adds sub-voxel detail to a smooth density field.
#import params
#import grid
#import photon_lookup
#import rng
#import hg

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(3) var<storage, read_write> image: array<vec4<f32>>;

// Vector value noise in [−1, 1]³ on the integer lattice, smoothly interpolated.
fn lattice(c: vec3<i32>) -> vec3<f32> {
    let h = pcg_hash(bitcast<u32>(c.x) ^ pcg_hash(bitcast<u32>(c.y) ^ pcg_hash(bitcast<u32>(c.z))));
    let h2 = pcg_hash(h);
    let h3 = pcg_hash(h2);
    return vec3<f32>(f32(h >> 8u), f32(h2 >> 8u), f32(h3 >> 8u)) * (2.0 / 16777216.0) - vec3<f32>(1.0);
}

fn value_noise(q: vec3<f32>) -> vec3<f32> {
    let b = floor(q);
    let f = q - b;
    let s = f * f * (vec3<f32>(3.0) - 2.0 * f);
    let c = vec3<i32>(b);
    let x00 = mix(lattice(c), lattice(c + vec3<i32>(1, 0, 0)), s.x);
    let x10 = mix(lattice(c + vec3<i32>(0, 1, 0)), lattice(c + vec3<i32>(1, 1, 0)), s.x);
    let x01 = mix(lattice(c + vec3<i32>(0, 0, 1)), lattice(c + vec3<i32>(1, 0, 1)), s.x);
    let x11 = mix(lattice(c + vec3<i32>(0, 1, 1)), lattice(c + vec3<i32>(1, 1, 1)), s.x);
    return mix(mix(x00, x10, s.y), mix(x01, x11, s.y), s.z);
}

// Pipeline constant: the noise code is compiled in only when detail noise is on.
override DETAIL_NOISE: bool = false;

fn perturb(x: vec3<f32>) -> vec3<f32> {
    if (!DETAIL_NOISE || P.noise_amplitude <= 0.0) { return x; }
    let q = x * P.noise_frequency;
    let n = value_noise(q) + 0.5 * value_noise(2.0 * q) + 0.25 * value_noise(4.0 * q);
    return x + P.noise_amplitude * n;
}

@compute @workgroup_size(8, 8)
fn raymarch(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= P.width || gid.y >= P.height) { return; }
    let px = (f32(gid.x) + 0.5) / f32(P.width) * 2.0 - 1.0;
    let py = 1.0 - (f32(gid.y) + 0.5) / f32(P.height) * 2.0;
    let d = normalize(P.cam_forward + P.cam_right * (px * P.tan_half * P.aspect) + P.cam_up * (py * P.tan_half));
    var l = vec3<f32>(0.0);
    var tr = 1.0;
    let hit = box_intersect(P.cam_origin, d);
    if (hit.x <= hit.y) {
        let offset = f32(pcg_hash(gid.y * P.width + gid.x) >> 8u) * (1.0 / 16777216.0);
        var t = hit.x + offset * P.step;
        let mu = dot(d, P.sun_dir);
        let sigma_s_scale = P.albedo * P.density_scale;
        loop {
            if (t >= hit.y || tr < P.early_exit) { break; }
            let dt = min(P.step, hit.y - t);
            let x = perturb(P.cam_origin + d * (t + 0.5 * dt));
            let dens = density_at(x);
            let sigma_t = P.density_scale * dens;
            if (sigma_t > 0.0) {
                let lc = light_corners(x);
                let jv = j_at(lc);
                // Light along the axis a scattered towards the camera (−d): cos = a·(−d).
                var ls: vec3<f32>;
                if (P.view_mode == 2u) {
                    // J holds the in-scattering towards the camera itself (view mode).
                    ls = sigma_s_scale * dens * (P.sun_irradiance * jv.x + P.sky_radiance * jv.y);
                } else {
                    ls = sigma_s_scale * dens * (P.sun_irradiance * sun_in_scatter(lc, jv, d)
                        + P.sky_radiance * (jv.y / (4.0 * PI)));
                }
                if (P.single_scatter != 0u) {
                    ls += sigma_s_scale * dens * P.sun_irradiance * (t_sun_at(lc) * hg_eval(P.g, mu));
                }
                let ts = exp(-sigma_t * dt);
                l += tr * ls * (1.0 - ts) / sigma_t;
                tr *= ts;
            }
            t += dt;
        }
    }
    if (tr >= P.early_exit) {
        var bg = P.sky_radiance;
        if (P.sun_disc_radiance > 0.0 && dot(d, P.sun_dir) >= P.sun_cos_max) {
            bg += P.sun_irradiance * P.sun_disc_radiance;
        }
        l += tr * bg;
    }
    image[gid.y * P.width + gid.x] = vec4<f32>(l, 1.0);
}
