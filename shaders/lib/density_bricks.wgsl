#import grid

// The density as a brick map (crates/gpu/src/density.rs, CPU twin `AtlasPlan::voxel`): 8³
// bricks on the lattice of the sparse grid (`crates/scene/src/brick.rs`, shifted by `offset`
// voxels); `brick_index` holds each brick's slot in `atlas`, a 3D texture of 8³ blocks (slot s
// at block (s mod a.x, (s / a.x) mod a.y, s / (a.x a.y))) holding the f32 bits as u32. Slot 0
// is all zeros (absent bricks); bricks of one constant value share a slot. A texture is not
// bound by the storage-binding size (128 MiB on lavapipe), so the box may be any size whose
// stored bricks fit the texture. The importing stage declares
// `DI: DensityInfo` (uniform), `brick_index: array<u32>` and `atlas: texture_3d<u32>`.

struct DensityInfo {
    offset: vec3<u32>, _a: u32,
    bricks: vec3<u32>, _b: u32,
    atlas: vec3<u32>, _c: u32,
};

fn voxel(x: u32, y: u32, z: u32) -> f32 {
    let g = vec3<u32>(x, y, z) + DI.offset;
    let b = g / 8u;
    let slot = brick_index[(b.z * DI.bricks.y + b.y) * DI.bricks.x + b.x];
    let a = vec3<u32>(slot % DI.atlas.x, (slot / DI.atlas.x) % DI.atlas.y,
                      slot / (DI.atlas.x * DI.atlas.y));
    return bitcast<f32>(textureLoad(atlas, a * 8u + g % 8u, 0).r);
}
