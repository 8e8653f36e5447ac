//! Twin of `sun_transmittance` in `shaders/photon_sun.wgsl`.

use super::*;

/// Sun transmittance at density voxel `idx` (the pass of `photon_sun.wgsl`): midpoint rule
/// with half the smallest voxel as step from the voxel centre to the box boundary; 0 where no
/// density is near ([`near_density`]: never read there).
pub fn sun_transmittance(p: &VolumeParams, density: &[f32], idx: usize) -> f32 {
    if !near_density(p, density, idx) {
        return 0.0;
    }
    let r = p.d_res;
    let ext = v3(p.aabb_max) - v3(p.aabb_min);
    let resf = Vec3::new(r[0] as f32, r[1] as f32, r[2] as f32);
    let x = voxel_centre(p, idx);
    let sun = v3(p.sun_dir);
    let (_, t1) = box_intersect(p, x, sun);
    let cell = ext / resf;
    let h = 0.5 * cell.x.min(cell.y.min(cell.z));
    let len = t1.max(0.0);
    let n = (len / h).ceil().max(1.0);
    let dt = len / n;
    let tau: f32 = (0..n as u32)
        .map(|i| density_at(p, density, x + sun * ((i as f32 + 0.5) * dt)))
        .sum();
    (-p.density_scale * tau * dt).exp()
}
