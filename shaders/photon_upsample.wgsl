// Physically based upsampling of the cache I to J at the light resolution (the density's, or
// coarser for large grids: `mapper/light.rs`) (Elek 2012 §4.3).
// CPU twins: `nimbus_photon::cpu::{cells, upsample, upsample_dirs}` (GPU = CPU tests).
//
// For each fine voxel p and each of the 3×3×3 coarse cells q around p's coarse cell:
//   w_L = f_exp(|p − q| | λ, r) · max(1 − |D(p) − D(q)| / D_max, 0),
//   λ = σ_s (D(p) − D(q)) / 2, r = 1.5 × smallest coarse cell side,
//   w_g = |g|^δ, δ = γ(p) − γ(q) (γ = penetration depth, trilinear in I),
//   J_L = Σ I_L w_L / Σ w_L,   J_g' = Σ g'(q) w_g w_L / Σ w_g w_L (cells with sun flux only).
// Two readings of the paper are selectable and were measured against the path tracer and
// Mitsuba (BENCHMARKS.md "Upsampling readings"); the printed formulas stay the default because
// they are closer: λ as the mean extinction σ_s (D(p) + D(q))/2 (`P.upsample_mean`) and g'
// extrapolated as Σ g'(q) g^δ w_L / Σ w_L (`P.upsample_g_extrapolate`) are both worse.
// f_exp is evaluated in the stable form of `cpu::f_exp` (series for |λ r| < 0.05, no
// overflow for large |λ r|, λ < 0 allowed). If every weight vanishes, trilinear interpolation
// of I is used. With `filtered == 0` (I and J of equal resolution) J is I converted to
// physical units, without filtering.
// J layout: 4 floats per voxel: sun fluence per unit irradiance, sky fluence per unit radiance,
// g', γ (with `P.view_mode` = 2: in-scattered radiance towards the view point per unit sun
// irradiance and per unit sky radiance instead of the two fluences). The lobe's axis: the sun's propagation direction (`P.lobe_axis` = 0, the paper, g' =
// the mean cosine to it), or each cell's mean sun-flux direction (1, Appendix C's per-cell
// direction; g' = |mean propagation vector|), kept per coarse cell in `cell_dir` and
// interpolated by the ray marcher.
#import params
#import grid
#import density_light
#import constants

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> density: array<f32>;
@group(0) @binding(2) var<storage, read> total: array<u32>;
@group(0) @binding(3) var<storage, read_write> j_out: array<vec4<f32>>;
// Per coarse cell, computed once by `cells` before `upsample` reads them 27 + 8 times per voxel:
// (sun fluence, sky fluence, g', γ) and (D at the cell centre, has sun flux, 0, 0).
@group(0) @binding(4) var<storage, read_write> cell_vals: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> cell_aux: array<vec4<f32>>;
// Per coarse cell, two entries: the mean propagation vector Σ w d / Σ w of its low-order sun
// light (orders below `P.lobe_split`; all orders when that is 0) with 1 when there is such
// light, and that of its high-order sun light with the high-order fluence.
@group(0) @binding(6) var<storage, read_write> cell_dirs: array<vec4<f32>>;
// Per fine voxel (flux axes only): the upsampled mean propagation vectors, Σ w_L v(q) / Σ w_L
// over the cells with such light (a flux is linear in the deposits: averaged as a vector, its
// length falls where directions diverge, which widens the lobe as it should). j_dir: low
// orders and the upsampled high-order fluence; j_hi: high orders.
@group(0) @binding(7) var<storage, read_write> j_dir: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> j_hi: array<vec4<f32>>;
// The light bricks' index and slots: J and the work density are pools of the stored bricks.
@group(0) @binding(9) var<storage, read> light_map: array<u32>;


struct CellValue {
    sun: f32, sky: f32, g: f32, gamma: f32, has_sun: bool,
    // Low-order (or, without a split, all) sun light: mean propagation vector, present.
    dir: vec3<f32>, has_lo: bool,
    // High-order sun light: fluence (part of `sun`) and mean propagation vector.
    sun_hi: f32, dir_hi: vec3<f32>,
};

