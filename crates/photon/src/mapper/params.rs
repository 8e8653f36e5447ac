//! The photon map's uniform block ([`VolumeParams`]), filled in this one place from the scene,
//! the settings and the light volumes' layout; the ray marcher's copy differs only in the
//! density resolution it reads ([`PhotonMapper::march_params`]).

use super::*;

/// The resolutions and light-volume layout the photon map was built with.
pub(super) struct Layout {
    /// The light resolution the photon stages work at (`mapper/light.rs`).
    pub d_res: [u32; 3],
    /// The cache's resolution.
    pub i_res: [u32; 3],
    pub light_res: [u32; 3],
    /// The density grid's own resolution.
    pub fine_res: [u32; 3],
    /// The work density's largest value.
    pub d_max: f64,
    /// Beams accumulate in workgroup memory.
    pub use_shared: bool,
    /// The light volumes are dense (no bricks).
    pub light_full: bool,
    pub light_voxels: u32,
}

/// The uniform block for `scene` with medium anisotropy `g`.
pub(super) fn volume_params(
    scene: &Scene,
    settings: &PmSettings,
    g: f64,
    l: &Layout,
) -> VolumeParams {
    let vol = &scene.volume;
    let aabb = vol.aabb();
    let sigma_max = (vol.density_scale() * l.d_max).max(1e-30);
    let centre = aabb.center();
    let radius = 0.5 * aabb.extent().length();
    let (forward, right, up, tan_half) = scene.camera.basis();
    let sun = scene.sun.as_ref();
    VolumeParams {
        aabb_min: f3(aabb.min),
        density_scale: vol.density_scale() as f32,
        aabb_max: f3(aabb.max),
        albedo: scene.medium.albedo as f32,
        d_res: l.d_res,
        g: g as f32,
        i_res: l.i_res,
        sigma_max: sigma_max as f32,
        sun_dir: f3(sun.map_or(DVec3::Y, |s| s.dir)),
        sun_cos_max: sun.map_or(1.0, |s| s.angular_radius.cos() as f32),
        sun_irradiance: f3(sun.map_or(DVec3::ZERO, |s| s.irradiance)),
        bound_radius: radius as f32,
        sky_radiance: match &scene.sky {
            Some(Sky::Constant(c)) => f3(*c),
            _ => [0.0; 3],
        },
        d_max: l.d_max.max(1e-30) as f32,
        bound_center: f3(centre),
        sun_disc_radiance: sun.filter(|s| !s.is_delta()).map_or(0.0, |s| {
            (1.0 / (PI * s.angular_radius.sin().powi(2))) as f32
        }),
        cam_origin: f3(scene.camera.origin),
        tan_half: tan_half as f32,
        cam_forward: f3(forward),
        aspect: (scene.camera.width as f64 / scene.camera.height as f64) as f32,
        cam_right: f3(right),
        step: (aabb.extent().length() * settings.step_fraction) as f32,
        cam_up: f3(up),
        early_exit: settings.early_exit,
        n_sun: 0,
        n_sky: 0,
        seed: settings.seed,
        frame: 0,
        similarity_order: similarity_order(g, settings.similarity_t),
        max_order: settings.max_order,
        use_shared: l.use_shared as u32,
        filtered: (l.i_res != l.d_res) as u32,
        width: scene.camera.width as u32,
        height: scene.camera.height as u32,
        beam_threshold: settings.beam_threshold,
        reduced_factor: if settings
            .similarity_linear
            .unwrap_or(settings.variant == PmVariant::Exact)
        {
            (1.0 - g).max(0.0) as f32
        } else {
            (1.0 - g).max(0.0).sqrt() as f32
        },
        sun_norm: 0.0,
        sky_norm: 0.0,
        noise_amplitude: {
            let voxel = vol.cell_size().min_element();
            (settings.detail_noise as f64 * voxel) as f32
        },
        noise_frequency: (1.0 / (4.0 * vol.cell_size().min_element())) as f32,
        single_scatter: (settings.variant == PmVariant::Exact) as u32,
        density_weighted: settings.density_weighted.unwrap_or(false) as u32,
        lobe_axis: (settings.effective_lobe_axis() == LobeAxis::Flux) as u32,
        lobe_split: if settings.effective_lobe_axis() == LobeAxis::Flux {
            settings.effective_lobe_split()
        } else {
            0
        },
        upsample_mean: settings.upsample_mean as u32,
        upsample_g_extrapolate: settings.upsample_g_extrapolate as u32,
        sun_first: 0,
        sun_count: 0,
        view_origin: f3(scene.camera.origin),
        view_mode: settings.effective_view() as u32,
        light_res: l.light_res,
        near_radius: light::near_radius(l.fine_res, l.light_res),
        skip_empty: settings
            .skip_empty
            .unwrap_or(l.light_res != l.fine_res || !l.light_full) as u32,
        light_voxels: l.light_voxels,
        view_g: settings.view_g.map_or(0.0, |v| v as f32),
        _pad_skip2: 0,
    }
}

/// The ray marcher's uniform block: `params` with the grid's own resolution `fine_res`.
pub(super) fn march(params: &VolumeParams, fine_res: [u32; 3]) -> VolumeParams {
    VolumeParams {
        d_res: fine_res,
        ..*params
    }
}
