// GPU volumetric path tracer (the reference estimator's algorithm in f32): delta tracking with
// the global majorant, ratio-tracking next-event estimation to the sun (a delta light, or a disc
// sampled uniformly in its cone — NEE only, so phase-sampled paths that escape add the sky but
// not the sun; camera rays that see the disc directly add it), HG/isotropic phase sampling,
// a constant sky or an environment map (Task.env_w > 0: the nearest texel, `lib/env_map.wgsl`;
// reached by phase sampling alone, as the constant sky), Russian roulette on throughput < 1
// after 8 scatterings.
// Mirrors crates/trace/src/integrator.rs; imports Params, the grid lookups, RNG and HG. The
// stage files `pt.wgsl` (dense density) and `pt_bricks.wgsl` (brick map) import this module
// with their density module and bindings.
//
// Two modes (Task.mode):
//  0 image: one invocation per pixel, `spp` camera samples with box-filter jitter; adds
//    (R, G, B, Σ lum²) sums into out[pixel].
//  1 indirect radiance L_i (RPNN training targets, Kallweit 2017 §5.1): one invocation per
//    (task, slot); each draws `spp` samples of L_i(x, ω) for unit irradiance from the task's
//    light direction — a phase sample at x, then the path with NEE at later vertices only — and
//    writes (Σ L, Σ L², n, 0) into out[task * slots + slot].
#import params
#import grid
#import rng
#import tracking
#import hg
#import env_map
#import constants

struct Task {
    spp: u32, sample_offset: u32, mode: u32, max_depth: i32,
    n_tasks: u32, slots: u32, env_w: u32, env_h: u32,
};
struct LiTask { x: vec4<f32>, view: vec4<f32>, to_light: vec4<f32> };

@group(0) @binding(0) var<uniform> P: Params;
// binding 1 (and 5, 6): the density, declared by the stage file (`pt.wgsl`, `pt_bricks.wgsl`).
@group(0) @binding(2) var<uniform> T: Task;
@group(0) @binding(3) var<storage, read> li_tasks: array<LiTask>;
@group(0) @binding(4) var<storage, read_write> out: array<vec4<f32>>;
// The environment map's texels (RGB × scale) when Task.env_w > 0 (one black texel otherwise).
@group(0) @binding(7) var<storage, read> env: array<vec4<f32>>;

// The sky seen along d: the environment map, else the constant sky.
fn sky_along(d: vec3<f32>) -> vec3<f32> {
    if (T.env_w > 0u) { return env_radiance(d, T.env_w, T.env_h); }
    return P.sky_radiance;
}

// Radiance along o + t d for a path that has scattered `scat0` times, lit by a delta sun
// towards `sun_dir` with irradiance `sun_e` and the sky (`sky_along`: the environment map in
// image mode, the constant sky otherwise).
fn radiance(o0: vec3<f32>, d0: vec3<f32>, scat0: u32, sun_dir: vec3<f32>, sun_e: vec3<f32>, disc: bool, rng: ptr<function, Rng>) -> vec3<f32> {
    // Disc: 1 − cos r from sin² r = 1 / (π L_unit) without cancellation; solid angle Ω.
    let sin2 = select(0.0, 1.0 / (PI * P.sun_disc_radiance), disc);
    let omc = sin2 / (1.0 + P.sun_cos_max);
    let omega = 2.0 * PI * omc;
    var o = o0;
    var d = d0;
    var beta = 1.0;
    var l = vec3<f32>(0.0);
    var scat = scat0;
    loop {
        let hit = box_intersect(o, d);
        var t = -1.0;
        if (hit.x <= hit.y) { t = delta_track(o, d, hit.x, hit.y, P.sigma_max, rng); }
        if (t < 0.0) {
            l += beta * sky_along(d);
            if (disc && scat == 0u && dot(d, sun_dir) >= P.sun_cos_max) {
                l += beta * sun_e * P.sun_disc_radiance;
            }
            break;
        }
        if (T.max_depth >= 0 && i32(scat) >= T.max_depth) { break; }
        let x = o + d * t;
        scat++;
        beta *= P.albedo;
        if (beta <= 0.0) { break; }
        if (any(sun_e > vec3<f32>(0.0))) {
            var wi = sun_dir;
            var scale = 1.0;
            if (disc) {
                // Uniform in the cone: L / pdf = (E · L_unit) · Ω.
                wi = around(sun_dir, 1.0 - rand(rng) * omc, 2.0 * PI * rand(rng));
                scale = P.sun_disc_radiance * omega;
            }
            let ph = hg_eval(P.g, dot(d, wi));
            if (ph > 0.0) {
                l += beta * ph * scale * ratio_track(x, wi, P.sigma_max, rng) * sun_e;
            }
        }
        let u1 = rand(rng);
        d = around(d, hg_sample_cos(P.g, u1), 2.0 * PI * rand(rng));
        o = x;
        if (scat > 8u && beta < 1.0) {
            if (rand(rng) >= beta) { break; }
            beta = 1.0;
        }
    }
    return l;
}

@compute @workgroup_size(WG)
fn pt(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * WG;
    if (T.mode == 0u) {
        if (i >= P.width * P.height) { return; }
        let px = i % P.width;
        let py = i / P.width;
        var acc = vec4<f32>(0.0);
        for (var s = 0u; s < T.spp; s++) {
            var rng = rng_new(P.seed, i, T.sample_offset + s);
            let fx = (f32(px) + rand(&rng)) / f32(P.width) * 2.0 - 1.0;
            let fy = 1.0 - (f32(py) + rand(&rng)) / f32(P.height) * 2.0;
            let d = normalize(P.cam_forward + P.cam_right * (fx * P.tan_half * P.aspect) + P.cam_up * (fy * P.tan_half));
            let l = radiance(P.cam_origin, d, 0u, P.sun_dir, P.sun_irradiance, P.sun_disc_radiance > 0.0, &rng);
            let lum = (l.x + l.y + l.z) / 3.0;
            acc += vec4<f32>(l, lum * lum);
        }
        out[i] += acc;
    } else {
        if (i >= T.n_tasks * T.slots) { return; }
        let task = li_tasks[i / T.slots];
        let view = normalize(task.view.xyz);
        let light = normalize(task.to_light.xyz);
        var s1 = 0.0;
        var s2 = 0.0;
        for (var s = 0u; s < T.spp; s++) {
            var rng = rng_new(P.seed ^ 0x9e3779b9u, i, T.sample_offset + s);
            let dir = around(view, hg_sample_cos(P.g, rand(&rng)), 2.0 * PI * rand(&rng));
            let l = radiance(task.x.xyz, dir, 1u, light, vec3<f32>(1.0), false, &rng);
            let v = (l.x + l.y + l.z) / 3.0;
            s1 += v;
            s2 += v * v;
        }
        out[i] = vec4<f32>(s1, s2, f32(T.spp), 0.0);
    }
}
