// Photon-mapping ray marcher over a dense density (one storage buffer); the body is
// `lib/photon_raymarch_core.wgsl` (Elek 2012 §4.4).
#import photon_raymarch_core
#import density_dense

@group(0) @binding(1) var<storage, read> density: array<f32>;
