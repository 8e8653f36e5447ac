// Final gathering from the photon map where the light volumes have the grid's resolution: the
// density is the work density in the light bricks' pool (`lib/density_light.wgsl`); the body is
// `lib/photon_gather_core.wgsl`.
#import photon_gather_core
#import density_light

@group(0) @binding(1) var<storage, read> density: array<f32>;
