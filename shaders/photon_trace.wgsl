// Photon-beam tracing into the partial cache H_new (Elek 2012 §4.1, Appendix A).
// CPU twin: `nimbus_photon::cpu::trace` (one beam).
//
// One invocation traces one beam: sun beams start on a disc of the bounding-sphere radius facing
// the sun, sky beams on the bounding sphere with cosine-distributed inward directions. Woodcock
// tracking with the global majorant σ̄ (σ_max) deposits at every tentative collision; since all
// deposits share the weight 1/σ̄, H holds integer sums (exact and order-independent: the same
// seed gives the same cache on every run). A real collision (probability σ_t/σ̄) multiplies the
// beam weight by the albedo (the beam stops below `beam_threshold`) and scatters with HG(g);
// after `similarity_order` scatterings the beam switches to σ' = σ √(1 − g) and isotropic
// scattering (Elek §4.1.1). Beams end when they leave the box or after `max_order` scatterings.
//
// Per cache cell, CELL_WORDS = 13 u32 (fixed point, scale W = 4096 per unit weight, stochastic
// rounding):
//   0: Σ w (sun)   1: Σ w (sky)   2, 3, 4: Σ w (d_k + 1)/2 for k = x, y, z (sun beams; d the
//   beam's propagation direction, so Σ w d = 2 (slots 2–4) − Σ w: the cell's net sun flux)
//   5: Σ min(order, 1023)   6: number of deposits
//   7, 8, 9, 10: slots 0 and 2–4 again for the sun deposits of order ≥ `P.lobe_split` only
//   (0: no split, these stay 0), so high and low orders get lobes of their own.
//   11, 12: with `P.view_mode` ≠ 0, Σ w p_HG(d · ω_v | g) for sun (11) and sky (12) deposits,
//   ω_v the unit vector from the deposit towards `P.view_origin`: a collision estimate of the
//   radiance the medium scatters towards that point (exact in angle: no lobe in between).
// The paper projects each photon on the sun direction only (§4.1.2); the flux vector gives that
// projection (`cells` in photon_upsample.wgsl) and also the per-cell lobe axis that Appendix C
// allows ("storing the direction separately for each cell").
// Workgroup-shared accumulation when the grid fits (SHARED_CELLS), else global atomics.
// With `P.density_weighted` every deposit is weighted by σ(x)/σ̄ (see `cells` in
// photon_upsample.wgsl). With exact single scattering (`P.single_scatter` = 1) an unscattered sun beam (order 0)
// deposits nothing: the ray marcher computes first-order sun light exactly from the
// sun-transmittance volume, and the cache holds only light scattered at least once.
#import params
#import grid
#import density_light
#import rng
#import hg
#import constants

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> density: array<f32>;
@group(0) @binding(2) var<storage, read_write> h_new: array<atomic<u32>>;
// Set to 1 when a u32 sum wraps (too many deposits in one cell for 32 bits): the mapper reports
// it instead of rendering a silently wrong cache.
@group(0) @binding(3) var<storage, read_write> overflow: array<atomic<u32>>;
// 1 for each cache cell that no later stage reads (no density within a cell and three light
// voxels of it: `nimbus_photon::mapper::light::skippable_cells`); read when `P.skip_empty`.
@group(0) @binding(4) var<storage, read> cell_skip: array<u32>;
// The light bricks' index and slots: the density is the work density's brick pool
// (`lib/density_light.wgsl`).
@group(0) @binding(5) var<storage, read> light_map: array<u32>;

// Cells accumulated in workgroup memory: set per pipeline by the mapper (`cache_layout.rs`).
override SHARED_CELLS: u32 = 256u;
var<workgroup> sh: array<atomic<u32>, SHARED_CELLS * CELL_WORDS>;

fn deposit(slot: u32, v: u32) {
    if (v == 0u) { return; }
    var old: u32;
    if (P.use_shared != 0u) {
        old = atomicAdd(&sh[slot], v);
    } else {
        old = atomicAdd(&h_new[slot], v);
    }
    if (old > 0xffffffffu - v) { atomicStore(&overflow[0], 1u); }
}

