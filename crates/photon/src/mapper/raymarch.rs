//! The last stage of a [`PhotonMapper`] image: ray marching the upsampled J towards a camera
//! (Elek 2012 §4.4), at full or half resolution; the stage's bindings are made once per image
//! size.

use super::*;

impl PhotonMapper<'_> {
    /// Ray marches the current J for `camera` (Elek §4.4).
    pub fn raymarch(&mut self, camera: &Camera) -> Result<Image, PmError> {
        // J upsampled for a view point too far from this camera: upsampled again (with the lobes
        // unless the ring is close enough to this camera).
        if self
            .j_view
            .is_some_and(|v| !self.view_close(v, f3(camera.origin)))
        {
            self.set_view(camera.origin);
            self.upsample();
        }
        self.update_sun_transmittance();
        // What J holds, whatever a trace since the last upsampling left in the uniform.
        self.params.view_mode = self.j_view_mode();
        let (w, h) = (camera.width, camera.height);
        self.set_camera_params(camera);
        self.gpu
            .queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        self.gpu
            .queue
            .write_buffer(&self.march_buf, 0, bytemuck::bytes_of(&self.march_params()));
        if !matches!(&self.raymarch, Some((_, rw, rh)) if *rw == w && *rh == h) {
            self.gpu
                .check_storage("the image", w as u64 * h as u64 * 16)?;
            let img = self.gpu.zeroed("image", w as u64 * h as u64 * 16);
            let mut buffers = vec![
                (0, &self.march_buf),
                (2, &self.j),
                (3, &img),
                (4, &self.t_sun),
                (5, &self.j_dir),
                (6, &self.j_hi),
                (9, &self.light_map),
            ];
            let bind = match &self.march_density {
                light::MarchDensity::Work => {
                    buffers.push((1, &self.density));
                    self.gpu.bind(&self.raymarch_pipeline, &buffers)
                }
                light::MarchDensity::Dense(d) => {
                    buffers.push((1, d));
                    self.gpu.bind(&self.raymarch_pipeline, &buffers)
                }
                light::MarchDensity::Bricks(k) => {
                    buffers.extend([(1, &k.index), (7, &k.info)]);
                    self.gpu
                        .bind_with(&self.raymarch_pipeline, &buffers, &[(8, &k.view)])
                }
            };
            self.raymarch = Some((
                Stage {
                    pipeline: self.raymarch_pipeline.clone(),
                    bind,
                },
                w,
                h,
            ));
            self.image_buf = Some(img);
        }
        let (stage, _, _) = self.raymarch.as_ref().unwrap();
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("raymarch"),
                timestamp_writes: self.timer.pass("ray-marching"),
            });
            pass.set_pipeline(&stage.pipeline);
            pass.set_bind_group(0, &stage.bind, &[]);
            pass.dispatch_workgroups((w as u32).div_ceil(8), (h as u32).div_ceil(8), 1);
        }
        self.timer.resolve(&mut enc);
        self.gpu.queue.submit([enc.finish()]);
        let t = self.timer.read(self.gpu);
        self.last_times.extend(t);
        let px: Vec<[f32; 4]> = self.gpu.read(self.image_buf.as_ref().unwrap())?;
        let mut img = Image::new(w, h);
        for (o, p) in img.pixels.iter_mut().zip(px) {
            *o = [p[0], p[1], p[2]];
        }
        Ok(img)
    }

    /// Writes `camera` into the uniform block (position, basis, field of view, image size).
    pub(super) fn set_camera_params(&mut self, camera: &Camera) {
        let (w, h) = (camera.width, camera.height);
        let (forward, right, up, tan_half) = camera.basis();
        self.params.cam_origin = f3(camera.origin);
        self.params.cam_forward = f3(forward);
        self.params.cam_right = f3(right);
        self.params.cam_up = f3(up);
        self.params.tan_half = tan_half as f32;
        self.params.aspect = (w as f64 / h as f64) as f32;
        self.params.width = w as u32;
        self.params.height = h as u32;
    }

    /// Ray marches at half the resolution in both dimensions and upscales bilinearly
    /// (Elek §4.4: the detail noise is of lower frequency than the screen sampling).
    pub fn raymarch_half(&mut self, camera: &Camera) -> Result<Image, PmError> {
        let (w, h) = (camera.width, camera.height);
        let half = camera
            .with_size(w.div_ceil(2), h.div_ceil(2))
            .map_err(|e| PmError::Unsupported(e.to_string()))?;
        Ok(self.raymarch(&half)?.resize_bilinear(w, h))
    }
}
