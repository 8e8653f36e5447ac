#import params

// Grid lookups over the volume's box. They read the importing stage's uniform P: Params and
// the density through `voxel(x, y, z)`, which the stage brings in with one of the density
// modules: `density_dense` (one storage buffer, binding `density`) or `density_bricks` (a
// brick map over a 3D-texture atlas, for grids beyond one storage binding).

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

// Unscaled density at p (trilinear, 0 outside the box).
fn density_at(p: vec3<f32>) -> f32 {
    if (!inside_box(p)) { return 0.0; }
    let t = trilinear(p, P.d_res);
    let c000 = voxel(t.i0.x, t.i0.y, t.i0.z);
    let c100 = voxel(t.i1.x, t.i0.y, t.i0.z);
    let c010 = voxel(t.i0.x, t.i1.y, t.i0.z);
    let c110 = voxel(t.i1.x, t.i1.y, t.i0.z);
    let c001 = voxel(t.i0.x, t.i0.y, t.i1.z);
    let c101 = voxel(t.i1.x, t.i0.y, t.i1.z);
    let c011 = voxel(t.i0.x, t.i1.y, t.i1.z);
    let c111 = voxel(t.i1.x, t.i1.y, t.i1.z);
    let f = t.f;
    let c00 = mix(c000, c100, f.x);
    let c10 = mix(c010, c110, f.x);
    let c01 = mix(c001, c101, f.x);
    let c11 = mix(c011, c111, f.x);
    return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
}

// Whether a voxel within `P.near_radius` (at least 1) of voxel v (the block clamped to the
// grid) holds density: the trilinear lookups of a light volume where σ(x) > 0 touch only such
// voxels. With the grid's own resolution, or one coarser by a factor ≥ 2 per axis, radius 1
// suffices: the fine voxel that makes σ(x) > 0 lies within one fine voxel of x, so within half
// a light voxel, and its light voxel is a trilinear neighbour of x or next to one; a factor
// between 1 and 2 needs radius 2 (`nimbus_photon::mapper::light::near_radius`).
fn near_density(v: vec3<u32>) -> bool {
    let r = vec3<i32>(i32(max(P.near_radius, 1u)));
    let lo = max(vec3<i32>(v) - r, vec3<i32>(0));
    let hi = min(vec3<i32>(v) + r, vec3<i32>(P.d_res) - vec3<i32>(1));
    for (var z = lo.z; z <= hi.z; z++) {
        for (var y = lo.y; y <= hi.y; y++) {
            for (var x = lo.x; x <= hi.x; x++) {
                if (voxel(u32(x), u32(y), u32(z)) > 0.0) { return true; }
            }
        }
    }
    return false;
}