// Mean density over coarse cell c (4×4×4 stratified samples of the trilinear field): the
// divisor of density-weighted sums, which estimate ⟨σφ⟩ over the cell.
fn cell_mean_density(c: vec3<u32>) -> f32 {
    let lo = P.aabb_min + vec3<f32>(c) / vec3<f32>(P.i_res) * (P.aabb_max - P.aabb_min);
    let size = (P.aabb_max - P.aabb_min) / vec3<f32>(P.i_res);
    var s = 0.0;
    for (var k = 0u; k < 64u; k++) {
        let u = (vec3<f32>(f32(k % 4u), f32((k / 4u) % 4u), f32(k / 16u)) + vec3<f32>(0.5)) * 0.25;
        s += density_at(lo + u * size);
    }
    return s / 64.0;
}

fn cell_value(i: u32) -> CellValue {
    let b = i * CELL_WORDS;
    let w_sun = f32(total[b]);
    let w_sky = f32(total[b + 1u]);
    let cw = vec3<f32>(f32(total[b + 2u]), f32(total[b + 3u]), f32(total[b + 4u]));
    let ord = f32(total[b + 5u]);
    let n = f32(total[b + 6u]);
    var g = 0.0;
    if (w_sun > 0.0) {
        let all = 2.0 * cw / w_sun - vec3<f32>(1.0);
        if (P.lobe_axis != 0u) {
            g = min(length(all), 0.999);
        } else {
            g = clamp(dot(all, -P.sun_dir), -0.999, 0.999);
        }
    }
    // High orders (slots 7–10, a subset of the sums in 0 and 2–4) and the rest, in integers.
    let hi_u = total[b + 7u];
    let cw_hi_u = vec3<u32>(total[b + 8u], total[b + 9u], total[b + 10u]);
    let lo_u = total[b] - hi_u;
    let cw_lo = vec3<f32>(vec3<u32>(total[b + 2u], total[b + 3u], total[b + 4u]) - cw_hi_u);
    var dir = vec3<f32>(0.0);
    if (lo_u > 0u) { dir = 2.0 * cw_lo / f32(lo_u) - vec3<f32>(1.0); }
    var dir_hi = vec3<f32>(0.0);
    if (hi_u > 0u) { dir_hi = 2.0 * vec3<f32>(cw_hi_u) / f32(hi_u) - vec3<f32>(1.0); }
    var gamma = 0.0;
    if (n > 0.0) { gamma = ord / n; }
    var scale = 1.0;
    if (P.density_weighted != 0u) {
        let c = vec3<u32>(i % P.i_res.x, (i / P.i_res.x) % P.i_res.y, i / (P.i_res.x * P.i_res.y));
        let m = cell_mean_density(c) / P.d_max;
        scale = select(0.0, 1.0 / m, m > 0.0);
    }
    // View mode 2: the cell's sun and sky values are the in-scattering towards the view point
    // (words 11, 12) per unit irradiance / radiance, upsampled like the fluences they replace.
    var v_sun = w_sun;
    var v_sky = w_sky;
    if (P.view_mode == 2u) {
        v_sun = f32(total[b + 11u]);
        v_sky = f32(total[b + 12u]);
    }
    return CellValue(v_sun * P.sun_norm * scale, v_sky * P.sky_norm * scale, g, gamma, w_sun > 0.0,
        dir, lo_u > 0u, f32(hi_u) * P.sun_norm * scale, dir_hi);
}

@compute @workgroup_size(WG)
fn cells(@builtin(global_invocation_id) gid: vec3<u32>) {
    let n = P.i_res.x * P.i_res.y * P.i_res.z;
    let i = gid.x;
    if (i >= n) { return; }
    let cv = cell_value(i);
    cell_vals[i] = vec4<f32>(cv.sun, cv.sky, cv.g, cv.gamma);
    let c = vec3<u32>(i % P.i_res.x, (i / P.i_res.x) % P.i_res.y, i / (P.i_res.x * P.i_res.y));
    cell_aux[i] = vec4<f32>(density_at(coarse_centre(c)), select(0.0, 1.0, cv.has_sun), 0.0, 0.0);
    cell_dirs[2u * i] = vec4<f32>(cv.dir, select(0.0, 1.0, cv.has_lo));
    cell_dirs[2u * i + 1u] = vec4<f32>(cv.dir_hi, cv.sun_hi);
}

fn coarse_centre(c: vec3<u32>) -> vec3<f32> {
    return P.aabb_min + (vec3<f32>(c) + vec3<f32>(0.5)) / vec3<f32>(P.i_res) * (P.aabb_max - P.aabb_min);
}

