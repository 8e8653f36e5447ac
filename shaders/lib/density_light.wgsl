#import light_bricks

// The work density in the light volumes' brick pool (`lib/light_bricks.wgsl`): the photon
// stages' grid (the importing stage declares `density: array<f32>` and `light_map`).
fn voxel(x: u32, y: u32, z: u32) -> f32 {
    return density[light_at(x, y, z)];
}
