//! # nimbus-gpu
//!
//! wgpu 30 device creation (prefers a discrete GPU, falls back to any adapter such as Mesa's
//! lavapipe), limit checks with clear errors, the registry of all WGSL shaders in `shaders/`,
//! buffer helpers and GPU timestamp queries.

pub mod compose;
pub mod consts;
pub mod density;
pub mod params;
pub mod readback;
pub mod shaders;
pub mod testing;
pub mod timing;

use bytemuck::Pod;
use wgpu::util::DeviceExt;

/// Errors of GPU setup and use.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error(
        "no GPU adapter found (on a machine without a GPU, install Mesa's software Vulkan: `apt-get install mesa-vulkan-drivers`)"
    )]
    NoAdapter,
    #[error("cannot open the GPU device {adapter}: {msg}")]
    Device { adapter: String, msg: String },
    #[error(
        "{what} needs {bytes} bytes in one GPU storage buffer, but this adapter ({adapter}) allows at most {limit}; use a smaller grid or image"
    )]
    TooLarge {
        what: String,
        bytes: u64,
        limit: u64,
        adapter: String,
    },
    #[error("{what} cannot be placed in a GPU texture atlas on this adapter ({adapter}): {msg}")]
    Atlas {
        what: String,
        msg: String,
        adapter: String,
    },
    #[error("GPU readback failed: {0}")]
    Readback(String),
    /// A host-side copy for an upload does not fit the memory budget (the message names the
    /// bytes and the budget).
    #[error("{0}")]
    Memory(String),
    /// Something this GPU code does not implement (the message says what and where instead).
    #[error("{0}")]
    Unsupported(String),
}

/// An open device with its queue and what it offers.
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
    pub features: wgpu::Features,
}

/// Adapter order: hardware before software, and within a kind the native APIs (Vulkan, Metal,
/// DX12) before OpenGL (Mesa's GL llvmpipe is ≈ 3× slower than Vulkan lavapipe on the same CPU).
fn preference(info: &wgpu::AdapterInfo) -> (u32, u32) {
    let kind = match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    };
    let api = match info.backend {
        wgpu::Backend::Gl => 1,
        _ => 0,
    };
    (kind, api)
}

/// One line for the user when the chosen adapter is slow for a reason they can fix: OpenGL
/// (wgpu falls back to it when no Vulkan driver is installed). Software Vulkan (lavapipe) gets
/// no hint: it is the expected adapter on machines without a GPU.
pub fn adapter_hint(info: &wgpu::AdapterInfo) -> Option<String> {
    (info.backend == wgpu::Backend::Gl).then(|| {
        let soft = if info.device_type == wgpu::DeviceType::Cpu {
            " (software, on the CPU)"
        } else {
            ""
        };
        format!(
            "note: the GPU work runs on OpenGL: {}{soft}; a Vulkan driver is faster — install \
             your GPU's Vulkan driver, or Mesa's lavapipe on machines without a GPU \
             (`apt-get install mesa-vulkan-drivers`); `nimbus info --gpu` lists the adapters",
            info.name
        )
    })
}

/// Keeps a headless process's output to what a user needs. Without a Wayland session (no
/// valid `XDG_RUNTIME_DIR`), Mesa's device-selection layer (`VK_LAYER_MESA_device_select`, an
/// implicit Vulkan layer installed with Mesa's drivers) asks libwayland for a display when a
/// Vulkan instance is made, and libwayland prints "error: XDG_RUNTIME_DIR is invalid or not set
/// in the environment." although nothing failed. The layer only reorders the devices the
/// loader lists, and wgpu chooses its adapter itself ([`Gpu::new`]), so such a process turns
/// the layer off with the switch its manifest declares (`NODEVICE_SELECT=1`) — unless the user
/// set that switch or chose a device through the layer (`MESA_VK_DEVICE_SELECT`).
///
/// It sets an environment variable: call it first in `main` (or a module's initialisation),
/// before other threads start. Returns whether it turned the layer off.
pub fn quiet_headless_vulkan() -> bool {
    let env = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
    let session = env("XDG_RUNTIME_DIR").is_some_and(|d| std::path::Path::new(&d).is_dir());
    if session || env("NODEVICE_SELECT").is_some() || env("MESA_VK_DEVICE_SELECT").is_some() {
        return false;
    }
    // SAFETY: called before other threads run (the documented contract), so no other thread
    // reads the environment while it is changed.
    unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    true
}

