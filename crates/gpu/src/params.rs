//! The uniform block of the volume shaders (photon mapping, GPU path tracing): `struct Params`
//! in `shaders/lib/params.wgsl`. `#[repr(C)]` + bytemuck; a test checks every field offset against the
//! layout naga computes for the WGSL struct.

use bytemuck::{Pod, Zeroable};

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default, PartialEq)]
pub struct VolumeParams {
    pub aabb_min: [f32; 3],
    pub density_scale: f32,
    pub aabb_max: [f32; 3],
    pub albedo: f32,
    pub d_res: [u32; 3],
    pub g: f32,
    pub i_res: [u32; 3],
    /// Global majorant σ̄ = density_scale × max D.
    pub sigma_max: f32,
    /// Unit vector towards the sun.
    pub sun_dir: [f32; 3],
    pub sun_cos_max: f32,
    pub sun_irradiance: [f32; 3],
    pub bound_radius: f32,
    pub sky_radiance: [f32; 3],
    /// Largest grid value (normalises the range filter of the upsampling).
    pub d_max: f32,
    pub bound_center: [f32; 3],
    /// Disc radiance per unit irradiance, 1/(π sin² r); 0 for a delta sun.
    pub sun_disc_radiance: f32,
    pub cam_origin: [f32; 3],
    pub tan_half: f32,
    pub cam_forward: [f32; 3],
    pub aspect: f32,
    pub cam_right: [f32; 3],
    pub step: f32,
    pub cam_up: [f32; 3],
    pub early_exit: f32,
    pub n_sun: u32,
    pub n_sky: u32,
    pub seed: u32,
    pub frame: u32,
    pub similarity_order: u32,
    pub max_order: u32,
    pub use_shared: u32,
    pub filtered: u32,
    pub width: u32,
    pub height: u32,
    pub beam_threshold: f32,
    /// √(1 − g): σ' = σ √(1 − g) after the similarity switch.
    pub reduced_factor: f32,
    /// Cache sums → sun fluence per unit irradiance.
    pub sun_norm: f32,
    /// Cache sums → sky fluence per unit radiance.
    pub sky_norm: f32,
    /// Detail noise: displacement amplitude of lookups (world units; 0 = off).
    pub noise_amplitude: f32,
    /// Detail noise: base frequency (1 / world units).
    pub noise_frequency: f32,
    /// Photon mapping: 1 = exact single scattering (sun-transmittance volume in the ray
    /// marcher, no order-0 sun deposits in the cache); 0 = the paper's single cache.
    pub single_scatter: u32,
    /// Photon mapping: 1 = density-weighted deposits (weight σ(x)/σ̄; a cell stores
    /// ⟨σφ⟩/⟨σ⟩, the fluence where the medium is, not averaged with the air of the cell).
    pub density_weighted: u32,
    /// Photon mapping: axis of each cell's incident HG lobe: 0 = the sun's propagation
    /// direction (Elek §4.1.2), 1 = the cell's mean sun-flux direction (Appendix C).
    pub lobe_axis: u32,
    /// Photon mapping (flux axes): sun light of scattering order ≥ this gets an HG lobe of its
    /// own (0 = one lobe per cell for all orders).
    pub lobe_split: u32,
    /// Photon mapping: the upsampling's attenuation λ between a voxel p and a cell q:
    /// 0 = σ_s (D(p) − D(q)) / 2 (Elek §4.3 as printed), 1 = σ_s (D(p) + D(q)) / 2 (the mean
    /// extinction between them).
    pub upsample_mean: u32,
    /// Photon mapping, sun-axis lobes: 0 = g' upsampled as Σ g'(q) g^δ w_L / Σ g^δ w_L (g^δ a
    /// weight, Elek §4.3's formula), 1 = extrapolated, Σ g'(q) g^δ w_L / Σ w_L (the prose:
    /// anisotropy decays as g per scattering order).
    pub upsample_g_extrapolate: u32,
    /// Sun-transmittance pass: the voxels it marches, `sun_first .. sun_first + sun_count`
    /// (all of them, or one slice of an amortised rebuild).
    pub sun_first: u32,
    pub sun_count: u32,
    /// Photon mapping: the point the view-dependent cache words are deposited for (the camera
    /// the ring is traced for).
    pub view_origin: [f32; 3],
    /// Photon mapping: 0 = no view-dependent words; 1 = the trace deposits the sun and sky
    /// in-scattering towards `view_origin` (words 11 and 12), the ray marcher uses the lobes;
    /// 2 = as 1, and `cells`/the ray marcher use those words (every ring slot was traced for
    /// `view_origin`).
    pub view_mode: u32,
    /// Photon mapping: resolution of the light volumes (J, its flux directions, T_sun) that
    /// the ray marcher reads. The photon stages run on a density at this resolution; the ray
    /// marcher reads the density at `d_res` (equal unless the grid is too large for the light
    /// volumes at full resolution: `nimbus_photon::settings::light_res`).
    pub light_res: [u32; 3],
    /// Photon mapping: the sun pass and the upsampling skip light voxels with no density within
    /// this many voxels (0 counts as 1): 1, or 2 where an axis of the light volumes is coarser
    /// than the density's by a factor below 2 (`nimbus_photon::mapper::light`).
    pub near_radius: u32,
    /// Photon mapping: 1 = beams cross the cache cells no later stage reads in one step
    /// (`cell_skip` in photon_trace.wgsl), 0 = Woodcock tracking everywhere.
    pub skip_empty: u32,
    /// Photon mapping: voxels of the light volumes' stored bricks, slot 0 excluded (the
    /// upsampling's dispatch: `shaders/lib/light_bricks.wgsl`).
    pub light_voxels: u32,
    /// Photon mapping: anisotropy of the phase function of the view-dependent words (0: the
    /// medium's g). The final gathering's words are traced with g^(k+1), the phase function of
    /// a terminal vertex k bounces from the camera averaged over its direction (HG's Legendre
    /// coefficients g^l multiply under convolution).
    pub view_g: f32,
    pub _pad_skip2: u32,
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::offset_of;

