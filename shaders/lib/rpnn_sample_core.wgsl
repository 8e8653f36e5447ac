// One RPNN sample per pixel entirely on the GPU (Kallweit 2017 §4.4; the CPU version is
// `nimbus_rpnn::render::shade` and the contraction `nimbus_rpnn::render::sky_product`). Per chunk
// of pixels and sample, four passes share these buffers:
//  1. `shade` (here): camera ray, delta tracking to the first real collision x (the path
//     tracer's `tracking` module), the direct light there — the sun by next-event estimation
//     with a ratio-tracked shadow ray (a delta sun, or a disc sampled in its cone), the sky's
//     single scattering by one phase-sampled direction — and, at x, the network queries: the
//     sun's (x, ω, ω_sun), and with the paper's sky directions (`sky_dirs`, a constant sky) one
//     more per direction, uniform on the sphere. They take consecutive slots of `configs`
//     (`counter[0]`), each with the weight of its prediction; the collision takes a head
//     (`counter[2]`) with its pixel, its first slot and count and the radiance known without the
//     network. A camera ray that leaves the volume adds the sky (and the sun's disc) to its pixel
//     at once.
//  1b. `dispatch_args` (here): workgroup counts of the later passes for the chunk's count, so
//     no pass dispatches empty workgroups (on lavapipe they cost as much as full ones);
//  2. the descriptor stage (`rpnn_descriptor.wgsl`) and 3. the layers (`rpnn_mlp.wgsl`) read
//     the `counter[0]` slots and write the network's rows;
//  4. `resolve` (here): per head, known + Σ over its slots of weight × sun head (+ sky weight ×
//     Σ t_lm c'_lm: the sky head's transfer against the sky's coefficients rotated into the
//     query's frame, by `nimbus_rpnn::sky::product_in_frame`'s sample-direction form) added to
//     the pixel's sums — one writer per pixel.
// Nothing is read back until the image is: the sums are (R, G, B, Σ lum²) per pixel.
#import params
#import grid
#import rng
#import tracking
#import hg
#import rpnn_frame
#import env_map
#import constants

struct Sample {
    first: u32,        // first pixel of the chunk
    count: u32,        // pixels in the chunk
    sample: u32,       // sample index of every pixel in this pass
    flags: u32,        // 1: a sky, 2: the sky is `env` (else P.sky_radiance), 4: the sky head
    env_w: u32, env_h: u32,
    outputs: u32,      // network values per query
    sun_outputs: u32,  // of which the sun head's (1 grey, 3 RGB)
    degree: u32,       // highest SH degree of the contraction
    rows: u32,         // slots of a chunk (the network's batch)
    sky_dirs: u32,     // the paper's sky directions per collision (constant sky; 0: none)
    query_every: u32,  // one sample in every `query_every` of a pixel asks the network (1: all)
};

struct Config { x: vec4<f32>, view: vec4<f32>, to_light: vec4<f32> };

@group(0) @binding(0) var<uniform> P: Params;
// binding 1 (and 5, 6): the density, declared by the stage file.
@group(0) @binding(2) var<uniform> S: Sample;
// [0]: this chunk's queries, [2]: its heads (both cleared per chunk); [1]: all queries since
// the sums were emptied.
@group(0) @binding(3) var<storage, read_write> counter: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read_write> configs: array<Config>;
// Per slot: (weight RGB of the sun head's prediction, weight of the sky head's contraction).
@group(0) @binding(7) var<storage, read_write> extra: array<vec4<f32>>;
// Per head (two entries): (known RGB, pixel as bits), (first slot, slots as bits, 0, 0).
@group(0) @binding(14) var<storage, read_write> heads: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> acc: array<vec4<f32>>;
// The environment map's texels (RGB × scale), rows from the zenith, when flags & 2.
@group(0) @binding(9) var<storage, read> env: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read> net: array<f32>;
// `nimbus_rpnn::sky::gpu_table`: world coefficients, band directions, band inverses.
@group(0) @binding(11) var<storage, read> sky_tab: array<f32>;
// Indirect dispatch arguments, (x, y, z) triples: the descriptor pass, the resolve pass, then
// one per network layer, whose output tiles `layer_tiles` lists (`GpuMlp::layer_tiles`).
@group(0) @binding(12) var<storage, read_write> args: array<u32>;
@group(0) @binding(13) var<storage, read> layer_tiles: array<u32>;

