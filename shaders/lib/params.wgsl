// The uniform block of the volume shaders (photon mapping and the GPU path tracer). Mirrors
// `VolumeParams` in crates/gpu/src/params.rs (#[repr(C)]; a test checks every offset against
// the layout naga computes for this struct). Each stage declares the binding itself:
//   @group(0) @binding(0) var<uniform> P: Params;

struct Params {
    aabb_min: vec3<f32>, density_scale: f32,
    aabb_max: vec3<f32>, albedo: f32,
    d_res: vec3<u32>, g: f32,
    i_res: vec3<u32>, sigma_max: f32,
    sun_dir: vec3<f32>, sun_cos_max: f32,
    sun_irradiance: vec3<f32>, bound_radius: f32,
    sky_radiance: vec3<f32>, d_max: f32,
    bound_center: vec3<f32>, sun_disc_radiance: f32,
    cam_origin: vec3<f32>, tan_half: f32,
    cam_forward: vec3<f32>, aspect: f32,
    cam_right: vec3<f32>, step: f32,
    cam_up: vec3<f32>, early_exit: f32,
    n_sun: u32, n_sky: u32, seed: u32, frame: u32,
    similarity_order: u32, max_order: u32, use_shared: u32, filtered: u32,
    width: u32, height: u32, beam_threshold: f32, reduced_factor: f32,
    sun_norm: f32, sky_norm: f32, noise_amplitude: f32, noise_frequency: f32,
    single_scatter: u32, density_weighted: u32, lobe_axis: u32, lobe_split: u32,
    upsample_mean: u32, upsample_g_extrapolate: u32, sun_first: u32, sun_count: u32,
    view_origin: vec3<f32>, view_mode: u32,
    light_res: vec3<u32>, near_radius: u32,
    skip_empty: u32, light_voxels: u32, view_g: f32, _pad_skip2: u32,
};
