// One RPNN sample per pixel on the GPU over a dense density buffer (the body:
// `lib/rpnn_sample_core.wgsl`).
#import rpnn_sample_core
#import density_dense

@group(0) @binding(1) var<storage, read> density: array<f32>;