// Sky radiance seen along d (`nimbus_scene::EnvMap::radiance`: the nearest texel).
fn sky(d: vec3<f32>) -> vec3<f32> {
    if ((S.flags & 1u) == 0u) { return vec3<f32>(0.0); }
    if ((S.flags & 2u) == 0u) { return P.sky_radiance; }
    return env_radiance(d, S.env_w, S.env_h);
}

fn finite(v: vec3<f32>) -> bool {
    let e = vec3<u32>(0x7f800000u);
    return all((bitcast<vec3<u32>>(v) & e) != e);
}

// Adds one sample's radiance to a pixel (a non-finite value counts as black, as on the CPU).
fn add(pixel: u32, l0: vec3<f32>) {
    var l = l0;
    if (!finite(l)) { l = vec3<f32>(0.0); }
    let lum = (l.x + l.y + l.z) / 3.0;
    acc[pixel] += vec4<f32>(l, lum * lum);
}

@compute @workgroup_size(WG)
fn shade(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = gid.x + gid.y * nwg.x * WG;
    if (k >= S.count) { return; }
    let pixel = S.first + k;
    let px = pixel % P.width;
    let py = pixel / P.width;
    var rng = rng_new(P.seed ^ 0x2545f491u, pixel, S.sample);
    let fx = (f32(px) + rand(&rng)) / f32(P.width) * 2.0 - 1.0;
    let fy = 1.0 - (f32(py) + rand(&rng)) / f32(P.height) * 2.0;
    let d = normalize(P.cam_forward + P.cam_right * (fx * P.tan_half * P.aspect) + P.cam_up * (fy * P.tan_half));
    let o = P.cam_origin;
    let disc = P.sun_disc_radiance > 0.0;
    let hit = box_intersect(o, d);
    var t = -1.0;
    if (hit.x <= hit.y) { t = delta_track(o, d, hit.x, hit.y, P.sigma_max, &rng); }
    if (t < 0.0) {
        var bg = sky(d);
        if (disc && dot(d, P.sun_dir) >= P.sun_cos_max) {
            bg += P.sun_irradiance * P.sun_disc_radiance;
        }
        add(pixel, bg);
        return;
    }
    let x = o + d * t;
    let has_sun = any(P.sun_irradiance > vec3<f32>(0.0));
    var direct = vec3<f32>(0.0);
    if (has_sun) {
        var wi = P.sun_dir;
        var scale = 1.0;
        if (disc) {
            // Uniform in the cone (`pt_core`): L / pdf = (E · L_unit) · Ω.
            let omc = (1.0 / (PI * P.sun_disc_radiance)) / (1.0 + P.sun_cos_max);
            wi = around(P.sun_dir, 1.0 - rand(&rng) * omc, 2.0 * PI * rand(&rng));
            scale = P.sun_disc_radiance * 2.0 * PI * omc;
        }
        let ph = hg_eval(P.g, dot(d, wi));
        if (ph > 0.0) {
            direct += ph * scale * ratio_track(x, wi, P.sigma_max, &rng) * P.sun_irradiance;
        }
    }
    let has_sky = (S.flags & 1u) != 0u;
    if (has_sky) {
        // The sky's single scattering: one phase-sampled direction (p / pdf = 1).
        let wi = around(d, hg_sample_cos(P.g, rand(&rng)), 2.0 * PI * rand(&rng));
        let l = sky(wi);
        if (any(l > vec3<f32>(0.0))) {
            direct += ratio_track(x, wi, P.sigma_max, &rng) * l;
        }
    }
    let known = P.albedo * direct;
    // One sample in every S.query_every asks the network (`nimbus_rpnn::render::asks_network`'s
    // rule): when (sample + offset) mod query_every = 0, the offset ⌊u m / 2²⁴⌋ per pixel from
    // 24 random bits u of its own stream (uniform up to 2⁻²⁴; u m < 2³⁰ for m ≤ 64); the
    // answers are weighted query_every, so the sum is unbiased at any number of samples.
    var m = 1.0;
    let every = S.query_every;
    if (every > 1u) {
        var orng = rng_new(P.seed ^ 0x6a09e667u, pixel, 0xffffffffu);
        let offset = (rand_u24(&orng) * every) >> 24u;
        if ((S.sample + offset) % every != 0u) {
            add(pixel, known);
            return;
        }
        m = f32(every);
    }
    // The first query: the sun's frame when there is a sun, else the zenith's (for the sky
    // head); then the paper's sky directions.
    let sky_w = select(0.0, m * P.albedo, has_sky && (S.flags & 4u) != 0u);
    let first = u32(has_sun || sky_w != 0.0);
    // (no directions for a black sky: their weights would be 0, as the CPU leaves them out)
    let dirs = select(0u, S.sky_dirs, has_sky && any(P.sky_radiance > vec3<f32>(0.0)));
    let n = first + dirs;
    if (n == 0u) {
        add(pixel, known);
        return;
    }
    let base = atomicAdd(&counter[0], n);
    atomicAdd(&counter[1], n);
    let h = atomicAdd(&counter[2], 1u);
    heads[2u * h] = vec4<f32>(known, bitcast<f32>(pixel));
    heads[2u * h + 1u] = vec4<f32>(bitcast<f32>(base), bitcast<f32>(n), 0.0, 0.0);
    if (first == 1u) {
        let to_light = select(vec3<f32>(0.0, 1.0, 0.0), P.sun_dir, has_sun);
        let sun_w = select(vec3<f32>(0.0), m * P.albedo * P.sun_irradiance, has_sun);
        configs[base] = Config(vec4<f32>(x, 0.0), vec4<f32>(d, 0.0), vec4<f32>(to_light, 0.0));
        extra[base] = vec4<f32>(sun_w, sky_w);
    }
    // The paper's sky directions (Kallweit §4.4): uniform on the sphere, each prediction per
    // unit irradiance weighted by 4π L_sky / N (a constant sky).
    let w = m * P.albedo * P.sky_radiance * (4.0 * PI / f32(max(dirs, 1u)));
    for (var k = 0u; k < dirs; k++) {
        let z = 1.0 - 2.0 * rand(&rng);
        let phi = 2.0 * PI * rand(&rng);
        let r = sqrt(max(0.0, 1.0 - z * z));
        let wi = vec3<f32>(r * cos(phi), r * sin(phi), z);
        let slot = base + first + k;
        configs[slot] = Config(vec4<f32>(x, 0.0), vec4<f32>(d, 0.0), vec4<f32>(wi, 0.0));
        extra[slot] = vec4<f32>(w, 0.0);
    }
}