fn f_exp(d: f32, lambda: f32, r: f32) -> f32 {
    if (d >= r) { return 0.0; }
    let y = lambda * r;
    let u = d / r;
    let v = 1.0 - u;
    if (abs(y) < 0.05) {
        return 2.0 / r * v * (1.0 + y * v / 2.0 + y * y * v * v / 6.0) / (1.0 + y / 3.0 + y * y / 12.0);
    }
    if (y > 0.0) {
        let num = exp(-y * u) * (1.0 - exp(-y * v));
        let den = 1.0 - (1.0 + y) * exp(-y);
        return max(y / r * num / den, 0.0);
    }
    // y < 0: expm1 form, no overflow.
    let num = exp(y * v) - 1.0;
    let den = exp(y) - 1.0 - y;
    return max(y / r * num / den, 0.0);
}

fn gamma_at(p: vec3<f32>) -> f32 {
    let t = trilinear(p, P.i_res);
    let r = P.i_res;
    let f = t.f;
    let c00 = mix(cell_vals[grid_index(t.i0.x, t.i0.y, t.i0.z, r)].w, cell_vals[grid_index(t.i1.x, t.i0.y, t.i0.z, r)].w, f.x);
    let c10 = mix(cell_vals[grid_index(t.i0.x, t.i1.y, t.i0.z, r)].w, cell_vals[grid_index(t.i1.x, t.i1.y, t.i0.z, r)].w, f.x);
    let c01 = mix(cell_vals[grid_index(t.i0.x, t.i0.y, t.i1.z, r)].w, cell_vals[grid_index(t.i1.x, t.i0.y, t.i1.z, r)].w, f.x);
    let c11 = mix(cell_vals[grid_index(t.i0.x, t.i1.y, t.i1.z, r)].w, cell_vals[grid_index(t.i1.x, t.i1.y, t.i1.z, r)].w, f.x);
    return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
}

// Trilinear (sun, sky, high-order sun) fluence of the coarse cells.
fn trilinear_fluence(p: vec3<f32>) -> vec3<f32> {
    let t = trilinear(p, P.i_res);
    let r = P.i_res;
    var acc = vec3<f32>(0.0);
    for (var k = 0u; k < 8u; k++) {
        let sx = (k & 1u) != 0u;
        let sy = (k & 2u) != 0u;
        let sz = (k & 4u) != 0u;
        let ix = select(t.i0.x, t.i1.x, sx);
        let iy = select(t.i0.y, t.i1.y, sy);
        let iz = select(t.i0.z, t.i1.z, sz);
        let wx = select(1.0 - t.f.x, t.f.x, sx);
        let wy = select(1.0 - t.f.y, t.f.y, sy);
        let wz = select(1.0 - t.f.z, t.f.z, sz);
        let ci = grid_index(ix, iy, iz, r);
        acc += vec3<f32>(cell_vals[ci].xy, cell_dirs[2u * ci + 1u].w) * (wx * wy * wz);
    }
    return acc;
}

