// Photon-mapping ray marcher over a brick-map density (`lib/density_bricks.wgsl`): for grids
// beyond one storage binding and sparse grids, whose light volumes are then coarser
// (`lib/photon_raymarch_core.wgsl`, Elek 2012 §4.4).
#import photon_raymarch_core
#import density_bricks

@group(0) @binding(1) var<storage, read> brick_index: array<u32>;
@group(0) @binding(7) var<uniform> DI: DensityInfo;
@group(0) @binding(8) var atlas: texture_3d<u32>;
