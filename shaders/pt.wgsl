// GPU volumetric path tracer over a dense density buffer (the body: `lib/pt_core.wgsl`).
#import pt_core
#import density_dense

@group(0) @binding(1) var<storage, read> density: array<f32>;