@compute @workgroup_size(WG)
fn upsample(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    // Pool entries from 512 on: the voxels of the stored bricks (`lib/light_bricks.wgsl`).
    let local = gid.x + gid.y * nwg.x * WG;
    if (local >= P.light_voxels) { return; }
    let idx = 512u + local;
    let res = P.d_res;
    let v = light_voxel(idx);
    let x = v.x;
    let y = v.y;
    let z = v.z;
    // Voxels past the grid's edge in its last bricks are never read.
    if (any(v >= res)) { return; }
    if (P.filtered == 0u) {
        let ci = grid_index(x, y, z, res);
        j_out[idx] = cell_vals[ci];
        if (P.lobe_axis != 0u) {
            j_dir[idx] = vec4<f32>(cell_dirs[2u * ci].xyz, cell_dirs[2u * ci + 1u].w);
            j_hi[idx] = vec4<f32>(cell_dirs[2u * ci + 1u].xyz, 0.0);
        }
        return;
    }
    // J is read only where σ(x) > 0, i.e. next to density (`near_density`): elsewhere 0,
    // so the empty space of a sparse box costs 27 reads per voxel, not a 27-cell filter.
    if (!near_density(v)) {
        j_out[idx] = vec4<f32>(0.0);
        if (P.lobe_axis != 0u) {
            j_dir[idx] = vec4<f32>(0.0);
            j_hi[idx] = vec4<f32>(0.0);
        }
        return;
    }
    let ext = P.aabb_max - P.aabb_min;
    let p = P.aabb_min + (vec3<f32>(f32(x), f32(y), f32(z)) + vec3<f32>(0.5)) / vec3<f32>(res) * ext;
    let dp = density[idx];
    let cell = ext / vec3<f32>(P.i_res);
    let radius = 1.5 * min(cell.x, min(cell.y, cell.z));
    let uc = (p - P.aabb_min) / ext * vec3<f32>(P.i_res);
    let c = vec3<i32>(clamp(floor(uc), vec3<f32>(0.0), vec3<f32>(P.i_res) - vec3<f32>(1.0)));
    let sigma_s = P.albedo * P.density_scale;
    let gp = gamma_at(p);
    let lng = log(max(abs(P.g), 1.0e-30));
    var sw = 0.0;
    var s_sun = 0.0;
    var s_sky = 0.0;
    var swg = 0.0;
    var s_g = 0.0;
    var s_dir = vec3<f32>(0.0);
    var sw_dir = 0.0;
    var s_hi = 0.0;
    var s_dir_hi = vec3<f32>(0.0);
    var sw_dir_hi = 0.0;
    for (var dz = -1; dz <= 1; dz++) {
        for (var dy = -1; dy <= 1; dy++) {
            for (var dx = -1; dx <= 1; dx++) {
                let q = c + vec3<i32>(dx, dy, dz);
                if (any(q < vec3<i32>(0)) || any(q >= vec3<i32>(P.i_res))) { continue; }
                let qu = vec3<u32>(q);
                let qc = coarse_centre(qu);
                let qi = grid_index(qu.x, qu.y, qu.z, P.i_res);
                let aux = cell_aux[qi];
                let dq = aux.x;
                var lambda = sigma_s * (dp - dq) * 0.5;
                if (P.upsample_mean != 0u) { lambda = sigma_s * (dp + dq) * 0.5; }
                let wl = f_exp(length(p - qc), lambda, radius) * max(1.0 - abs(dp - dq) / P.d_max, 0.0);
                if (wl <= 0.0) { continue; }
                let cv = cell_vals[qi];
                sw += wl;
                s_sun += wl * cv.x;
                s_sky += wl * cv.y;
                if (P.lobe_axis != 0u) {
                    let lo = cell_dirs[2u * qi];
                    let hi = cell_dirs[2u * qi + 1u];
                    s_hi += wl * hi.w;
                    if (lo.w > 0.0) {
                        s_dir += wl * lo.xyz;
                        sw_dir += wl;
                    }
                    if (hi.w > 0.0) {
                        s_dir_hi += wl * hi.xyz;
                        sw_dir_hi += wl;
                    }
                }
                if (aux.y > 0.0) {
                    var wg = 1.0;
                    if (abs(P.g) >= 1.0e-6) { wg = exp(clamp((gp - cv.w) * lng, -60.0, 60.0)); }
                    if (P.upsample_g_extrapolate != 0u) {
                        swg += wl;
                    } else {
                        swg += wg * wl;
                    }
                    s_g += wg * wl * cv.z;
                }
            }
        }
    }
    var out: vec4<f32>;
    var hi_f = 0.0;
    if (sw > 0.0) {
        out = vec4<f32>(s_sun / sw, s_sky / sw, 0.0, gp);
        hi_f = s_hi / sw;
    } else {
        let f = trilinear_fluence(p);
        out = vec4<f32>(f.x, f.y, 0.0, gp);
        hi_f = f.z;
    }
    // A weighted mean of g' stays in [−0.999, 0.999]; the extrapolation g'(q)·g^δ may not.
    if (swg > 0.0) { out.z = clamp(s_g / swg, -0.999, 0.999); }
    j_out[idx] = out;
    if (P.lobe_axis != 0u) {
        var v = vec3<f32>(0.0);
        if (sw_dir > 0.0) { v = s_dir / sw_dir; }
        var vh = vec3<f32>(0.0);
        if (sw_dir_hi > 0.0) { vh = s_dir_hi / sw_dir_hi; }
        j_dir[idx] = vec4<f32>(v, hi_f);
        j_hi[idx] = vec4<f32>(vh, 0.0);
    }
}
