// Free flights and transmittance along a ray through the density `density_at` (the importing
// stage's uniform P: Params and density module), against a global majorant `sigma_max`:
// delta tracking samples the distance to the next real collision, ratio tracking estimates the
// transmittance (Novák et al. 2014 / the CPU's `nimbus_trace::tracking`, which walks a majorant
// grid instead: the same expectations). Used by the GPU path tracer (`pt_core`) and the photon
// map's final gathering (`photon_gather_core`).
#import grid
#import rng

// Half the smallest voxel edge: the step through empty space where free-flight steps fall
// below the resolution of t.
fn half_voxel() -> f32 {
    let v = (P.aabb_max - P.aabb_min) / vec3<f32>(P.d_res);
    return 0.5 * min(v.x, min(v.y, v.z));
}

// Distance along o + t d (t in [t0, t1]) to the first real collision, or −1 when the ray
// leaves [t0, t1] first.
fn delta_track(o: vec3<f32>, d: vec3<f32>, t0: f32, t1: f32, sigma_max: f32, rng: ptr<function, Rng>) -> f32 {
    var t = t0;
    loop {
        var next = t - log(1.0 - rand(rng)) / sigma_max;
        if (next <= t) {
            // A step below the representable increment of t (σ̄ beyond ≈ 1e7 per unit at
            // t ≈ 1), where a null collision would repeat forever: where there is density the
            // medium is opaque at this resolution and the collision happens here; where there
            // is none the walk moves on by half a voxel (the CPU's majorant grid skips such
            // cells, `tracking.rs`).
            if (density_at(o + d * t) > 0.0) { return t; }
            next = t + half_voxel();
        }
        t = next;
        if (t >= t1) { return -1.0; }
        if (rand(rng) * sigma_max < P.density_scale * density_at(o + d * t)) { return t; }
    }
    return -1.0;
}

// Transmittance from o along d to the box's far side, by ratio tracking with Russian roulette
// below 0.1.
fn ratio_track(o: vec3<f32>, d: vec3<f32>, sigma_max: f32, rng: ptr<function, Rng>) -> f32 {
    let hit = box_intersect(o, d);
    if (hit.x > hit.y) { return 1.0; }
    var tr = 1.0;
    var t = hit.x;
    loop {
        var next = t - log(1.0 - rand(rng)) / sigma_max;
        if (next <= t) {
            // Below one ulp of t: opaque where there is density, else half a voxel on (see
            // `delta_track`).
            if (density_at(o + d * t) > 0.0) { return 0.0; }
            next = t + half_voxel();
        }
        t = next;
        if (t >= hit.y) { break; }
        tr *= max(1.0 - P.density_scale * density_at(o + d * t) / sigma_max, 0.0);
        if (tr < 0.1) {
            if (tr <= 0.0 || rand(rng) < 0.5) { return 0.0; }
            tr *= 2.0;
        }
    }
    return tr;
}
