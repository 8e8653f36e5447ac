//! `render --method rpnn`: model lookup, backend choice, timings.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::ValueEnum;
use nimbus_scene::Scene;
use nimbus_trace::RenderOptions;

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum NetBackend {
    /// wgpu on a hardware GPU, ort when the only adapter is a software rasteriser (lavapipe
    /// runs the network ≈ 30× slower than ONNX Runtime on the same CPU).
    Auto,
    /// Descriptors and network in WGSL compute shaders (any GPU or lavapipe).
    Wgpu,
    /// Descriptors on the CPU, network in ONNX Runtime (PyPI onnxruntime, found at run time).
    Ort,
}

/// RPNN settings of `render --method rpnn`.
#[derive(clap::Args)]
pub(crate) struct RpnnArgs {
    /// RPNN: the ONNX model (default: the shipped models/rpnn-hg.onnx).
    #[arg(long)]
    pub(crate) model: Option<PathBuf>,
    /// RPNN: where the network runs.
    #[arg(long, value_enum, default_value = "auto")]
    pub(crate) backend: NetBackend,
    /// RPNN: sky directions per shading point and sample (network queries for sky light).
    #[arg(long, default_value_t = 4)]
    pub(crate) sky_dirs: u32,
    /// RPNN: refuse (instead of warning) when the scene's phase function or albedo differs
    /// from the model's training data.
    #[arg(long)]
    pub(crate) strict: bool,
}

/// `render --method rpnn`.
pub(crate) fn render_rpnn(
    s: &Scene,
    scene: &Path,
    opts: &RenderOptions,
    args: &RpnnArgs,
    timings: bool,
) -> Result<nimbus_rpnn::render::RpnnOutput> {
    use nimbus_rpnn::render::{Backend, RpnnOptions};
    if s.sky.is_some() && !(1..=1024).contains(&args.sky_dirs) {
        anyhow::bail!(
            "--sky-dirs must lie in 1..=1024 for a scene with a sky (0 would drop the sky's multiple scattering), got {}",
            args.sky_dirs
        );
    }
    let model_path = args
        .model
        .clone()
        .unwrap_or_else(nimbus_rpnn::model::default_model_path);
    let model = nimbus_rpnn::model::Rpnn::load(&model_path)?;
    let mismatches = [
        nimbus_rpnn::render::phase_mismatch(s, &model.phase),
        nimbus_rpnn::render::albedo_mismatch(s, model.albedo),
    ];
    for w in mismatches.into_iter().flatten() {
        if args.strict {
            anyhow::bail!(
                "{}: {} (--strict)",
                model_path.display(),
                w.trim_start_matches("warning: ")
            );
        }
        say!("{w}");
    }
    let pyr = nimbus_rpnn::Pyramid::for_rendering(&s.volume)
        .map_err(|e| anyhow::anyhow!("{}: {e}", s.source.display()))?;
    let gpu = match args.backend {
        NetBackend::Ort => None,
        NetBackend::Wgpu => Some(nimbus_gpu::Gpu::new()?),
        NetBackend::Auto => nimbus_gpu::Gpu::new().ok().filter(|g| !g.is_software()),
    };
    let mut backend = match &gpu {
        None => Backend::Ort(nimbus_rpnn::ort_backend::OrtModel::load(&model_path, 0)?),
        Some(gpu) => Backend::Wgpu(Box::new(nimbus_rpnn::gpu_mlp::GpuRpnn::new(
            gpu,
            &pyr,
            &model,
            nimbus_rpnn::gpu_mlp::DEFAULT_BATCH,
        )?)),
    };
    let ro = RpnnOptions {
        spp: opts.spp,
        seed: opts.seed,
        sky_dirs: args.sky_dirs,
    };
    let out = nimbus_rpnn::render::render(s, &pyr, &mut backend, &ro)?;
    let t = &out.times;
    say!(
        "{}: RPNN ({}, {}) {}x{} at {} spp in {:.2} s — {:.1} ms per spp, {} network queries",
        scene.display(),
        model_path.display(),
        backend.name(),
        s.camera.width,
        s.camera.height,
        opts.spp,
        t.total_ms / 1e3,
        t.total_ms / opts.spp as f64,
        t.queries
    );
    if timings {
        let n = opts.spp as f64;
        say!("  descriptor {:9.2} ms per spp", t.descriptor_ms / n);
        say!("  inference  {:9.2} ms per spp", t.inference_ms / n);
        say!("  rest       {:9.2} ms per spp", t.rest_ms / n);
    }
    Ok(out)
}