// (x, y) workgroups covering n one-dimensional invocations (`nimbus_gpu::Gpu::workgroups_1d`).
fn groups_1d(n: u32) -> vec2<u32> {
    let wg = max((n + WG - 1u) / WG, 1u);
    if (wg <= 65535u) { return vec2<u32>(wg, 1u); }
    return vec2<u32>(65535u, (wg + 65534u) / 65535u);
}

fn put_args(k: u32, x: u32, y: u32) {
    args[3u * k] = x;
    args[3u * k + 1u] = y;
    args[3u * k + 2u] = 1u;
}

@compute @workgroup_size(1)
fn dispatch_args() {
    let n = min(atomicLoad(&counter[0]), S.rows);
    let d = groups_1d(n * DESCRIPTOR_LEN);
    put_args(0u, d.x, d.y);
    let r = groups_1d(min(atomicLoad(&counter[2]), S.rows));
    put_args(1u, r.x, r.y);
    let row_tiles = max((n + MLP_TILE_ROWS - 1u) / MLP_TILE_ROWS, 1u);
    for (var k = 0u; k < arrayLength(&layer_tiles); k++) {
        put_args(2u + k, layer_tiles[k], row_tiles);
    }
}

// Real orthonormal spherical harmonic `i` (= l² + l + m) at the unit vector d
// (`nimbus_rpnn::sky::eval`).
fn sh(i: u32, d: vec3<f32>) -> f32 {
    let x = d.x;
    let y = d.y;
    let z = d.z;
    let x2 = x * x;
    let y2 = y * y;
    let z2 = z * z;
    switch i {
        case 0u: { return 0.2820947917738781; }
        case 1u: { return 0.4886025119029199 * y; }
        case 2u: { return 0.4886025119029199 * z; }
        case 3u: { return 0.4886025119029199 * x; }
        case 4u: { return 1.092548430592079 * x * y; }
        case 5u: { return 1.092548430592079 * y * z; }
        case 6u: { return 0.31539156525252005 * (3.0 * z2 - 1.0); }
        case 7u: { return 1.092548430592079 * x * z; }
        case 8u: { return 0.5462742152960395 * (x2 - y2); }
        case 9u: { return 0.5900435899266435 * y * (3.0 * x2 - y2); }
        case 10u: { return 2.890611442640554 * x * y * z; }
        case 11u: { return 0.4570457994644658 * y * (5.0 * z2 - 1.0); }
        case 12u: { return 0.3731763325901154 * z * (5.0 * z2 - 3.0); }
        case 13u: { return 0.4570457994644658 * x * (5.0 * z2 - 1.0); }
        case 14u: { return 1.445305721320277 * z * (x2 - y2); }
        case 15u: { return 0.5900435899266435 * x * (x2 - 3.0 * y2); }
        case 16u: { return 2.5033429417967045 * x * y * (x2 - y2); }
        case 17u: { return 1.7701307697799305 * y * z * (3.0 * x2 - y2); }
        case 18u: { return 0.9461746957575601 * x * y * (7.0 * z2 - 1.0); }
        case 19u: { return 0.6690465435572892 * y * z * (7.0 * z2 - 3.0); }
        case 20u: { return 0.10578554691520422 * (35.0 * z2 * z2 - 30.0 * z2 + 3.0); }
        case 21u: { return 0.6690465435572892 * x * z * (7.0 * z2 - 3.0); }
        case 22u: { return 0.473087347878780 * (x2 - y2) * (7.0 * z2 - 1.0); }
        case 23u: { return 1.7701307697799305 * x * z * (x2 - 3.0 * y2); }
        default: { return 0.6258357354491761 * (x2 * (x2 - 3.0 * y2) - y2 * (3.0 * x2 - y2)); }
    }
}

