// Shared by the photon-mapping shaders (prepended by nimbus_gpu::shaders::source).
// Mirrors crates/gpu/src/params.rs (`PmParams`, #[repr(C)]; layout test in Rust) and the
// CPU reference code in crates/photon/src/reference.rs.

struct Params {
    aabb_min: vec3<f32>, density_scale: f32,
    aabb_max: vec3<f32>, albedo: f32,
    d_res: vec3<u32>, g: f32,
    i_res: vec3<u32>, sigma_max: f32,
    sun_dir: vec3<f32>, sun_cos_max: f32,
    sun_irradiance: vec3<f32>, bound_radius: f32,
    sky_radiance: vec3<f32>, d_max: f32,
    bound_center: vec3<f32>, sun_disc_radiance: f32,
    cam_origin: vec3<f32>, tan_half: f32,
    cam_forward: vec3<f32>, aspect: f32,
    cam_right: vec3<f32>, step: f32,
    cam_up: vec3<f32>, early_exit: f32,
    n_sun: u32, n_sky: u32, seed: u32, frame: u32,
    similarity_order: u32, max_order: u32, use_shared: u32, filtered: u32,
    width: u32, height: u32, beam_threshold: f32, reduced_factor: f32,
    sun_norm: f32, sky_norm: f32, noise_amplitude: f32, noise_frequency: f32,
    single_scatter: u32, density_weighted: u32, lobe_axis: u32, lobe_split: u32,
    upsample_mean: u32, upsample_g_extrapolate: u32, sun_first: u32, sun_count: u32,
};

const PI: f32 = 3.14159265358979;

// ---- PCG32 (O'Neill), one stream per beam / pixel ------------------------------------------
struct Rng { state: u32 };

fn pcg_hash(v: u32) -> u32 {
    let state = v * 747796405u + 2891336453u;
    let word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

fn rng_new(a: u32, b: u32, c: u32) -> Rng {
    return Rng(pcg_hash(a ^ pcg_hash(b ^ pcg_hash(c))));
}

fn rand(r: ptr<function, Rng>) -> f32 {
    (*r).state = (*r).state * 747796405u + 2891336453u;
    let s = (*r).state;
    let word = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    let x = (word >> 22u) ^ word;
    // 24 random bits -> [0, 1)
    return f32(x >> 8u) * (1.0 / 16777216.0);
}

// ---- Density grid: Mitsuba gridvolume convention (cell centres, clamp-to-edge, 0 outside) ---
fn inside_box(p: vec3<f32>) -> bool {
    return all(p >= P.aabb_min) && all(p <= P.aabb_max);
}

fn grid_index(x: u32, y: u32, z: u32, res: vec3<u32>) -> u32 {
    return (z * res.y + y) * res.x + x;
}

// Continuous cell-centred coordinates of p in a grid of `res` cells over the box.
fn grid_coord(p: vec3<f32>, res: vec3<u32>) -> vec3<f32> {
    return (p - P.aabb_min) / (P.aabb_max - P.aabb_min) * vec3<f32>(res) - vec3<f32>(0.5);
}

struct Trilinear { i0: vec3<u32>, i1: vec3<u32>, f: vec3<f32> };

fn trilinear(p: vec3<f32>, res: vec3<u32>) -> Trilinear {
    let u = grid_coord(p, res);
    let b = floor(u);
    let hi = vec3<f32>(res) - vec3<f32>(1.0);
    let i0 = vec3<u32>(clamp(b, vec3<f32>(0.0), hi));
    let i1 = vec3<u32>(clamp(b + vec3<f32>(1.0), vec3<f32>(0.0), hi));
    return Trilinear(i0, i1, u - b);
}

fn box_intersect(o: vec3<f32>, d: vec3<f32>) -> vec2<f32> {
    // Returns (t0, t1) with t0 > t1 for a miss; t clipped to >= 0.
    var t0 = 0.0;
    var t1 = 3.0e38;
    for (var a = 0; a < 3; a++) {
        if (d[a] == 0.0) {
            if (o[a] < P.aabb_min[a] || o[a] > P.aabb_max[a]) { return vec2<f32>(1.0, 0.0); }
        } else {
            let inv = 1.0 / d[a];
            let ta = (P.aabb_min[a] - o[a]) * inv;
            let tb = (P.aabb_max[a] - o[a]) * inv;
            t0 = max(t0, min(ta, tb));
            t1 = min(t1, max(ta, tb));
        }
    }
    return vec2<f32>(t0, t1);
}

// ---- Henyey–Greenstein (propagation convention: cos between travel directions) -------------
fn hg_eval(g: f32, mu: f32) -> f32 {
    let denom = (1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 - mu);
    return (1.0 - g * g) / (4.0 * PI * denom * sqrt(denom));
}

fn hg_sample_cos(g: f32, u: f32) -> f32 {
    let s = 2.0 * u - 1.0;
    // The Taylor branch below |g| = 1e-3, not 1e-4 as in f64 (`crates/scene/src/phase/hg.rs`):
    // in f32 the closed form loses ≈ 6e-8 / (2|g|) to cancellation (3e-5 at 1e-3, 3e-4 at
    // 1e-4), while the first-order expansion errs by O(g²) = 1e-6 at 1e-3.
    if (abs(g) < 1.0e-3) {
        return clamp(s + 1.5 * g * (1.0 - s * s), -1.0, 1.0);
    }
    let t = (1.0 - g * g) / (1.0 + g * s);
    return clamp((1.0 + g * g - t * t) / (2.0 * g), -1.0, 1.0);
}

fn around(axis: vec3<f32>, mu: f32, phi: f32) -> vec3<f32> {
    let sign = select(-1.0, 1.0, axis.z >= 0.0);
    let a = -1.0 / (sign + axis.z);
    let b = axis.x * axis.y * a;
    let t = vec3<f32>(1.0 + sign * axis.x * axis.x * a, sign * b, -sign * axis.x);
    let bb = vec3<f32>(b, sign + axis.y * axis.y * a, -axis.y);
    let st = sqrt(max(0.0, 1.0 - mu * mu));
    return normalize(t * (st * cos(phi)) + bb * (st * sin(phi)) + axis * mu);
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> density: array<f32>;

// Unscaled density at p (trilinear, 0 outside the box).
fn density_at(p: vec3<f32>) -> f32 {
    if (!inside_box(p)) { return 0.0; }
    let t = trilinear(p, P.d_res);
    let r = P.d_res;
    let c000 = density[grid_index(t.i0.x, t.i0.y, t.i0.z, r)];
    let c100 = density[grid_index(t.i1.x, t.i0.y, t.i0.z, r)];
    let c010 = density[grid_index(t.i0.x, t.i1.y, t.i0.z, r)];
    let c110 = density[grid_index(t.i1.x, t.i1.y, t.i0.z, r)];
    let c001 = density[grid_index(t.i0.x, t.i0.y, t.i1.z, r)];
    let c101 = density[grid_index(t.i1.x, t.i0.y, t.i1.z, r)];
    let c011 = density[grid_index(t.i0.x, t.i1.y, t.i1.z, r)];
    let c111 = density[grid_index(t.i1.x, t.i1.y, t.i1.z, r)];
    let f = t.f;
    let c00 = mix(c000, c100, f.x);
    let c10 = mix(c010, c110, f.x);
    let c01 = mix(c001, c101, f.x);
    let c11 = mix(c011, c111, f.x);
    return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
}
