//! GPU timestamp queries per compute stage, when the adapter has them.

use crate::Gpu;

/// Up to `capacity` named stages timed with a pair of timestamps each.
pub struct StageTimer {
    set: Option<wgpu::QuerySet>,
    resolve: Option<wgpu::Buffer>,
    names: Vec<&'static str>,
    capacity: u32,
}

impl StageTimer {
    pub fn new(gpu: &Gpu, capacity: u32) -> Self {
        if !gpu.has_timestamps() {
            return Self {
                set: None,
                resolve: None,
                names: Vec::new(),
                capacity,
            };
        }
        let set = gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("stage timestamps"),
            ty: wgpu::QueryType::Timestamp,
            count: capacity * 2,
        });
        let resolve = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("timestamp resolve"),
            size: capacity as u64 * 16,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        Self {
            set: Some(set),
            resolve: Some(resolve),
            names: Vec::new(),
            capacity,
        }
    }

    /// Timestamp writes for a compute pass of stage `name` (None without timestamp support or
    /// when full).
    pub fn pass(&mut self, name: &'static str) -> Option<wgpu::ComputePassTimestampWrites<'_>> {
        let set = self.set.as_ref()?;
        if self.names.len() as u32 >= self.capacity {
            return None;
        }
        let i = self.names.len() as u32;
        self.names.push(name);
        Some(wgpu::ComputePassTimestampWrites {
            query_set: set,
            beginning_of_pass_write_index: Some(2 * i),
            end_of_pass_write_index: Some(2 * i + 1),
        })
    }

    /// Resolves the queries (call before submitting the encoder).
    pub fn resolve(&self, enc: &mut wgpu::CommandEncoder) {
        if let (Some(set), Some(buf)) = (&self.set, &self.resolve)
            && !self.names.is_empty()
        {
            enc.resolve_query_set(set, 0..2 * self.names.len() as u32, buf, 0);
        }
    }

    /// Milliseconds per stage, summed over passes with the same name, in first-seen order.
    pub fn read(&mut self, gpu: &Gpu) -> Vec<(&'static str, f64)> {
        let Some(buf) = &self.resolve else {
            return Vec::new();
        };
        if self.names.is_empty() {
            return Vec::new();
        }
        let Ok(ticks) = gpu.read::<u64>(buf) else {
            return Vec::new();
        };
        let period = gpu.queue.get_timestamp_period() as f64;
        let mut out: Vec<(&'static str, f64)> = Vec::new();
        for (i, name) in self.names.iter().enumerate() {
            let dt = ticks[2 * i + 1].saturating_sub(ticks[2 * i]) as f64 * period * 1e-6;
            match out.iter_mut().find(|(n, _)| n == name) {
                Some(e) => e.1 += dt,
                None => out.push((name, dt)),
            }
        }
        self.names.clear();
        out
    }
}
