// One RPNN sample per pixel on the GPU over a brick-map density (the body:
// `lib/rpnn_sample_core.wgsl`; the brick map: `lib/density_bricks.wgsl`).
#import rpnn_sample_core
#import density_bricks

@group(0) @binding(1) var<storage, read> brick_index: array<u32>;
@group(0) @binding(5) var<uniform> DI: DensityInfo;
@group(0) @binding(6) var atlas: texture_3d<u32>;
