// Sun transmittance at every density voxel centre (exact single scattering, beyond Elek 2012):
// T_sun(x) = exp(−∫ σ_t(x + s ω_sun) ds) from x to the box boundary, by the midpoint rule with
// a step of half the smallest voxel. The ray marcher adds σ_s(x) E_sun T_sun(x) p(ω·ω_sun | g)
// at every step, so first-order sun light — the silver lining — comes from the density itself,
// not from the coarse photon cache, which then holds only light scattered at least once (an
// exact split by scattering order). Rebuilt only when the sun or the density changes, at
// once or amortised over frames in slices.
// Only voxels with density nearby (`near_density`, lib/grid.wgsl) are marched (the rest get
// 0): the ray marcher reads T_sun trilinearly where σ(x) > 0, and such a lookup touches only
// voxels near a non-zero one — at the light resolution of a coarser grid too
// (`mapper/light.rs`) — so the empty space of a sparse box costs 27 reads per voxel instead of
// a march.
// CPU twin: `nimbus_photon::cpu::sun_transmittance`.
#import params
#import grid
#import density_dense
#import constants

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> density: array<f32>;
@group(0) @binding(2) var<storage, read_write> t_sun: array<f32>;

@compute @workgroup_size(WG)
fn sun_transmittance(@builtin(global_invocation_id) gid: vec3<u32>,
                     @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = P.d_res;
    // Voxels sun_first .. sun_first + sun_count (all of them, or one slice of an amortised
    // rebuild: `mapper/sun.rs`).
    let local = gid.x + gid.y * nwg.x * WG;
    let idx = P.sun_first + local;
    if (local >= P.sun_count || idx >= r.x * r.y * r.z) { return; }
    let v = vec3<u32>(idx % r.x, (idx / r.x) % r.y, idx / (r.x * r.y));
    if (!near_density(v)) {
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
    var tau = 0.0;
    for (var i = 0u; i < u32(n); i++) {
        tau += density_at(x + P.sun_dir * ((f32(i) + 0.5) * dt));
    }
    t_sun[idx] = exp(-P.density_scale * tau * dt);
}
