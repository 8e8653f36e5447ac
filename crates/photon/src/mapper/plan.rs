//! The photon map's buffer plan: every buffer sized by the input (the light volumes' pools, the
//! ring of partial caches, the per-cell read-outs, the image), derived once from the settings and
//! the uniform block. [`PhotonMapper::new`] allocates each buffer at its planned size and the
//! memory checks sum the same plan, so the two cannot drift apart (a test compares the plan with
//! the sizes the device reports for every buffer of a mapper).

use super::*;

/// A buffer of the photon map sized by its input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Buf {
    /// The work density D at the light resolution (one f32 per pool entry).
    Density,
    /// The light bricks' index and slots (`crate::light_map`; one word when the volumes are
    /// dense).
    LightIndex,
    /// The ray marcher's own density (the grid, dense or as bricks; 0 when it reads D).
    March,
    /// The upsampled cache J (vec4 per pool entry).
    J,
    /// J's flux directions (flux-axis lobes; 16 bytes unused).
    JDir,
    /// J's high-order flux directions (split lobes; 16 bytes unused).
    JHigh,
    /// The sun-transmittance volume (exact single scattering; 4 bytes unused).
    SunT,
    /// Its back buffer while a rebuild is amortised over several frames (0: none).
    SunTBack,
    /// H_new: the generation being traced.
    HNew,
    /// The ring H_0 … H_m−1 of partial caches.
    Ring,
    /// I: the ring's total.
    Total,
    /// Per-cell read-outs of I: values, auxiliary values, flux directions.
    CellVals,
    CellAux,
    CellDir,
    /// Per cell, 1 where beams skip ahead (4 bytes unused).
    CellSkip,
    /// Each cache cell's fill, read by the final gathering.
    CellFill,
    /// The overflow flag.
    Overflow,
    /// The image: the ray marcher's, or the final gathering's running sums (made on first use).
    Image,
}

impl Buf {
    pub const ALL: [Buf; 18] = [
        Buf::Density,
        Buf::LightIndex,
        Buf::March,
        Buf::J,
        Buf::JDir,
        Buf::JHigh,
        Buf::SunT,
        Buf::SunTBack,
        Buf::HNew,
        Buf::Ring,
        Buf::Total,
        Buf::CellVals,
        Buf::CellAux,
        Buf::CellDir,
        Buf::CellSkip,
        Buf::CellFill,
        Buf::Overflow,
        Buf::Image,
    ];

    /// What the buffer holds, as errors name it when it does not fit one storage binding.
    pub fn what(self) -> &'static str {
        match self {
            Buf::Density => "the photon stages' density",
            Buf::LightIndex => "the light bricks' index",
            Buf::March => "the ray marcher's density",
            Buf::J => "the upsampled cache J",
            Buf::JDir => "the upsampled flux directions",
            Buf::JHigh => "the upsampled high-order flux directions",
            Buf::SunT => "the sun-transmittance volume",
            Buf::SunTBack => "the sun-transmittance volume's back buffer",
            Buf::HNew => "the photon cache H_new",
            Buf::Ring => "the photon-cache ring",
            Buf::Total => "the photon cache I",
            Buf::CellVals => "the cache cells' values",
            Buf::CellAux => "the cache cells' auxiliary values",
            Buf::CellDir => "the cache cells' flux directions",
            Buf::CellSkip => "the skippable cache cells",
            Buf::CellFill => "the cache cells' fills",
            Buf::Overflow => "the cache overflow flag",
            Buf::Image => "the image",
        }
    }
}

/// The bytes of every [`Buf`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BufferPlan {
    bytes: [u64; Buf::ALL.len()],
}

