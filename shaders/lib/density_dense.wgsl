#import grid

// The density as one dense storage buffer, x fastest (the importing stage declares
// `density: array<f32>`).
fn voxel(x: u32, y: u32, z: u32) -> f32 {
    return density[grid_index(x, y, z, P.d_res)];
}
