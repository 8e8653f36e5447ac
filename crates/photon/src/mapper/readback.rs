//! Read-back and inspection of a [`PhotonMapper`]'s GPU state: caches, upsampled volumes, the
//! sun-transmittance volume, beam counts and the overflow flag (for tests, tools and checks;
//! each read is a GPU sync, none runs on the frame path except the 4-byte overflow flag).

use super::*;

impl PhotonMapper<'_> {
    /// Reads the sun-transmittance volume back (exact variant).
    pub fn read_sun_transmittance(&mut self) -> Result<Vec<f32>, PmError> {
        self.update_sun_transmittance();
        let pool: Vec<f32> = self.gpu.read(&self.t_sun)?;
        Ok(self.map.to_dense(&pool))
    }

    /// Reads the coarse cells' flux entries back (as written by the last upsampling): per
    /// cell, (low-order mean propagation vector, 1 if present) and (high-order mean
    /// propagation vector, high-order fluence).
    pub fn read_cell_dirs(&self) -> Result<Vec<[glam::Vec4; 2]>, PmError> {
        let v: Vec<[f32; 4]> = self.gpu.read(&self.cell_dir)?;
        Ok(v.chunks(2)
            .map(|c| [glam::Vec4::from_array(c[0]), glam::Vec4::from_array(c[1])])
            .collect())
    }

    /// Reads the upsampled flux lobes back (flux axes; one per light voxel, dense): (low-order
    /// mean propagation vector, high-order fluence) and (high-order mean propagation vector, 0).
    pub fn read_j_dirs(&self) -> Result<Vec<[glam::Vec4; 2]>, PmError> {
        let a: Vec<[f32; 4]> = self.map.to_dense(&self.gpu.read::<[f32; 4]>(&self.j_dir)?);
        let b: Vec<[f32; 4]> = if self.params.lobe_split != 0 {
            self.map.to_dense(&self.gpu.read::<[f32; 4]>(&self.j_hi)?)
        } else {
            vec![[0.0; 4]; a.len()]
        };
        Ok(a.into_iter()
            .zip(b)
            .map(|(a, b)| [glam::Vec4::from_array(a), glam::Vec4::from_array(b)])
            .collect())
    }

    /// Reads the total cache I ([`CELL_WORDS`] u32 per cell) back.
    pub fn read_total(&self) -> Result<Vec<u32>, PmError> {
        Ok(self.gpu.read(&self.total)?)
    }

    /// Reads J (4 floats per light voxel, dense: 0 in absent bricks) back.
    pub fn read_j(&self) -> Result<Vec<[f32; 4]>, PmError> {
        Ok(self.map.to_dense(&self.gpu.read::<[f32; 4]>(&self.j)?))
    }

    /// Each cache cell's fill (`light::cell_fills`), as the final gathering reads it.
    pub fn read_cell_fill(&self) -> Result<Vec<f32>, PmError> {
        Ok(self.gpu.read(&self.cell_fill)?)
    }

    /// The density the photon stages read (the grid's values, or its block means at the light
    /// resolution), dense.
    pub fn read_density(&self) -> Result<Vec<f32>, PmError> {
        Ok(self.map.to_dense(&self.gpu.read::<f32>(&self.density)?))
    }

    /// Light bricks stored and in the light grid (`crate::light_map`).
    pub fn light_bricks(&self) -> (usize, usize) {
        let b = crate::light_map::brick_res(self.map.res());
        (self.map.stored_bricks(), b.iter().product())
    }

    /// Total number of (sun, sky) beams in the ring.
    pub fn ring_beams(&self) -> (u64, u64) {
        self.slot_beams
            .iter()
            .fold((0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
    }

    /// (sun, sky) beams of the most recently traced generation.
    pub fn last_generation_beams(&self) -> (u64, u64) {
        if self.frame == 0 {
            return (0, 0);
        }
        self.slot_beams[((self.frame - 1) % self.settings.ring) as usize]
    }

    /// Whether a cache sum overflowed 32 bits since the mapper was made (or [`Self::reset`]):
    /// an error naming the remedies, else `Ok`. One 4-byte read back (a GPU sync).
    pub fn check_overflow(&self) -> Result<(), PmError> {
        let flag: Vec<u32> = self.gpu.read(&self.overflow)?;
        if flag.first().copied().unwrap_or(0) == 0 {
            return Ok(());
        }
        let r = self.params.i_res;
        Err(PmError::Overflow {
            cells: format!("{}×{}×{} cache", r[0], r[1], r[2]),
            units: u32::MAX as f64 / W_SCALE,
            ring: self.settings.ring,
            beams: self.settings.beams_per_frame,
        })
    }
}