impl BufferPlan {
    /// The plan for `settings` and the uniform block `params` (cache and light resolutions,
    /// variant flags, image size), with `voxels` entries per light-volume pool, `light_words`
    /// words of the bricks' index and `march_bytes` of the ray marcher's own density.
    pub fn new(
        settings: &PmSettings,
        params: &VolumeParams,
        voxels: u32,
        light_words: u64,
        march_bytes: u64,
    ) -> Self {
        let v = voxels as u64;
        let cells = params.i_res.iter().map(|&r| r as u64).product::<u64>();
        let cell = cells * CELL_BYTES as u64;
        let exact = settings.variant == PmVariant::Exact;
        let unused = 16;
        let size = |b: Buf| match b {
            Buf::Density => v * 4,
            Buf::LightIndex => light_words * 4,
            Buf::March => march_bytes,
            Buf::J => v * 16,
            Buf::JDir if params.lobe_axis != 0 => v * 16,
            Buf::JDir => unused,
            Buf::JHigh if params.lobe_axis != 0 && params.lobe_split != 0 => v * 16,
            Buf::JHigh => unused,
            Buf::SunT if exact => v * 4,
            Buf::SunT => 4,
            Buf::SunTBack if exact && sun::amortised_chunks(settings, voxels) > 1 => v * 4,
            Buf::SunTBack => 0,
            Buf::HNew | Buf::Total => cell,
            Buf::Ring => settings.ring as u64 * cell,
            Buf::CellVals | Buf::CellAux => cells * 16,
            Buf::CellDir => cells * 32,
            Buf::CellSkip if params.skip_empty != 0 => cells * 4,
            Buf::CellSkip => 4,
            Buf::CellFill => cells * 4,
            Buf::Overflow => 16,
            Buf::Image => params.width as u64 * params.height as u64 * 16,
        };
        Self {
            bytes: Buf::ALL.map(size),
        }
    }

    pub fn bytes(&self, b: Buf) -> u64 {
        self.bytes[Buf::ALL
            .iter()
            .position(|&x| x == b)
            .expect("every Buf is in ALL")]
    }

    /// Every buffer with its bytes.
    pub fn entries(&self) -> impl Iterator<Item = (Buf, u64)> + '_ {
        Buf::ALL.iter().copied().zip(self.bytes.iter().copied())
    }

    /// All of the photon map's buffers sized by input, in bytes.
    pub fn total(&self) -> u64 {
        self.bytes.iter().sum()
    }

    /// Each buffer within one storage binding (errors name the buffer); on a software adapter
    /// (lavapipe), where GPU buffers live in host memory, the total within the memory budget
    /// like any other allocation sized by input, so a huge cache or ring is an error naming the
    /// settings instead of an allocation failure that aborts.
    pub fn check(&self, gpu: &Gpu, settings: &PmSettings, voxels: u32) -> Result<(), PmError> {
        for (b, bytes) in self.entries() {
            if b != Buf::March {
                // The ray marcher's density was planned within the limits (`light::march_plan`).
                gpu.check_storage(b.what(), bytes)?;
            }
        }
        if !gpu.is_software() {
            return Ok(());
        }
        let cells = self.bytes(Buf::HNew) / CELL_BYTES as u64;
        nimbus_scene::memory::check(
            self.total() as u128,
            "ring",
            &format!(
                "the photon map's buffers on {} (host memory): density and cache at {voxels} voxels, a ring of {} × {cells} cells",
                gpu.info.name, settings.ring
            ),
        )
        .map_err(PmError::Memory)
    }
}

impl PhotonMapper<'_> {
    /// The planned size of every buffer.
    pub fn plan(&self) -> &BufferPlan {
        &self.plan
    }

    /// The buffer `b` as allocated (`None`: not made yet, as the image before the first render,
    /// or not one buffer, as the ray marcher's density bricks).
    pub fn buffer(&self, b: Buf) -> Option<&wgpu::Buffer> {
        Some(match b {
            Buf::Density => &self.density,
            Buf::LightIndex => &self.light_map,
            Buf::March => match &self.march_density {
                light::MarchDensity::Dense(d) => d,
                _ => return None,
            },
            Buf::J => &self.j,
            Buf::JDir => &self.j_dir,
            Buf::JHigh => &self.j_hi,
            Buf::SunT => &self.t_sun,
            Buf::SunTBack => return self.sun.back_buffer(),
            Buf::HNew => &self.h_new,
            Buf::Ring => &self.ring,
            Buf::Total => &self.total,
            Buf::CellVals => &self.cell_vals,
            Buf::CellAux => &self.cell_aux,
            Buf::CellDir => &self.cell_dir,
            Buf::CellSkip => &self.cell_skip,
            Buf::CellFill => &self.cell_fill,
            Buf::Overflow => &self.overflow,
            Buf::Image => match (&self.image_buf, &self.gather) {
                (Some(b), _) => b,
                (None, Some(g)) => g.sums(),
                (None, None) => return None,
            },
        })
    }
}