// Phase function value for light travelling along d at x scattered towards P.view_origin
// (isotropic when x is the view point itself).
fn view_phase(x: vec3<f32>, d: vec3<f32>) -> f32 {
    let v = P.view_origin - x;
    let l = length(v);
    if (!(l > 1.0e-20)) { return 1.0 / (4.0 * PI); }
    // `P.view_g`: the final gathering's effective anisotropy (0: the medium's).
    return hg_eval(select(P.view_g, P.g, P.view_g == 0.0), dot(d, v / l));
}

// Empty-space skipping (`P.skip_empty`): the distance that takes a beam at x along d out of its
// cell when no stage reads the cell, else −1. Free flights are memoryless, so the walk
// restarts where the beam leaves the cell: nothing changes but the deposits in a cell no stage
// reads, and the sliver of 10⁻³ of a cell by which the beam is pushed past the face (so the next
// lookup lands in the next cell). CPU twin: `skip_distance` in `cpu/trace.rs`.
fn skip_distance(x: vec3<f32>, d: vec3<f32>) -> f32 {
    let ext = P.aabb_max - P.aabb_min;
    let size = ext / vec3<f32>(P.i_res);
    let u = (x - P.aabb_min) / ext * vec3<f32>(P.i_res);
    let c = vec3<u32>(clamp(floor(u), vec3<f32>(0.0), vec3<f32>(P.i_res) - vec3<f32>(1.0)));
    if (cell_skip[grid_index(c.x, c.y, c.z, P.i_res)] == 0u) { return -1.0; }
    let lo = P.aabb_min + vec3<f32>(c) * size;
    var t = 3.0e38;
    for (var a = 0; a < 3; a++) {
        if (d[a] > 0.0) {
            t = min(t, (lo[a] + size[a] - x[a]) / d[a]);
        } else if (d[a] < 0.0) {
            t = min(t, (lo[a] - x[a]) / d[a]);
        }
    }
    return max(t, 0.0) + 1.0e-3 * min(size.x, min(size.y, size.z));
}

fn cell_of(p: vec3<f32>) -> u32 {
    let u = (p - P.aabb_min) / (P.aabb_max - P.aabb_min) * vec3<f32>(P.i_res);
    let c = vec3<u32>(clamp(floor(u), vec3<f32>(0.0), vec3<f32>(P.i_res) - vec3<f32>(1.0)));
    return grid_index(c.x, c.y, c.z, P.i_res);
}