    #[test]
    fn layout_matches_wgsl() {
        let (members, span) = crate::shaders::struct_layout("params", "Params");
        assert_eq!(span as usize, std::mem::size_of::<VolumeParams>());
        let rust: Vec<(&str, usize)> = vec![
            ("aabb_min", offset_of!(VolumeParams, aabb_min)),
            ("density_scale", offset_of!(VolumeParams, density_scale)),
            ("aabb_max", offset_of!(VolumeParams, aabb_max)),
            ("albedo", offset_of!(VolumeParams, albedo)),
            ("d_res", offset_of!(VolumeParams, d_res)),
            ("g", offset_of!(VolumeParams, g)),
            ("i_res", offset_of!(VolumeParams, i_res)),
            ("sigma_max", offset_of!(VolumeParams, sigma_max)),
            ("sun_dir", offset_of!(VolumeParams, sun_dir)),
            ("sun_cos_max", offset_of!(VolumeParams, sun_cos_max)),
            ("sun_irradiance", offset_of!(VolumeParams, sun_irradiance)),
            ("bound_radius", offset_of!(VolumeParams, bound_radius)),
            ("sky_radiance", offset_of!(VolumeParams, sky_radiance)),
            ("d_max", offset_of!(VolumeParams, d_max)),
            ("bound_center", offset_of!(VolumeParams, bound_center)),
            (
                "sun_disc_radiance",
                offset_of!(VolumeParams, sun_disc_radiance),
            ),
            ("cam_origin", offset_of!(VolumeParams, cam_origin)),
            ("tan_half", offset_of!(VolumeParams, tan_half)),
            ("cam_forward", offset_of!(VolumeParams, cam_forward)),
            ("aspect", offset_of!(VolumeParams, aspect)),
            ("cam_right", offset_of!(VolumeParams, cam_right)),
            ("step", offset_of!(VolumeParams, step)),
            ("cam_up", offset_of!(VolumeParams, cam_up)),
            ("early_exit", offset_of!(VolumeParams, early_exit)),
            ("n_sun", offset_of!(VolumeParams, n_sun)),
            ("n_sky", offset_of!(VolumeParams, n_sky)),
            ("seed", offset_of!(VolumeParams, seed)),
            ("frame", offset_of!(VolumeParams, frame)),
            (
                "similarity_order",
                offset_of!(VolumeParams, similarity_order),
            ),
            ("max_order", offset_of!(VolumeParams, max_order)),
            ("use_shared", offset_of!(VolumeParams, use_shared)),
            ("filtered", offset_of!(VolumeParams, filtered)),
            ("width", offset_of!(VolumeParams, width)),
            ("height", offset_of!(VolumeParams, height)),
            ("beam_threshold", offset_of!(VolumeParams, beam_threshold)),
            ("reduced_factor", offset_of!(VolumeParams, reduced_factor)),
            ("sun_norm", offset_of!(VolumeParams, sun_norm)),
            ("sky_norm", offset_of!(VolumeParams, sky_norm)),
            ("noise_amplitude", offset_of!(VolumeParams, noise_amplitude)),
            ("noise_frequency", offset_of!(VolumeParams, noise_frequency)),
            ("single_scatter", offset_of!(VolumeParams, single_scatter)),
            (
                "density_weighted",
                offset_of!(VolumeParams, density_weighted),
            ),
            ("lobe_axis", offset_of!(VolumeParams, lobe_axis)),
            ("lobe_split", offset_of!(VolumeParams, lobe_split)),
            ("upsample_mean", offset_of!(VolumeParams, upsample_mean)),
            (
                "upsample_g_extrapolate",
                offset_of!(VolumeParams, upsample_g_extrapolate),
            ),
            ("sun_first", offset_of!(VolumeParams, sun_first)),
            ("sun_count", offset_of!(VolumeParams, sun_count)),
            ("view_origin", offset_of!(VolumeParams, view_origin)),
            ("view_mode", offset_of!(VolumeParams, view_mode)),
            ("light_res", offset_of!(VolumeParams, light_res)),
            ("near_radius", offset_of!(VolumeParams, near_radius)),
            ("skip_empty", offset_of!(VolumeParams, skip_empty)),
            ("light_voxels", offset_of!(VolumeParams, light_voxels)),
            ("view_g", offset_of!(VolumeParams, view_g)),
            ("_pad_skip2", offset_of!(VolumeParams, _pad_skip2)),
        ];
        assert_eq!(members.len(), rust.len());
        for ((m, moff), (name, off)) in members.iter().zip(rust) {
            assert_eq!(m, name);
            assert_eq!(*moff as usize, off, "field {name}");
        }
    }
}
