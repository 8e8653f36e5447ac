//! Where the GPU estimators and the RPNN network run: the one place that opens the GPU and
//! chooses the network's backend.

use std::sync::OnceLock;

use anyhow::{Context, Result};
use nimbus_gpu::Gpu;

/// Where RPNN's network runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum NetBackend {
    /// wgpu on a hardware GPU, ONNX Runtime when the only adapter is a software rasteriser
    /// (lavapipe runs the network ≈ 30× slower than ONNX Runtime on the same CPU) or there is
    /// none.
    #[default]
    Auto,
    /// Descriptors and network in WGSL compute shaders (any GPU or lavapipe).
    Wgpu,
    /// Descriptors on the CPU, network in ONNX Runtime (PyPI onnxruntime, found at run time).
    Ort,
    /// As [`NetBackend::Ort`], with the model's int8 copy (`<model>.int8.onnx`, made by
    /// `training/quantize.py`; [`nimbus_rpnn::ort_backend::OrtModel::load_int8`]): beyond the
    /// paper, about half the network's time on a CPU with AVX-512 VNNI
    /// (`docs/experiments/2026-12-07-rpnn-sample-rounds.md`, "The int8 network").
    OrtInt8,
}

impl NetBackend {
    pub const ALL: [NetBackend; 4] = [
        NetBackend::Auto,
        NetBackend::Wgpu,
        NetBackend::Ort,
        NetBackend::OrtInt8,
    ];

    /// The name on the command line (`--backend`).
    pub fn name(self) -> &'static str {
        match self {
            NetBackend::Auto => "auto",
            NetBackend::Wgpu => "wgpu",
            NetBackend::Ort => "ort",
            NetBackend::OrtInt8 => "ort-int8",
        }
    }

    /// Whether the network runs in WGSL, given the adapter `Auto` would use (`None`: no
    /// adapter).
    pub fn uses_wgpu(self, adapter_is_software: Option<bool>) -> bool {
        match self {
            NetBackend::Wgpu => true,
            NetBackend::Ort | NetBackend::OrtInt8 => false,
            NetBackend::Auto => adapter_is_software == Some(false),
        }
    }
}

impl std::str::FromStr for NetBackend {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|b| b.name() == s)
            .ok_or_else(|| {
                format!("unknown network backend `{s}` (expected auto, wgpu, ort or ort-int8)")
            })
    }
}

/// A GPU opened on first use and shared by every estimator of one program run (the
/// evaluation renders several methods on one device). `Sync`: a `static` slot gives a
/// process one device that every estimator, on any thread, borrows (`Estimator<'static>`).
#[derive(Default)]
pub struct GpuSlot {
    gpu: OnceLock<Gpu>,
}

impl GpuSlot {
    /// An empty slot: no adapter is opened until a method needs one.
    pub const fn new() -> Self {
        Self {
            gpu: OnceLock::new(),
        }
    }

    /// A slot holding an already opened GPU (the viewer owns its device and surface).
    pub fn with(gpu: Gpu) -> Self {
        let s = Self::default();
        let _ = s.gpu.set(gpu);
        s
    }

    /// The GPU, opened now if it is not yet.
    pub fn get(&self) -> Result<&Gpu> {
        if let Some(g) = self.gpu.get() {
            return Ok(g);
        }
        let g = Gpu::new().context("no GPU adapter for a GPU method")?;
        Ok(self.gpu.get_or_init(|| g))
    }

    /// The GPU if one can be opened, without an error when there is none.
    pub fn try_get(&self) -> Option<&Gpu> {
        self.get().ok()
    }
}

/// Where an estimator finds its GPU: a [`GpuSlot`] (opened on first use) or an open [`Gpu`]
/// (the viewer's, which owns the window's surface).
pub trait GpuSource<'g>: Copy {
    fn get(self) -> Result<&'g Gpu>;
    fn try_get(self) -> Option<&'g Gpu>;
}

impl<'g> GpuSource<'g> for &'g GpuSlot {
    fn get(self) -> Result<&'g Gpu> {
        GpuSlot::get(self)
    }
    fn try_get(self) -> Option<&'g Gpu> {
        GpuSlot::try_get(self)
    }
}

impl<'g> GpuSource<'g> for &'g Gpu {
    fn get(self) -> Result<&'g Gpu> {
        Ok(self)
    }
    fn try_get(self) -> Option<&'g Gpu> {
        Some(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Auto takes the GPU only when it is real hardware; the explicit choices are obeyed.
    #[test]
    fn backend_choice() {
        assert!(NetBackend::Auto.uses_wgpu(Some(false)));
        assert!(!NetBackend::Auto.uses_wgpu(Some(true)));
        assert!(!NetBackend::Auto.uses_wgpu(None));
        assert!(NetBackend::Wgpu.uses_wgpu(Some(true)));
        assert!(!NetBackend::Ort.uses_wgpu(Some(false)));
    }
}
