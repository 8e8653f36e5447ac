//! The one way a buffer comes back from the GPU: [`Gpu::read_async`] starts the copy and the
//! map and returns a future of the contents; [`Gpu::read`] is that future waited for on native
//! targets (the device polled, then the future completed). A browser has no blocking wait: its
//! event loop completes the map, and an `async` caller awaits the same future.

use std::future::Future;
use std::marker::PhantomData;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, Waker};

use bytemuck::Pod;

use crate::{Gpu, GpuError};

/// A read-back under way ([`Gpu::read_async`]).
pub struct ReadBack<T> {
    staging: wgpu::Buffer,
    state: Arc<Mutex<MapState>>,
    _t: PhantomData<fn() -> T>,
}

#[derive(Default)]
struct MapState {
    done: Option<Result<(), wgpu::BufferAsyncError>>,
    waker: Option<Waker>,
}

impl<T: Pod> Future for ReadBack<T> {
    type Output = Result<Vec<T>, GpuError>;

    fn poll(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Self::Output> {
        let err = |e: &dyn std::fmt::Display| GpuError::Readback(e.to_string());
        let done = {
            let mut s = self.state.lock().map_err(|e| err(&e))?;
            match s.done.take() {
                Some(r) => r,
                None => {
                    s.waker = Some(cx.waker().clone());
                    return Poll::Pending;
                }
            }
        };
        done.map_err(|e| err(&e))?;
        let slice = self.staging.slice(..);
        let view = slice.get_mapped_range().map_err(|e| err(&e))?;
        let out = bytemuck::cast_slice::<u8, T>(&view).to_vec();
        drop(view);
        self.staging.unmap();
        Poll::Ready(Ok(out))
    }
}

impl Gpu {
    /// Starts copying `buffer` back to the CPU: the copy is submitted and the staging buffer's
    /// map requested now; the future resolves once the map completes (native: when the device
    /// is polled; in a browser: by its event loop).
    pub fn read_async<T: Pod>(&self, buffer: &wgpu::Buffer) -> ReadBack<T> {
        let size = buffer.size();
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
        self.queue.submit([enc.finish()]);
        let state = Arc::new(Mutex::new(MapState::default()));
        let shared = state.clone();
        staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            if let Ok(mut s) = shared.lock() {
                s.done = Some(r);
                if let Some(w) = s.waker.take() {
                    w.wake();
                }
            }
        });
        ReadBack {
            staging,
            state,
            _t: PhantomData,
        }
    }

    /// Copies a buffer back to the CPU, blocking: [`Gpu::read_async`] with the device polled
    /// until the work is done.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn read<T: Pod>(&self, buffer: &wgpu::Buffer) -> Result<Vec<T>, GpuError> {
        let back = self.read_async(buffer);
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        pollster::block_on(back)
    }
}

#[cfg(test)]
mod tests {
    use wgpu::util::DeviceExt;

    /// The future and the blocking read give the buffer's values; several read-backs under way
    /// at once each get their own.
    #[test]
    fn async_and_blocking_reads_agree() {
        let Some(gpu) = crate::testing::gpu("readback::async_and_blocking_reads_agree") else {
            return;
        };
        let data: Vec<u32> = (0..1000).map(|i| i * 7 + 1).collect();
        let other: Vec<u32> = (0..64).map(|i| 1_000_000 - i).collect();
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
        let make = |v: &[u32]| {
            gpu.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: None,
                    contents: bytemuck::cast_slice(v),
                    usage,
                })
        };
        let (a, b) = (make(&data), make(&other));
        assert_eq!(gpu.read::<u32>(&a).unwrap(), data);
        let fa = gpu.read_async::<u32>(&a);
        let fb = gpu.read_async::<u32>(&b);
        gpu.device
            .poll(wgpu::PollType::wait_indefinitely())
            .unwrap();
        assert_eq!(pollster::block_on(fb).unwrap(), other);
        assert_eq!(pollster::block_on(fa).unwrap(), data);
    }
}