/// Every adapter wgpu sees, best first (the first is the one [`Gpu::new`] opens), as
/// "name (type, backend)" lines.
pub fn list_adapters() -> Vec<String> {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let mut infos: Vec<wgpu::AdapterInfo> =
        pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()))
            .iter()
            .map(|a| a.get_info())
            .collect();
    infos.sort_by_key(preference);
    infos
        .iter()
        .map(|i| format!("{} ({:?}, {:?})", i.name, i.device_type, i.backend))
        .collect()
}

impl Gpu {
    /// Opens the best adapter: a discrete GPU if there is one, else any (a software rasteriser
    /// on machines without a GPU). Requests only the features Nimbus uses (timestamp queries,
    /// when offered) and the adapter's own limits.
    pub fn new() -> Result<Self, GpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        Ok(Self::for_surface(&instance, None)?.0)
    }

    /// Like [`Gpu::new`], restricted to adapters that can present to `surface` (a window);
    /// also returns the adapter, which the surface configuration needs.
    pub fn for_surface(
        instance: &wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<(Self, wgpu::Adapter), GpuError> {
        let mut adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()));
        adapters.retain(|a| surface.is_none_or(|s| a.is_surface_supported(s)));
        adapters.sort_by_key(|a| preference(&a.get_info()));
        let adapter = adapters.into_iter().next().ok_or(GpuError::NoAdapter)?;
        let info = adapter.get_info();
        if let Some(hint) = adapter_hint(&info) {
            static ONCE: std::sync::Once = std::sync::Once::new();
            ONCE.call_once(|| eprintln!("{hint}"));
        }
        let wanted = wgpu::Features::TIMESTAMP_QUERY;
        let features = adapter.features() & wanted;
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("nimbus"),
            required_features: features,
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| GpuError::Device {
            adapter: info.name.clone(),
            msg: e.to_string(),
        })?;
        Ok((
            Self {
                device,
                queue,
                info,
                limits,
                features,
            },
            adapter,
        ))
    }

    /// A one-line description of the adapter.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.device_type, self.info.backend
        )
    }

    /// Whether the adapter is a software rasteriser (lavapipe/llvmpipe) running on the CPU.
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    pub fn has_timestamps(&self) -> bool {
        self.features.contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// Checks that one storage binding of `bytes` fits this adapter.
    pub fn check_storage(&self, what: &str, bytes: u64) -> Result<(), GpuError> {
        let limit = self
            .limits
            .max_storage_buffer_binding_size
            .min(self.limits.max_buffer_size);
        if bytes > limit {
            return Err(GpuError::TooLarge {
                what: what.to_string(),
                bytes,
                limit,
                adapter: self.info.name.clone(),
            });
        }
        Ok(())
    }

    /// A storage buffer initialised with `data` (at least 4 bytes, so empty arrays still bind).
    pub fn storage<T: Pod>(&self, label: &str, data: &[T]) -> wgpu::Buffer {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let contents: Vec<u8> = if bytes.is_empty() {
            vec![0; 4]
        } else {
            bytes.to_vec()
        };
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: &contents,
                usage: wgpu::BufferUsages::STORAGE
                    | wgpu::BufferUsages::COPY_SRC
                    | wgpu::BufferUsages::COPY_DST,
            })
    }

    /// A zeroed storage buffer of `bytes` bytes.
    pub fn zeroed(&self, label: &str, bytes: u64) -> wgpu::Buffer {
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes.max(4).next_multiple_of(4),
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// A uniform buffer holding `value`.
    pub fn uniform<T: Pod>(&self, label: &str, value: &T) -> wgpu::Buffer {
        self.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytemuck::bytes_of(value),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            })
    }

    /// A compute pipeline from WGSL source with an automatic bind-group layout.
    pub fn pipeline(&self, label: &str, source: &str, entry: &str) -> wgpu::ComputePipeline {
        self.pipeline_with_constants(label, source, entry, &[])
    }

    /// A compute pipeline whose WGSL `override` constants are set (compile-time specialisation).
    pub fn pipeline_with_constants(
        &self,
        label: &str,
        source: &str,
        entry: &str,
        constants: &[(&str, f64)],
    ) -> wgpu::ComputePipeline {
        let module = self
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            });
        self.device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(label),
                layout: None,
                module: &module,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants,
                    ..Default::default()
                },
                cache: None,
            })
    }

    /// A bind group for group 0 of `pipeline` from (binding, buffer) pairs. Only the bindings
    /// the shader entry point uses may be given (the layout is derived from the shader).
    pub fn bind(
        &self,
        pipeline: &wgpu::ComputePipeline,
        buffers: &[(u32, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        self.bind_with(pipeline, buffers, &[])
    }

    /// Like [`Gpu::bind`], with texture views as well.
    pub fn bind_with(
        &self,
        pipeline: &wgpu::ComputePipeline,
        buffers: &[(u32, &wgpu::Buffer)],
        textures: &[(u32, &wgpu::TextureView)],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = buffers
            .iter()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: *i,
                resource: b.as_entire_binding(),
            })
            .chain(textures.iter().map(|(i, v)| wgpu::BindGroupEntry {
                binding: *i,
                resource: wgpu::BindingResource::TextureView(v),
            }))
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// Workgroup counts (x, y) covering `invocations` threads of [`consts::WG`]-wide
    /// workgroups; beyond the 65 535 limit of one dimension the rest goes to y (shaders index
    /// `gid.x + gid.y * num_workgroups.x * WG`).
    pub fn workgroups_1d(invocations: u32) -> (u32, u32) {
        let wg = invocations.div_ceil(consts::WG).max(1);
        if wg <= 65535 {
            (wg, 1)
        } else {
            (65535, wg.div_ceil(65535))
        }
    }

    /// Records and submits one compute pass of `pipeline` over `invocations` threads.
    pub fn dispatch_1d(
        &self,
        pipeline: &wgpu::ComputePipeline,
        bind: &wgpu::BindGroup,
        invocations: u32,
    ) {
        let (x, y) = Self::workgroups_1d(invocations);
        let mut enc = self.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, bind, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
        self.queue.submit([enc.finish()]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(
        name: &str,
        device_type: wgpu::DeviceType,
        backend: wgpu::Backend,
    ) -> wgpu::AdapterInfo {
        let mut i = wgpu::AdapterInfo::new(device_type, backend);
        i.name = name.into();
        i
    }

    #[test]
    fn vulkan_lavapipe_is_preferred_over_gl_llvmpipe_and_hardware_over_both() {
        use wgpu::{Backend, DeviceType};
        let mut v = [
            info("llvmpipe", DeviceType::Cpu, Backend::Gl),
            info("lavapipe", DeviceType::Cpu, Backend::Vulkan),
            info("gpu-gl", DeviceType::DiscreteGpu, Backend::Gl),
            info("gpu", DeviceType::DiscreteGpu, Backend::Vulkan),
        ];
        v.sort_by_key(preference);
        let names: Vec<&str> = v.iter().map(|i| i.name.as_str()).collect();
        assert_eq!(names, ["gpu", "gpu-gl", "lavapipe", "llvmpipe"]);
    }

    #[test]
    fn hint_only_for_opengl() {
        use wgpu::{Backend, DeviceType};
        let gl = adapter_hint(&info("llvmpipe", DeviceType::Cpu, Backend::Gl)).unwrap();
        assert!(gl.contains("llvmpipe") && gl.contains("apt-get install mesa-vulkan-drivers"));
        assert!(adapter_hint(&info("lavapipe", DeviceType::Cpu, Backend::Vulkan)).is_none());
        assert!(adapter_hint(&info("gpu", DeviceType::DiscreteGpu, Backend::Vulkan)).is_none());
    }
}
