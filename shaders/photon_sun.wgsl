// Sun transmittance at every density voxel centre (exact single scattering, beyond Elek 2012):
// T_sun(x) = exp(−∫ σ_t(x + s ω_sun) ds) from x to the box boundary, by the midpoint rule with
// a step of half the smallest voxel. The ray marcher adds σ_s(x) E_sun T_sun(x) p(ω·ω_sun | g)
// at every step, so first-order sun light — the silver lining — comes from the density itself,
// not from the coarse photon cache, which then holds only light scattered at least once (an
// exact split by scattering order). Rebuilt only when the sun or the density changes, at
// once or amortised over frames in slices.
// Only the stored bricks of the light grid are marched (`lib/light_bricks.wgsl`), and of
// them only voxels with density nearby (`near_density`, lib/grid.wgsl) are marched (the rest get
// 0): the ray marcher reads T_sun trilinearly where σ(x) > 0, and such a lookup touches only
// voxels near a non-zero one — at the light resolution of a coarser grid too
// (`mapper/light.rs`) — so the empty space of a sparse box costs 27 reads per voxel instead of
// a march.
// CPU twin: `nimbus_photon::cpu::sun_transmittance`.
#import params
#import grid
#import density_light
#import constants

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> density: array<f32>;
@group(0) @binding(2) var<storage, read_write> t_sun: array<f32>;
@group(0) @binding(3) var<storage, read> light_map: array<u32>;

@compute @workgroup_size(WG)
fn sun_transmittance(@builtin(global_invocation_id) gid: vec3<u32>,
                     @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = P.d_res;
    // Pool entries 512 + sun_first .. 512 + sun_first + sun_count: the stored bricks' voxels
    // (all of them, or one slice of an amortised rebuild: `mapper/sun.rs`).
    let local = gid.x + gid.y * nwg.x * WG;
    let idx = 512u + P.sun_first + local;
    if (local >= P.sun_count) { return; }
    let v = light_voxel(idx);
    if (any(v >= r) || !near_density(v)) {
        t_sun[idx] = 0.0;
        return;
    }
    let ext = P.aabb_max - P.aabb_min;
    let x = P.aabb_min + (vec3<f32>(v) + vec3<f32>(0.5)) / vec3<f32>(r) * ext;
    let hit = box_intersect(x, P.sun_dir);
    let cell = ext / vec3<f32>(r);
    let h = 0.5 * min(cell.x, min(cell.y, cell.z));
    let len = max(hit.y, 0.0);
    let n = max(ceil(len / h), 1.0);
    let dt = len / n;
    // Steps in an absent light brick are skipped to the first step past its exit. The sum is
    // the same, bit for bit: an absent brick holds no voxel within one of density, so every
    // trilinear lookup from inside it (or from the sliver past its faces) reads zeros.
    let scale = vec3<f32>(r) / ext;
    let u0 = (x - P.aabb_min) * scale;
    let du = P.sun_dir * scale;
    let nb = light_bricks();
    var tau = 0.0;
    var i = 0u;
    loop {
        if (i >= u32(n)) { break; }
        let t = (f32(i) + 0.5) * dt;
        if (LIGHT_SPARSE) {
            let u = u0 + du * t;
            let v = vec3<u32>(clamp(floor(u), vec3<f32>(0.0), vec3<f32>(r) - vec3<f32>(1.0)));
            let b = v / 8u;
            if (light_map[(b.z * nb.y + b.y) * nb.x + b.x] == 0u) {
                let lo = vec3<f32>(b * 8u);
                var t_exit = 3.0e38;
                for (var a = 0; a < 3; a++) {
                    if (du[a] > 0.0) {
                        t_exit = min(t_exit, (lo[a] + 8.0 - u0[a]) / du[a]);
                    } else if (du[a] < 0.0) {
                        t_exit = min(t_exit, (lo[a] - u0[a]) / du[a]);
                    }
                }
                i = max(i + 1u, u32(max(ceil(t_exit / dt - 0.5), 0.0)));
                continue;
            }
        }
        tau += density_at(x + P.sun_dir * t);
        i++;
    }
    t_sun[idx] = exp(-P.density_scale * tau * dt);
}
