// Final gathering from the photon map over a dense density (one storage buffer); the body is
// `lib/photon_gather_core.wgsl`.
#import photon_gather_core
#import density_dense

@group(0) @binding(1) var<storage, read> density: array<f32>;
