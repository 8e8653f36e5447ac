// GPU volumetric path tracer over a brick-map density (the body: `lib/pt_core.wgsl`): for
// sparse grids and boxes beyond one storage binding (crates/gpu/src/density.rs).
#import pt_core
#import density_bricks

@group(0) @binding(1) var<storage, read> brick_index: array<u32>;
@group(0) @binding(5) var<uniform> DI: DensityInfo;
@group(0) @binding(6) var atlas: texture_3d<u32>;
