//! `render --method rpnn`'s arguments (the choice itself is `nimbus_render::backend`).

use std::path::PathBuf;

use clap::ValueEnum;

/// `--backend` (see [`nimbus_render::NetBackend`]).
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum NetBackend {
    /// wgpu on a hardware GPU, ort when the only adapter is a software rasteriser (lavapipe
    /// runs the network ≈ 30× slower than ONNX Runtime on the same CPU).
    Auto,
    /// Descriptors and network in WGSL compute shaders (any GPU or lavapipe).
    Wgpu,
    /// Descriptors on the CPU, network in ONNX Runtime (PyPI onnxruntime, found at run time).
    Ort,
    /// ONNX Runtime with the model's int8 copy `<model>.int8.onnx` (made by
    /// `training/quantize.py`; beyond the paper: weights int8, activations u8 per batch, the
    /// heads f32; about half the network's time on a CPU with AVX-512 VNNI).
    OrtInt8,
}

impl From<NetBackend> for nimbus_render::NetBackend {
    fn from(b: NetBackend) -> Self {
        match b {
            NetBackend::Auto => Self::Auto,
            NetBackend::Wgpu => Self::Wgpu,
            NetBackend::Ort => Self::Ort,
            NetBackend::OrtInt8 => Self::OrtInt8,
        }
    }
}

/// RPNN settings of `render --method rpnn`.
#[derive(clap::Args)]
pub(crate) struct RpnnArgs {
    /// RPNN: the ONNX model (default: the shipped model for the scene: models/rpnn-hg.onnx; with
    /// a sky and `--method rpnn` models/rpnn-hg-sky.onnx; with a Lorenz–Mie phase function
    /// models/rpnn-mie.onnx).
    #[arg(long)]
    pub(crate) model: Option<PathBuf>,
    /// RPNN: where the network runs.
    #[arg(long, value_enum, default_value = "auto")]
    pub(crate) backend: NetBackend,
    /// RPNN: sky directions per shading point and sample (network queries for sky light) of
    /// the paper's sky (`rpnn-dirs`, or a model without a sky head), 1..=1024.
    #[arg(long, default_value_t = 4, value_parser = crate::flags::int_in(1u32, 1024))]
    pub(crate) sky_dirs: u32,
    /// RPNN with a sky head: the spherical-harmonic degree (0 … 4) the sky is contracted with.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u8).range(0..=4))]
    pub(crate) sky_degree: u8,
    /// RPNN: refuse (instead of warning) when the scene's phase function or albedo differs
    /// from the model's training data.
    #[arg(long)]
    pub(crate) strict: bool,
    /// RPNN with the network on the GPU: camera rays, tracking and direct light on the CPU
    /// anyway (the hybrid path, for comparison). Without it the whole sample runs on the GPU
    /// where the scene allows (HG or isotropic phase; a sky through the sky head).
    #[arg(long)]
    pub(crate) cpu_shading: bool,
    /// RPNN with the network on the GPU: how its weights and hidden activations are stored;
    /// f16 halves their memory traffic, the products accumulate in f32 either way.
    #[arg(long, value_enum, default_value = "f32")]
    pub(crate) net_precision: NetPrecision,
    /// RPNN with the network on the GPU: its kernel's tiles, queries × outputs per workgroup
    /// (the same products; which is faster depends on the GPU).
    #[arg(long, value_enum, default_value = "64x128")]
    pub(crate) net_tiles: NetTiles,
    /// RPNN: bounces traced before the network is asked (0: the paper). Lowers the error on
    /// thin clouds (cirrus), adds noise on thick ones; shades on the CPU.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=nimbus_rpnn::render::MAX_TRACED_BOUNCES as i64))]
    pub(crate) traced_bounces: u32,
    /// RPNN: one sample in every M of a pixel asks the network (1: every sample, the paper).
    /// The others estimate only the direct light, and the answers are weighted M, so the
    /// image's mean is the same: for converged renders, M-fold less network time for a little
    /// more noise (beyond the paper). A preview of fewer than M samples shows pixels without
    /// their multiple scattering.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=nimbus_rpnn::render::MAX_QUERY_EVERY as i64))]
    pub(crate) query_every: u32,
}

/// `--net-tiles` (see [`nimbus_rpnn::gpu_mlp::Tiles`]).
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum NetTiles {
    /// 4 × 4 per thread.
    #[value(name = "64x64")]
    Square,
    /// 8 × 8 per thread, slices loaded along the inputs.
    #[value(name = "64x128")]
    Wide,
}

impl From<NetTiles> for nimbus_rpnn::gpu_mlp::Tiles {
    fn from(t: NetTiles) -> Self {
        match t {
            NetTiles::Square => Self::Square,
            NetTiles::Wide => Self::Wide,
        }
    }
}

/// `--net-precision` (see [`nimbus_rpnn::gpu_mlp::Precision`]).
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum NetPrecision {
    F32,
    /// IEEE half floats (f32 accumulation).
    F16,
}

impl From<NetPrecision> for nimbus_rpnn::gpu_mlp::Precision {
    fn from(p: NetPrecision) -> Self {
        match p {
            NetPrecision::F32 => Self::F32,
            NetPrecision::F16 => Self::F16,
        }
    }
}

impl RpnnArgs {
    /// The estimator's RPNN settings.
    pub(crate) fn settings(&self) -> nimbus_render::RpnnSettings {
        nimbus_render::RpnnSettings {
            model: self.model.clone(),
            backend: self.backend.into(),
            sky_dirs: self.sky_dirs,
            strict: self.strict,
            sky_degree: self.sky_degree as usize,
            cpu_shading: self.cpu_shading,
            precision: self.net_precision.into(),
            tiles: self.net_tiles.into(),
            traced_bounces: self.traced_bounces,
            query_every: self.query_every,
        }
    }
}
