// Photon-mapping ray marcher where the light volumes have the grid's resolution: the density
// is the work density in the light bricks' pool (`lib/density_light.wgsl`); the body is
// `lib/photon_raymarch_core.wgsl` (Elek 2012 §4.4).
#import photon_raymarch_core
#import density_light

@group(0) @binding(1) var<storage, read> density: array<f32>;
