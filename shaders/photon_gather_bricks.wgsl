// Final gathering from the photon map over a brick-map density (`lib/density_bricks.wgsl`):
// grids beyond one storage binding and sparse grids; the body is `lib/photon_gather_core.wgsl`.
#import photon_gather_core
#import density_bricks

@group(0) @binding(1) var<storage, read> brick_index: array<u32>;
@group(0) @binding(7) var<uniform> DI: DensityInfo;
@group(0) @binding(8) var atlas: texture_3d<u32>;
