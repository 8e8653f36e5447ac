//! The sun-transmittance volume's rebuild (exact single scattering), at once or amortised.
//!
//! T_sun is rebuilt when the sun or the density changes. At once (`PmSettings::sun_chunks`
//! = 1, the default for still images and `animate`) the ray marcher always sees the current
//! sun. In the viewer the rebuild is amortised like the paper's ring of partial caches
//! (Elek 2012 §4.2: work spread over frames, the image lagging a few frames behind a change):
//! each frame marches one of `sun_chunks` slices of the voxels into a back buffer, which is
//! copied over the volume the ray marcher reads once every slice is done. The first build of a
//! mapper is always at once (there is no earlier volume to show). A change during a rebuild
//! lets it finish and starts another, so a sun that keeps moving still refreshes T_sun every
//! `sun_chunks` frames (each slice marched with the sun of its frame, as the ring mixes beams
//! of different frames).

use super::*;

/// State of the amortised rebuild.
pub(super) struct SunRebuild {
    /// The sun or the density changed since the last rebuild started.
    pub dirty: bool,
    /// T_sun has been built at least once.
    built: bool,
    /// The next slice of a rebuild in progress.
    next: Option<u32>,
    chunks: u32,
    /// The back buffer and the pass writing it (only when amortised).
    back: Option<(wgpu::Buffer, wgpu::BindGroup)>,
}

/// The frames one sun-transmittance rebuild is spread over (1: at once).
pub(super) fn amortised_chunks(settings: &PmSettings, voxels: u32) -> u32 {
    settings.sun_chunks.clamp(1, voxels.max(1))
}

impl SunRebuild {
    /// `back_bytes`: the planned back buffer ([`super::plan::Buf::SunTBack`]; 0 when the
    /// rebuild is not amortised).
    pub fn new(
        gpu: &Gpu,
        settings: &PmSettings,
        pipeline: &wgpu::ComputePipeline,
        [params, density, light_map]: [&wgpu::Buffer; 3],
        voxels: u32,
        back_bytes: u64,
    ) -> Self {
        let chunks = amortised_chunks(settings, voxels);
        let back = (back_bytes > 0).then(|| {
            let b = gpu.zeroed("sun transmittance (back)", back_bytes);
            let bind = gpu.bind(
                pipeline,
                &[(0, params), (1, density), (2, &b), (3, light_map)],
            );
            (b, bind)
        });
        Self {
            dirty: true,
            built: false,
            next: None,
            chunks: if back.is_some() { chunks } else { 1 },
            back,
        }
    }

    /// The back buffer of an amortised rebuild.
    pub(super) fn back_buffer(&self) -> Option<&wgpu::Buffer> {
        self.back.as_ref().map(|(b, _)| b)
    }

    /// Whether a rebuild is in progress (the volume the ray marcher reads is a few frames old).
    pub fn pending(&self) -> bool {
        self.next.is_some()
    }
}

impl PhotonMapper<'_> {
    /// Brings T_sun up to date (exact variant only; a no-op otherwise): at once, or one slice
    /// per call when amortised (see the module docs).
    pub(super) fn update_sun_transmittance(&mut self) {
        if self.params.single_scatter == 0 {
            return;
        }
        if !self.sun.built || self.sun.chunks == 1 {
            if self.sun.dirty || !self.sun.built {
                self.sun_pass(0, self.params.light_voxels, false);
                self.sun.built = true;
                self.sun.dirty = false;
            }
            return;
        }
        if self.sun.next.is_none() && self.sun.dirty {
            self.sun.next = Some(0);
            self.sun.dirty = false;
        }
        let Some(k) = self.sun.next else {
            return;
        };
        // Slices of the stored bricks' voxels (pool entries from 512 on).
        let n = self.params.light_voxels;
        let per = n.div_ceil(self.sun.chunks);
        let first = k * per;
        self.sun_pass(first, per.min(n - first.min(n)), true);
        if k + 1 == self.sun.chunks {
            let (back, _) = self.sun.back.as_ref().unwrap();
            let mut enc = self.gpu.device.create_command_encoder(&Default::default());
            enc.copy_buffer_to_buffer(back, 0, &self.t_sun, 0, self.voxels as u64 * 4);
            self.gpu.queue.submit([enc.finish()]);
            self.sun.next = None;
        } else {
            self.sun.next = Some(k + 1);
        }
    }

    /// Marches voxels `first .. first + count` into the volume (or the back buffer).
    fn sun_pass(&mut self, first: u32, count: u32, back: bool) {
        if count == 0 {
            return;
        }
        self.params.sun_first = first;
        self.params.sun_count = count;
        self.gpu
            .queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        {
            let (x, y) = Gpu::workgroups_1d(count);
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("sun transmittance"),
                timestamp_writes: self.timer.pass("sun transmittance"),
            });
            pass.set_pipeline(&self.sun_stage.pipeline);
            let bind = match (&self.sun.back, back) {
                (Some((_, b)), true) => b,
                _ => &self.sun_stage.bind,
            };
            pass.set_bind_group(0, bind, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
        self.timer.resolve(&mut enc);
        self.gpu.queue.submit([enc.finish()]);
        let t = self.timer.read(self.gpu);
        self.last_times.extend(t);
    }

    /// Whether an amortised T_sun rebuild is in progress.
    pub fn sun_rebuild_pending(&self) -> bool {
        self.sun.pending()
    }
}
