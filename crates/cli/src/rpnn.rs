//! `render --method rpnn`'s arguments (the choice itself is `nimbus_render::backend`).

use std::path::PathBuf;

use nimbus_render::NetBackend;
use nimbus_rpnn::gpu_mlp::{Precision, Tiles};

use crate::args::one_of;

/// RPNN settings of `render --method rpnn`.
#[derive(clap::Args)]
pub(crate) struct RpnnArgs {
    /// RPNN: the ONNX model (default: the shipped model for the scene: models/rpnn-hg.onnx; with
    /// a sky and `--method rpnn` models/rpnn-hg-sky.onnx; with a Lorenz–Mie phase function
    /// models/rpnn-mie.onnx).
    #[arg(long)]
    pub(crate) model: Option<PathBuf>,
    /// RPNN: where the network runs: `auto` (wgpu on a hardware GPU, ort when the only adapter
    /// is a software rasteriser: lavapipe runs the network ≈ 30× slower than ONNX Runtime on
    /// the same CPU), `wgpu` (descriptors and network in WGSL compute shaders, any GPU or
    /// lavapipe), `ort` (descriptors on the CPU, network in ONNX Runtime: PyPI onnxruntime,
    /// found at run time) or `ort-int8` (ONNX Runtime with the model's int8 copy
    /// `<model>.int8.onnx`, made by `training/quantize.py`; beyond the paper: weights int8,
    /// activations u8 per batch, the heads f32; about half the network's time on a CPU with
    /// AVX-512 VNNI).
    #[arg(long, default_value = "auto", value_parser = one_of(NetBackend::ALL, NetBackend::name))]
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
    /// f16 (IEEE half floats) halves their memory traffic, the products accumulate in f32
    /// either way.
    #[arg(long, default_value = "f32", value_parser = one_of(Precision::ALL, Precision::name))]
    pub(crate) net_precision: Precision,
    /// RPNN with the network on the GPU: its kernel's tiles, queries × outputs per workgroup
    /// (the same products; which is faster depends on the GPU): `64x64` (4 × 4 per thread) or
    /// `64x128` (8 × 8 per thread, slices loaded along the inputs).
    #[arg(long, default_value = "64x128", value_parser = one_of(Tiles::ALL, Tiles::name))]
    pub(crate) net_tiles: Tiles,
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

impl RpnnArgs {
    /// The estimator's RPNN settings.
    pub(crate) fn settings(&self) -> nimbus_render::RpnnSettings {
        nimbus_render::RpnnSettings {
            model: self.model.clone(),
            backend: self.backend,
            sky_dirs: self.sky_dirs,
            strict: self.strict,
            sky_degree: self.sky_degree as usize,
            cpu_shading: self.cpu_shading,
            precision: self.net_precision,
            tiles: self.net_tiles,
            traced_bounces: self.traced_bounces,
            query_every: self.query_every,
        }
    }
}