fn trace_beam(index: u32) {
    var rng = rng_new(P.seed, P.frame, index);
    let is_sun = index < P.n_sun;
    let c = P.bound_center;
    let r = P.bound_radius;
    var o: vec3<f32>;
    var d: vec3<f32>;
    if (is_sun) {
        // Uniform point on the disc of radius r perpendicular to the sun, outside the sphere.
        let rad = r * sqrt(rand(&rng));
        let phi = 2.0 * PI * rand(&rng);
        let q = around(P.sun_dir, 0.0, phi) * rad;
        o = c + q + P.sun_dir * (2.0 * r);
        d = -P.sun_dir;
    } else {
        let z = 1.0 - 2.0 * rand(&rng);
        let phi = 2.0 * PI * rand(&rng);
        let s = sqrt(max(0.0, 1.0 - z * z));
        let n = vec3<f32>(s * cos(phi), s * sin(phi), z);
        o = c + n * r;
        // Cosine-weighted direction into the sphere.
        let mu = sqrt(rand(&rng));
        d = around(-n, mu, 2.0 * PI * rand(&rng));
    }
    let hit = box_intersect(o, d);
    if (hit.x > hit.y) { return; }
    var x = o + d * hit.x;
    var w = 1.0;
    var order = 0u;
    var steps = 0u;
    var stalled = 0u;
    loop {
        steps++;
        if (steps > 1000000u) { break; }
        if (P.skip_empty != 0u) {
            let s = skip_distance(x, d);
            if (s >= 0.0) {
                x = x + d * s;
                if (!inside_box(x)) { break; }
                continue;
            }
        }
        let exit = box_intersect(x, d);
        let t = -log(1.0 - rand(&rng)) / P.sigma_max;
        if (exit.x > exit.y || t >= exit.y) { break; }
        // A free flight below f32's resolution of x (σ̄ ≳ 1e7 / box size, e.g. density_scale
        // 1e20) would leave the beam where it is for ever: the medium is opaque at this scale,
        // so after 8 such flights in a row the beam ends here as absorbed (the walk always
        // advances or ends). One tiny flight alone (u ≈ 0) happens at normal densities too,
        // eight in a row do not (probability ≈ 1e-56).
        let x_next = x + d * t;
        if (all(x_next == x)) {
            stalled++;
            if (stalled >= 8u) { break; }
        } else {
            stalled = 0u;
        }
        x = x_next;
        // A flight that ends in a skipped cell deposits nothing there (the next pass of the
        // loop moves the beam out of the cell).
        if (P.skip_empty != 0u && skip_distance(x, d) >= 0.0) { continue; }
        let skip = is_sun && order == 0u && P.single_scatter != 0u;
        let cell = cell_of(x) * CELL_WORDS;
        // Density-weighted deposits (a collision estimator): weight σ(x)/σ̄, so a cell sums
        // σφ and the `cells` pass divides by the cell's mean σ.
        let sigma_here = P.density_scale * density_at(x);
        var dw = 1.0;
        if (P.density_weighted != 0u) { dw = sigma_here / P.sigma_max; }
        let wu = u32(floor(w * dw * W_SCALE + rand(&rng)));
        // The random numbers drawn do not depend on `skip` (the paper variant is unchanged).
        if (is_sun) {
            let cu = vec3<u32>(floor(f32(wu) * 0.5 * (d + vec3<f32>(1.0))
                + vec3<f32>(rand(&rng), rand(&rng), rand(&rng))));
            if (!skip) {
                deposit(cell, wu);
                deposit(cell + 2u, cu.x);
                deposit(cell + 3u, cu.y);
                deposit(cell + 4u, cu.z);
                if (P.lobe_split != 0u && order >= P.lobe_split) {
                    deposit(cell + 7u, wu);
                    deposit(cell + 8u, cu.x);
                    deposit(cell + 9u, cu.y);
                    deposit(cell + 10u, cu.z);
                }
            }
        } else {
            deposit(cell + 1u, wu);
        }
        // In-scattering towards the view point (drawn only in view mode, so the other modes keep
        // their random streams).
        if (P.view_mode != 0u && !skip) {
            let vu = u32(floor(w * dw * W_SCALE * view_phase(x, d) + rand(&rng)));
            deposit(cell + select(12u, 11u, is_sun), vu);
        }
        if (!skip) {
            deposit(cell + 5u, min(order, 1023u));
            deposit(cell + 6u, 1u);
        }
        let reduced = order >= P.similarity_order;
        var sigma = sigma_here;
        if (reduced) { sigma = sigma * P.reduced_factor; }
        if (rand(&rng) * P.sigma_max < sigma) {
            w = w * P.albedo;
            order++;
            if (w < P.beam_threshold || order > P.max_order) { break; }
            let u1 = rand(&rng);
            let phi = 2.0 * PI * rand(&rng);
            if (order > P.similarity_order) {
                d = around(d, 1.0 - 2.0 * u1, phi);
            } else {
                d = around(d, hg_sample_cos(P.g, u1), phi);
            }
        }
    }
}

@compute @workgroup_size(WG)
fn trace(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(local_invocation_index) lid: u32,
         @builtin(num_workgroups) nwg: vec3<u32>) {
    let cells = P.i_res.x * P.i_res.y * P.i_res.z;
    if (P.use_shared != 0u) {
        for (var i = lid; i < cells * CELL_WORDS; i += WG) { atomicStore(&sh[i], 0u); }
    }
    workgroupBarrier();
    let index = gid.x + gid.y * nwg.x * WG;
    if (index < P.n_sun + P.n_sky) {
        trace_beam(index);
    }
    workgroupBarrier();
    if (P.use_shared != 0u) {
        for (var i = lid; i < cells * CELL_WORDS; i += WG) {
            let v = atomicLoad(&sh[i]);
            if (v != 0u) {
                let old = atomicAdd(&h_new[i], v);
                if (old > 0xffffffffu - v) { atomicStore(&overflow[0], 1u); }
            }
        }
    }
}