// Σ t_lm c'_lm up to S.degree for the transfer at net[base ..] in the frame of `cfg`
// (`nimbus_rpnn::sky::product_in_frame`): per band, (B⁻ᵀ t_l) · (band l of the sky along the
// rotated sample directions).
fn sky_product(cfg: Config, base: u32) -> vec3<f32> {
    let f = rpnn_frame(cfg.view.xyz, cfg.to_light.xyz);
    var out = vec3<f32>(0.0);
    var inv_o = 150u;
    for (var l = 0u; l <= S.degree; l++) {
        let n = 2u * l + 1u;
        let o = l * l;
        for (var i = 0u; i < n; i++) {
            var u = 0.0;
            for (var m = 0u; m < n; m++) {
                u += sky_tab[inv_o + m * n + i] * net[base + o + m];
            }
            let di = 75u + 3u * (o + i);
            let w = f * vec3<f32>(sky_tab[di], sky_tab[di + 1u], sky_tab[di + 2u]);
            var s = vec3<f32>(0.0);
            for (var m = 0u; m < n; m++) {
                let c = 3u * (o + m);
                s += vec3<f32>(sky_tab[c], sky_tab[c + 1u], sky_tab[c + 2u]) * sh(o + m, w);
            }
            out += u * s;
        }
        inv_o += n * n;
    }
    return out;
}

@compute @workgroup_size(WG)
fn resolve(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let h = gid.x + gid.y * nwg.x * WG;
    if (h >= min(S.rows, atomicLoad(&counter[2]))) { return; }
    let e0 = heads[2u * h];
    let e1 = heads[2u * h + 1u];
    let base = bitcast<u32>(e1.x);
    let n = bitcast<u32>(e1.y);
    var l = e0.xyz;
    for (var k = 0u; k < n; k++) {
        let slot = base + k;
        let w = extra[slot];
        let row = slot * S.outputs;
        var pred = vec3<f32>(net[row]);
        if (S.sun_outputs >= 3u) { pred = vec3<f32>(net[row], net[row + 1u], net[row + 2u]); }
        l += w.xyz * pred;
        if (w.w != 0.0) {
            l += w.w * sky_product(configs[slot], row + S.sun_outputs);
        }
    }
    add(bitcast<u32>(e0.w), l);
}
