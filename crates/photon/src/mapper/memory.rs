//! The photon map's memory: all of its buffers in bytes, checked against the memory budget
//! where GPU buffers live in host memory.

use super::*;

/// All of the photon map's buffers, in bytes: the light volumes' pools of `voxels` entries
/// each (`crate::light_map`: the work density, J and its flux directions, the
/// sun-transmittance volume), the ring of partial caches with H_new and I, the per-cell
/// read-outs, the image, and `march_bytes` of the ray marcher's own density (0 when it reads
/// the work density) and the light bricks' index.
pub fn buffer_bytes(
    settings: &PmSettings,
    params: &VolumeParams,
    voxels: u32,
    cells: u32,
    camera: &Camera,
    march_bytes: u64,
) -> u64 {
    let v = voxels as u64;
    let per_voxel = 4
        + 16
        + if settings.variant == PmVariant::Exact {
            4
        } else {
            0
        }
        + if params.lobe_axis != 0 { 16 } else { 0 }
        + if params.lobe_split != 0 { 16 } else { 0 };
    v * per_voxel
        + cells as u64 * (CELL_BYTES as u64 * (settings.ring as u64 + 2) + 64)
        + camera.width as u64 * camera.height as u64 * 16
        + march_bytes
}

/// On a software adapter (lavapipe) GPU buffers live in host memory: their total is checked
/// against the memory budget like any other allocation sized by input, so a huge cache or ring
/// is an error naming the settings instead of an allocation failure that aborts.
pub(super) fn check_host_memory(
    gpu: &Gpu,
    settings: &PmSettings,
    params: &VolumeParams,
    voxels: u32,
    cells: u32,
    camera: &Camera,
    march_bytes: u64,
) -> Result<(), PmError> {
    if !gpu.is_software() {
        return Ok(());
    }
    let bytes = buffer_bytes(settings, params, voxels, cells, camera, march_bytes);
    nimbus_scene::memory::check(
        bytes as u128,
        "ring",
        &format!(
            "the photon map's buffers on {} (host memory): density and cache at {voxels} voxels, a ring of {} × {cells} cells",
            gpu.info.name, settings.ring
        ),
    )
    .map_err(PmError::Memory)
}
