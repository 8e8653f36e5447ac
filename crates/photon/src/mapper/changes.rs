//! Changes between frames that keep the mapper: the majorant of a density sequence, the
//! lighting, the sun's direction (a new density: `mapper/light.rs`).

use super::*;

impl PhotonMapper<'_> {
    /// Sets the grid value the majorant is computed from (σ̄ = density_scale × value); used by
    /// density sequences, which need one majorant for all frames.
    /// Changing it invalidates the cached generations, so the ring is emptied if it held any.
    /// With coarse light volumes the value is the grid's, at least the block means' largest:
    /// still a majorant of the work density, and the upsampling's range filter is normalised
    /// by it.
    pub fn set_majorant_value(&mut self, max_value: f32) {
        if self.frame > 0 {
            self.reset();
        }
        self.params.d_max = max_value.max(1e-30);
        self.params.sigma_max = (self.params.density_scale * max_value).max(1e-30);
        // The final gathering tracks the grid itself: its majorant covers every frame too.
        self.grid_max = self.grid_max.max(max_value as f64);
    }

    /// Changes the sun irradiance and the constant sky radiance (e.g. an atmosphere recolouring
    /// a moving sun). J stores flux per unit irradiance, so the cached generations stay valid;
    /// the split of the beam budget between sun and sky follows the new powers.
    pub fn set_lighting(&mut self, sun_irradiance: DVec3, sky_radiance: DVec3) {
        let lum = |v: DVec3| (v.x + v.y + v.z) / 3.0;
        let r = self.params.bound_radius as f64;
        let had_sun =
            self.sun_fraction > 0.0 || self.params.sun_irradiance.iter().any(|&v| v > 0.0);
        let p_sun = if had_sun {
            lum(sun_irradiance) * PI * r * r
        } else {
            0.0
        };
        let p_sky = lum(sky_radiance) * 4.0 * PI * PI * r * r;
        self.sun_fraction = if p_sun + p_sky > 0.0 {
            p_sun / (p_sun + p_sky)
        } else {
            0.0
        };
        self.params.sun_irradiance = f3(sun_irradiance);
        self.params.sky_radiance = f3(sky_radiance);
    }

    /// Changes the sun direction (unit vector towards the sun) for the following frames.
    pub fn set_sun_dir(&mut self, dir: DVec3) {
        let d = f3(dir.normalize());
        if d != self.params.sun_dir {
            self.sun.dirty = true;
        }
        self.params.sun_dir = d;
    }
}
