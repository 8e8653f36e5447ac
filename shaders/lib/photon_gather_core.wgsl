// Final gathering from the photon map (beyond Elek 2012; Jensen's final gather applied to the
// paper's cache): the body of the stages `photon_gather.wgsl` (dense density),
// `photon_gather_bricks.wgsl` (brick map) and `photon_gather_light.wgsl` (the work density),
// which bind the density. CPU twin: `nimbus_photon::cpu::gather`.
//
// One invocation adds one sample to one pixel's running sums (`acc`: R, G, B, lum²). The
// camera ray goes through a uniformly jittered point of the pixel (box filter, as the path
// tracer). Its radiance is L = ∫ T σ_s (S₁ + Q) dt + T_∞ L_bg, where S₁ is the sun's single
// scattering and Q the in-scattering of light already scattered at least once (and of the sky):
//  - `G.shadow_rays` = 0 (the default): the single scattering and the background are ray
//    marched as in `photon_raymarch_core` (step `P.step` from a random offset, exact per-step
//    attenuation, T_sun from the sun-transmittance volume, Russian roulette below
//    `P.early_exit` instead of the marcher's cut-off), noise-free up to the pixel jitter; Q is
//    estimated at one collision x₁ found by delta tracking (pdf T σ_t, weight albedo);
//  - `G.shadow_rays` = 1: no marching; at x₁ the sun is next-event estimated with a
//    ratio-tracked shadow ray (a disc sampled in its cone), as at every later collision, and a
//    ray that leaves the box adds the sky (and the sun disc): with k beyond every path's length
//    this is the path tracer (`pt_core`, the same tracking and Russian roulette).
// Q at x_j is gathered: below k = `G.bounces` bounces a direction is drawn from the phase
// function and a free flight finds x_{j+1}, where the sun is next-event estimated (T_sun from
// the volume, or a shadow ray) and a ray that leaves the box adds the sky; at x_{k+1} the path
// ends with the photon map's in-scattering of the light arriving there already scattered (the
// exact variant's cache holds sun light of order ≥ 1 and all sky light): the view-dependent
// words traced for the end point (phase HG(g^(1 + k c)), `mapper/gather.rs` `Terminal::View`)
// when J holds them, else the two flux lobes (`photon_lookup`). A path does not end in a cache
// cell whose mean density is below `G.min_fill` of its largest (the cloud's features smaller
// than the cell: its words average their light over mostly empty space) but bounces on, up to
// `G.max_extra` bounces. Sun
// orders 1 … k + 1 are thus exact and the cache carries the rest, seen through k phase-sampled
// bounces that average its spatial blotches and, as g^k, the lobes' angular error; with k = 0
// the estimate is a Monte Carlo version of the ray marcher's integral (the same J and T_sun).
#import params
#import grid
#import photon_lookup
#import tracking
#import rng
#import hg
#import math

// Mirrors `nimbus_photon::mapper::GatherParams`: k, the sun's next-event estimate (0: the
// T_sun volume, 1: shadow rays), the first sample's index and the sample count of this
// dispatch, the seed, the tracked density's majorant, whether J holds the view words, and the
// factor on the running sums before this dispatch adds to them (1 but in a live view whose ring
// is being replaced), the cell fill a path needs to end with the cache and the most bounces
// beyond k it takes looking for one.
struct Gather {
    bounces: u32, shadow_rays: u32, sample: u32, seed: u32,
    sigma_max: f32, view_words: u32, count: u32, decay: f32,
    min_fill: f32, max_extra: u32, _a: u32, _b: u32,
};

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(3) var<storage, read_write> acc: array<vec4<f32>>;
@group(0) @binding(10) var<uniform> G: Gather;
// Per cache cell (`P.i_res`), its mean density over its largest (`mapper::light::cell_fills`).
@group(0) @binding(11) var<storage, read> cell_fill: array<f32>;

// Whether a path may end with the cache at x: its cache cell resolves the cloud (see the
// header), or the path has bounced `G.max_extra` times beyond k looking for one.
fn cache_resolves(x: vec3<f32>, scat: u32) -> bool {
    if (scat > G.bounces + G.max_extra) { return true; }
    let u = (x - P.aabb_min) / (P.aabb_max - P.aabb_min) * vec3<f32>(P.i_res);
    let c = vec3<u32>(clamp(floor(u), vec3<f32>(0.0), vec3<f32>(P.i_res) - vec3<f32>(1.0)));
    return cell_fill[grid_index(c.x, c.y, c.z, P.i_res)] >= G.min_fill;
}

// In-scattered radiance per unit σ_s at x for light arriving along d (scattered towards −d),
// from the photon map: sun light of order ≥ 1 and sky light — the view-dependent words traced
// for this terminal (phase HG(g^(1 + k c)) towards the camera) when J holds them, else the lobes.
fn cache_in_scatter(x: vec3<f32>, d: vec3<f32>) -> vec3<f32> {
    let lc = light_corners(x);
    let jv = j_at(lc);
    if (G.view_words != 0u) {
        return P.sun_irradiance * jv.x + P.sky_radiance * jv.y;
    }
    return P.sun_irradiance * sun_in_scatter(lc, jv, d) + P.sky_radiance * (jv.y / (4.0 * PI));
}

