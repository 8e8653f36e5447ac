#import params
#import grid

// The light volumes' layout (CPU twin: `nimbus_photon::light_map`): the work density, J, its
// flux directions and T_sun are pools whose first 512 entries are zeros, never written. With
// `LIGHT_SPARSE` false the grid follows densely (x fastest); with true only the 8³ bricks near
// density are stored: `light_map` (declared by the importing stage) holds each brick's slot,
// x fastest over ⌈light_res / 8⌉ bricks (0: absent, i.e. the zeros), then each slot's brick.

fn light_bricks() -> vec3<u32> {
    return (P.light_res + vec3<u32>(7u)) / 8u;
}

// Pool entry of light voxel (x, y, z).
// Pipeline constant: the layout (`nimbus_photon::mapper` sets it per mapper), so each variant
// is compiled without the other's branch.
override LIGHT_SPARSE: bool = false;

// With every voxel stored the pool is the dense grid after the 512 zeros.
fn light_at(x: u32, y: u32, z: u32) -> u32 {
    if (!LIGHT_SPARSE) { return 512u + grid_index(x, y, z, P.light_res); }
    let n = light_bricks();
    let b = vec3<u32>(x, y, z) / 8u;
    let l = vec3<u32>(x, y, z) % 8u;
    return light_map[(b.z * n.y + b.y) * n.x + b.x] * 512u + (l.z * 8u + l.y) * 8u + l.x;
}

// The light voxel of pool entry i (slot ≥ 1); its coordinates may lie past the grid's edge
// (the last bricks along an axis are partly outside), which the writer checks.
fn light_voxel(i: u32) -> vec3<u32> {
    if (!LIGHT_SPARSE) {
        let j = i - 512u;
        let r = P.light_res;
        return vec3<u32>(j % r.x, (j / r.x) % r.y, j / (r.x * r.y));
    }
    let n = light_bricks();
    let b = light_map[n.x * n.y * n.z + i / 512u];
    let l = i % 512u;
    return vec3<u32>(b % n.x, (b / n.x) % n.y, b / (n.x * n.y)) * 8u
        + vec3<u32>(l % 8u, (l / 8u) % 8u, l / 64u);
}
