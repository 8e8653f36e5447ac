#import params

// The light volumes' sparse layout (CPU twin: `nimbus_photon::light_map`): the work density,
// J, its flux directions and T_sun are pools of 8³ bricks over the light grid (`P.light_res`),
// only the bricks near density stored. `light_map` (declared by the importing stage) holds each
// brick's slot, x fastest over ⌈light_res / 8⌉ bricks (0: absent), then each slot's brick.
// Slot 0 is all zeros and never written: a lookup in an absent brick reads 0 with no branch.

fn light_bricks() -> vec3<u32> {
    return (P.light_res + vec3<u32>(7u)) / 8u;
}

// Pool entry of light voxel (x, y, z).
fn light_at(x: u32, y: u32, z: u32) -> u32 {
    let n = light_bricks();
    let b = vec3<u32>(x, y, z) / 8u;
    let l = vec3<u32>(x, y, z) % 8u;
    return light_map[(b.z * n.y + b.y) * n.x + b.x] * 512u + (l.z * 8u + l.y) * 8u + l.x;
}

// The light voxel of pool entry i (slot ≥ 1); its coordinates may lie past the grid's edge
// (the last bricks along an axis are partly outside), which the writer checks.
fn light_voxel(i: u32) -> vec3<u32> {
    let n = light_bricks();
    let b = light_map[n.x * n.y * n.z + i / 512u];
    let l = i % 512u;
    return vec3<u32>(b % n.x, (b / n.x) % n.y, b / (n.x * n.y)) * 8u
        + vec3<u32>(l % 8u, (l / 8u) % 8u, l / 64u);
}