// Sun light scattered at x towards −d, next-event estimated (without the albedo).
fn sun_nee(x: vec3<f32>, d: vec3<f32>, rng: ptr<function, Rng>) -> vec3<f32> {
    if (all(P.sun_irradiance <= vec3<f32>(0.0))) { return vec3<f32>(0.0); }
    if (G.shadow_rays == 0u) {
        return P.sun_irradiance * (t_sun_at(light_corners(x)) * hg_eval(P.g, dot(d, P.sun_dir)));
    }
    var wi = P.sun_dir;
    var scale = 1.0;
    if (P.sun_disc_radiance > 0.0) {
        // Uniform in the cone (as `pt_core`): L / pdf = (E · L_unit) · Ω.
        let omc = (1.0 / (PI * P.sun_disc_radiance)) / (1.0 + P.sun_cos_max);
        wi = around(P.sun_dir, 1.0 - rand(rng) * omc, 2.0 * PI * rand(rng));
        scale = P.sun_disc_radiance * 2.0 * PI * omc;
    }
    let ph = hg_eval(P.g, dot(d, wi));
    if (ph <= 0.0) { return vec3<f32>(0.0); }
    return P.sun_irradiance * (ph * scale * ratio_track(x, wi, G.sigma_max, rng));
}

// Radiance along o + t d after the collision count `scat0` (0: the camera ray), with the sun
// next-event estimated at every collision (from the volume or by shadow rays) except at the
// first when `skip_first_sun` (its single scattering is marched).
fn gather_path(o0: vec3<f32>, d0: vec3<f32>, skip_first_sun: bool, rng: ptr<function, Rng>) -> vec3<f32> {
    var o = o0;
    var d = d0;
    var beta = 1.0;
    var l = vec3<f32>(0.0);
    var scat = 0u;
    loop {
        let hit = box_intersect(o, d);
        var t = -1.0;
        if (hit.x <= hit.y) { t = delta_track(o, d, hit.x, hit.y, G.sigma_max, rng); }
        if (t < 0.0) {
            // The camera ray's background is marched with its single scattering.
            if (scat > 0u || !skip_first_sun) {
                l += beta * P.sky_radiance;
                if (scat == 0u && P.sun_disc_radiance > 0.0 && dot(d, P.sun_dir) >= P.sun_cos_max) {
                    l += beta * P.sun_irradiance * P.sun_disc_radiance;
                }
            }
            break;
        }
        let x = o + d * t;
        scat++;
        beta *= P.albedo;
        if (beta <= 0.0) { break; }
        if (scat > 1u || !skip_first_sun) {
            l += beta * sun_nee(x, d, rng);
        }
        if (scat > G.bounces && cache_resolves(x, scat)) {
            l += beta * cache_in_scatter(x, d);
            break;
        }
        d = around(d, hg_sample_cos(P.g, rand(rng)), 2.0 * PI * rand(rng));
        o = x;
        if (scat > 8u && beta < 1.0) {
            if (rand(rng) >= beta) { break; }
            beta = 1.0;
        }
    }
    return l;
}

// The camera ray's single scattering and background, ray marched (see the header).
fn march_single(o: vec3<f32>, d: vec3<f32>, rng: ptr<function, Rng>) -> vec3<f32> {
    var l = vec3<f32>(0.0);
    var tr = 1.0;
    let hit = box_intersect(o, d);
    if (hit.x <= hit.y) {
        var t = hit.x + rand(rng) * P.step;
        let ph = hg_eval(P.g, dot(d, P.sun_dir));
        let sigma_s_scale = P.albedo * P.density_scale;
        loop {
            if (t >= hit.y) { break; }
            if (tr < P.early_exit) {
                // Russian roulette instead of the marcher's cut-off: unbiased.
                if (rand(rng) < 0.5) { tr = 0.0; break; }
                tr *= 2.0;
            }
            let dt = min(P.step, hit.y - t);
            let x = o + d * (t + 0.5 * dt);
            let dens = density_at(x);
            let sigma_t = P.density_scale * dens;
            if (sigma_t > 0.0) {
                let ls = sigma_s_scale * dens * P.sun_irradiance * (t_sun_at(light_corners(x)) * ph);
                let ts = exp(-sigma_t * dt);
                l += tr * ls * (1.0 - ts) / sigma_t;
                tr *= ts;
            }
            t += dt;
        }
    }
    var bg = P.sky_radiance;
    if (P.sun_disc_radiance > 0.0 && dot(d, P.sun_dir) >= P.sun_cos_max) {
        bg += P.sun_irradiance * P.sun_disc_radiance;
    }
    return l + tr * bg;
}

@compute @workgroup_size(8, 8)
fn gather(@builtin(global_invocation_id) gid: vec3<u32>) {
    if (gid.x >= P.width || gid.y >= P.height) { return; }
    let i = gid.y * P.width + gid.x;
    var sum = vec4<f32>(0.0);
    for (var s = 0u; s < G.count; s++) {
        var rng = rng_new(G.seed, i, G.sample + s);
        let fx = (f32(gid.x) + rand(&rng)) / f32(P.width) * 2.0 - 1.0;
        let fy = 1.0 - (f32(gid.y) + rand(&rng)) / f32(P.height) * 2.0;
        let d = normalize(P.cam_forward + P.cam_right * (fx * P.tan_half * P.aspect) + P.cam_up * (fy * P.tan_half));
        var l: vec3<f32>;
        if (G.shadow_rays == 0u) {
            l = march_single(P.cam_origin, d, &rng) + gather_path(P.cam_origin, d, true, &rng);
        } else {
            l = gather_path(P.cam_origin, d, false, &rng);
        }
        // A non-finite sample (never expected) would poison the running sums for good.
        if (any(l != l) || any(abs(l) > vec3<f32>(3.0e38))) { l = vec3<f32>(0.0); }
        let lum = (l.x + l.y + l.z) / 3.0;
        sum += vec4<f32>(l, lum * lum);
    }
    acc[i] = acc[i] * G.decay + sum;
}
