//! The RPNN on the GPU (`shaders/rpnn_mlp.wgsl`): the weights read from the ONNX file
//! ([`crate::model::Rpnn`]) are evaluated by tiled matrix products in workgroup memory, one
//! dispatch per layer (2 per block + the head + the sky head, when the model has one: its
//! coefficients follow the sun head's in each output row). [`GpuRpnn`] records the descriptor pass
//! (`shaders/rpnn_descriptor.wgsl`) and the layers in one command buffer, so descriptors are
//! written and read on the GPU only; just the predictions come back.
//!
//! The CPU reference is [`crate::model::Rpnn::forward`]; tests require agreement to 1e-4 in
//! f32. [`Precision::F16`] stores the weights and the hidden activations as IEEE half floats
//! (packed pairs, `unpack2x16float`: every adapter reads them, `SHADER_F16` is not needed)
//! and accumulates in f32: half the memory traffic of the weights and activations; the
//! descriptors stay f32 and so do the outputs. Its agreement with ONNX Runtime is tested at a
//! stated tolerance (`tests/precision.rs`).

use bytemuck::{Pod, Zeroable};
use nimbus_gpu::timing::StageTimer;
use nimbus_gpu::{Gpu, GpuError, shaders};

use crate::descriptor::{Config, DESCRIPTOR_LEN};
use crate::gpu::GpuDescriptor;
use crate::model::{Dense, Rpnn};

/// `struct Layer` of the shader.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default, PartialEq)]
pub struct LayerParams {
    pub rows: u32,
    pub outputs: u32,
    pub ka: u32,
    pub kb: u32,
    pub a_stride: u32,
    pub a_offset: u32,
    pub a_gamma_col: u32,
    pub b_stride: u32,
    pub wa_offset: u32,
    pub wb_offset: u32,
    pub bias_offset: u32,
    pub out_stride: u32,
    pub residual: u32,
    pub res_stride: u32,
    pub relu: u32,
    /// First column of the output row this layer writes (the sky head's follow the sun's).
    pub out_offset: u32,
    /// Which buffers hold f16 pairs: bit 0 weights, 1 a, 2 b, 3 res, 4 out.
    pub flags: u32,
    pub _p0: u32,
    pub _p1: u32,
    pub _p2: u32,
}

/// How the network's weights and hidden activations are stored on the GPU (products
/// accumulate in f32 either way).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Precision {
    #[default]
    F32,
    /// IEEE half floats, two per word.
    F16,
}

/// Which kernel of `shaders/rpnn_mlp.wgsl` computes the layers (the same products; they differ
/// in how a workgroup's tile is split among its threads).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Tiles {
    /// `dense`: 64 queries × 64 outputs per workgroup, 4 × 4 per thread.
    Square,
    /// `dense_wide` (the default): 64 queries × 128 outputs per workgroup of 16 × 8 threads,
    /// 8 × 8 per thread, slices loaded along the inputs (coalesced on a GPU). On lavapipe a
    /// whole sample takes 25–31 % less time than with [`Tiles::Square`] (`BENCHMARKS.md`); no
    /// GPU has compared them yet (`bench/device.sh` step 2 does).
    #[default]
    Wide,
}

impl Precision {
    pub const ALL: [Precision; 2] = [Precision::F32, Precision::F16];

    /// The name on the command line (`--net-precision`).
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F16 => "f16",
        }
    }
}

impl std::str::FromStr for Precision {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| format!("unknown network precision `{s}` (expected f32 or f16)"))
    }
}

impl Tiles {
    pub const ALL: [Tiles; 2] = [Tiles::Square, Tiles::Wide];

    /// The name on the command line (`--net-tiles`): queries × outputs per workgroup.
    pub fn name(self) -> &'static str {
        match self {
            Tiles::Square => "64x64",
            Tiles::Wide => "64x128",
        }
    }

    /// Outputs per workgroup.
    pub fn outputs(self) -> u32 {
        match self {
            Tiles::Square => TILE_OUTPUTS,
            Tiles::Wide => nimbus_gpu::consts::MLP_WIDE_TILE_OUTPUTS,
        }
    }

    fn entry_point(self) -> &'static str {
        match self {
            Tiles::Square => "dense",
            Tiles::Wide => "dense_wide",
        }
    }
}

impl std::str::FromStr for Tiles {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|t| t.name() == s)
            .ok_or_else(|| format!("unknown network tiles `{s}` (expected 64x64 or 64x128)"))
    }
}

/// How the WGSL network is built.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct NetOptions {
    pub precision: Precision,
    pub tiles: Tiles,
}

impl From<Precision> for NetOptions {
    fn from(precision: Precision) -> Self {
        Self {
            precision,
            ..Default::default()
        }
    }
}

const F16_W: u32 = 1;
const F16_A: u32 = 2;
const F16_B: u32 = 4;
const F16_RES: u32 = 8;
const F16_OUT: u32 = 16;

const NO_GAMMA: u32 = u32::MAX;

/// Queries and outputs per workgroup of a layer (`shaders/rpnn_mlp.wgsl`).
pub use nimbus_gpu::consts::{MLP_TILE_OUTPUTS as TILE_OUTPUTS, MLP_TILE_ROWS as TILE_ROWS};

/// Where a layer reads its first input.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Src {
    Descriptor,
    Act(usize),
}

#[derive(Debug, Clone)]
struct Step {
    params: LayerParams,
    a: Src,
    b: Option<usize>,
    res: Option<usize>,
    /// Activation buffer written (`usize::MAX`: the output buffer).
    out: usize,
}

const OUT: usize = usize::MAX;

/// An RPNN uploaded to the GPU.
pub struct GpuMlp<'g> {
    gpu: &'g Gpu,
    pipeline: wgpu::ComputePipeline,
    tiles: Tiles,
    weights: wgpu::Buffer,
    steps: Vec<(Step, wgpu::Buffer)>,
    /// Values per query: the sun head's, then the sky head's coefficients.
    pub outputs: usize,
    /// The sun head's values per query (1 grey, 3 RGB).
    pub sun_outputs: usize,
    pub input_len: usize,
    /// Queries per dispatch (bounded by the storage-binding limit of the descriptor batch).
    pub max_batch: usize,
    acts: [wgpu::Buffer; 4],
    out: wgpu::Buffer,
    dummy: wgpu::Buffer,
    /// `row_limit` of a batch whose size the CPU knows: no limit.
    no_limit: wgpu::Buffer,
}

impl<'g> GpuMlp<'g> {
    pub fn new(gpu: &'g Gpu, model: &Rpnn, max_batch: usize) -> Result<Self, GpuError> {
        Self::with_precision(gpu, model, max_batch, Precision::F32)
    }

    /// [`GpuMlp::new`] storing the weights and hidden activations in `precision`.
    pub fn with_precision(
        gpu: &'g Gpu,
        model: &Rpnn,
        max_batch: usize,
        precision: Precision,
    ) -> Result<Self, GpuError> {
        Self::with_options(gpu, model, max_batch, precision.into())
    }

    /// [`GpuMlp::new`] with the storage precision and the kernel of `opts`.
    pub fn with_options(
        gpu: &'g Gpu,
        model: &Rpnn,
        max_batch: usize,
        opts: NetOptions,
    ) -> Result<Self, GpuError> {
        let NetOptions { precision, tiles } = opts;
        let limit = gpu
            .limits
            .max_storage_buffer_binding_size
            .min(gpu.limits.max_buffer_size) as usize;
        let stride = model
            .blocks
            .iter()
            .map(|b| b.v.outputs)
            .chain(model.head.iter().chain(&model.sky_head).map(|l| l.outputs))
            .max()
            .unwrap_or(1)
            // f16 rows start on whole words.
            .next_multiple_of(if precision == Precision::F16 { 2 } else { 1 });
        let max_batch = max_batch
            .min(limit / (DESCRIPTOR_LEN.max(model.input_len()) * 4))
            .min(limit / (stride * 4))
            .clamp(1, 65535 * TILE_ROWS as usize);
        let mut weights: Vec<f32> = Vec::new();
        let mut push = |d: &Dense| -> (u32, u32) {
            let w = weights.len() as u32;
            weights.extend_from_slice(&d.w);
            let b = weights.len() as u32;
            weights.extend_from_slice(&d.b);
            (w, b)
        };
        let (p, levels) = (model.points, model.levels);
        let last_block = model.blocks.len().saturating_sub(1);
        // The earlier block whose output the sky head reads beside the last one's (the
        // kernel's two inputs: at most one such block, read first).
        let keep = match model.sky_blocks.as_slice() {
            [] => None,
            [b] if *b == last_block => None,
            [e, b] if *b == last_block && *e < last_block => Some(*e),
            other => {
                return Err(GpuError::Unsupported(format!(
                    "the WGSL network's sky head reads the last block's output, or one earlier block's and then the last's; this model's reads blocks {other:?} (ONNX Runtime runs it: --backend ort)"
                )));
            }
        };
        let mut steps: Vec<Step> = Vec::new();
        // Activations: 0 and 1 alternate as o_k, 2 holds F1; after the blocks the sky head
        // alternates between 2 and 3 (reading the trunk first), then the sun head between 0
        // and 1. With a kept block (`keep`) its output stays where it was written and the
        // blocks after it alternate between the other of 0 and 1 and 3; the sky head's hidden
        // layers then use 2 and the one buffer left.
        let mut prev: Option<usize> = None;
        let mut pair = [0, 1];
        let mut kept: Option<usize> = None;
        for (k, b) in model.blocks.iter().enumerate() {
            let (wv, bv) = push(&b.v);
            let w1 = b.w1.as_ref().map(&mut push);
            let (ww2, bw2) = push(&b.w2);
            steps.push(Step {
                params: LayerParams {
                    outputs: b.v.outputs as u32,
                    ka: (p + 1) as u32,
                    kb: w1.map_or(0, |_| b.w1.as_ref().unwrap().inputs as u32),
                    a_stride: model.input_len() as u32,
                    a_offset: (k * p) as u32,
                    a_gamma_col: (levels * p) as u32,
                    b_stride: stride as u32,
                    wa_offset: wv,
                    wb_offset: w1.map_or(0, |w| w.0),
                    bias_offset: bv,
                    out_stride: stride as u32,
                    relu: 1,
                    ..Default::default()
                },
                a: Src::Descriptor,
                b: w1.and(prev),
                res: None,
                out: 2,
            });
            let next = if prev == Some(pair[0]) {
                pair[1]
            } else {
                pair[0]
            };
            steps.push(Step {
                params: LayerParams {
                    outputs: b.w2.outputs as u32,
                    ka: b.w2.inputs as u32,
                    a_stride: stride as u32,
                    a_gamma_col: NO_GAMMA,
                    wa_offset: ww2,
                    bias_offset: bw2,
                    out_stride: stride as u32,
                    residual: prev.is_some() as u32,
                    res_stride: stride as u32,
                    relu: 1,
                    ..Default::default()
                },
                a: Src::Act(2),
                b: None,
                res: prev,
                out: next,
            });
            prev = Some(next);
            if keep == Some(k) {
                kept = Some(next);
                pair = [1 - next, 3];
            }
        }
        let trunk = prev.expect("at least one block");
        let total = model.outputs_per_query() as u32;
        // A chain of dense layers from the trunk: hidden outputs alternate between the buffers
        // `bufs`, the last writes its columns from `first_col` of the output rows. With
        // `first` (a kept block's buffer) the first layer reads (o_kept, o_trunk): W_a o_kept +
        // W_b o_trunk + b, W split by its input columns (the kernel's two inputs).
        let width = model.width;
        let mut chain = |layers: &[Dense],
                         bufs: [usize; 2],
                         first_col: u32,
                         relu_last: bool,
                         first: Option<usize>| {
            let mut cur = trunk;
            for (i, l) in layers.iter().enumerate() {
                let (w, b, wb, ka, kb, src_b) = match (i, first) {
                    (0, Some(x)) => {
                        // W's first `width` columns read o_kept (with the bias), the rest
                        // o_trunk.
                        let cols = |c: std::ops::Range<usize>, b: Vec<f32>| Dense {
                            inputs: c.len(),
                            outputs: l.outputs,
                            w: l.w
                                .chunks_exact(l.inputs)
                                .flat_map(|row| row[c.clone()].iter().copied())
                                .collect(),
                            b,
                        };
                        let (wa, bias) = push(&cols(0..width, l.b.clone()));
                        let (wb, _) = push(&cols(width..2 * width, Vec::new()));
                        cur = x;
                        let k = width as u32;
                        (wa, bias, wb, k, k, Some(trunk))
                    }
                    _ => {
                        let (w, b) = push(l);
                        (w, b, 0, l.inputs as u32, 0, None)
                    }
                };
                let last = i + 1 == layers.len();
                let next = if last {
                    OUT
                } else if cur == bufs[0] {
                    bufs[1]
                } else {
                    bufs[0]
                };
                steps.push(Step {
                    params: LayerParams {
                        outputs: l.outputs as u32,
                        ka,
                        kb,
                        a_stride: stride as u32,
                        a_gamma_col: NO_GAMMA,
                        b_stride: stride as u32,
                        wa_offset: w,
                        wb_offset: wb,
                        bias_offset: b,
                        out_stride: if last { total } else { stride as u32 },
                        out_offset: if last { first_col } else { 0 },
                        relu: (relu_last || !last) as u32,
                        ..Default::default()
                    },
                    a: Src::Act(cur),
                    b: src_b,
                    res: None,
                    out: next,
                });
                cur = next;
            }
        };
        // The sky head first (its hidden layers in 2 and 3, so the trunk stays readable), its
        // last layer linear; then the sun head's ReLU layers in 0 and 1.
        // With a kept block its output is the first layer's first input, the trunk's the
        // second; the hidden layers use 2 and the buffer neither holds.
        let sky_bufs = match kept {
            None => [2, 3],
            Some(x) => [
                2,
                [0, 1, 3]
                    .into_iter()
                    .find(|&i| i != x && i != trunk)
                    .expect("three buffers, two taken"),
            ],
        };
        chain(&model.sky_head, sky_bufs, model.outputs as u32, false, kept);
        chain(&model.head, [0, 1], 0, true, None);
        let n_sky = model.sky_head.len();
        // f16: the weights, and every activation buffer but the descriptors and the output.
        if precision == Precision::F16 {
            for st in &mut steps {
                let mut f = F16_W | F16_B | F16_RES;
                if st.a != Src::Descriptor {
                    f |= F16_A;
                }
                if st.out != OUT {
                    f |= F16_OUT;
                }
                st.params.flags = f;
            }
        }
        let words: Vec<u32> = match precision {
            Precision::F32 => weights.iter().map(|w| w.to_bits()).collect(),
            Precision::F16 => weights
                .chunks(2)
                .map(|p| {
                    let lo = half::f16::from_f32(p[0]).to_bits() as u32;
                    let hi = p
                        .get(1)
                        .map_or(0, |&v| half::f16::from_f32(v).to_bits() as u32);
                    lo | (hi << 16)
                })
                .collect(),
        };
        gpu.check_storage("the network weights", words.len() as u64 * 4)?;
        let act_bytes = match precision {
            Precision::F32 => (max_batch * stride * 4) as u64,
            Precision::F16 => (max_batch * stride * 2).next_multiple_of(4) as u64,
        };
        gpu.check_storage("an activation batch", act_bytes)?;
        let steps = steps
            .into_iter()
            .map(|s| {
                let u = gpu.uniform("rpnn layer", &s.params);
                (s, u)
            })
            .collect();
        Ok(Self {
            gpu,
            pipeline: gpu.pipeline(
                "rpnn mlp",
                &shaders::source("rpnn_mlp.wgsl"),
                tiles.entry_point(),
            ),
            tiles,
            weights: gpu.storage("rpnn weights", &words),
            steps,
            outputs: model.outputs_per_query(),
            sun_outputs: model.outputs,
            input_len: model.input_len(),
            max_batch,
            acts: [0, 1, 2, 3].map(|i| {
                // The fourth is the sky head's second buffer (its second hidden layer's
                // output: heads of three layers or more).
                let bytes = if i == 3 && n_sky < 3 && kept.is_none() {
                    4
                } else {
                    act_bytes
                };
                gpu.zeroed("rpnn activations", bytes)
            }),
            out: gpu.zeroed(
                "rpnn output",
                (max_batch * model.outputs_per_query() * 4) as u64,
            ),
            dummy: gpu.zeroed("rpnn unused input", 16),
            no_limit: gpu.storage("rpnn no row limit", &[u32::MAX]),
        })
    }

    /// Records the layer passes for `rows` ≤ `max_batch` descriptors in `desc` (rows of
    /// `input_len` floats); the predictions land in [`GpuMlp::output`]. With `row_limit`, the
    /// first u32 of that buffer, written by an earlier pass, lowers the row count on the GPU.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        desc: &wgpu::Buffer,
        rows: usize,
        row_limit: Option<&wgpu::Buffer>,
        timer: Option<&mut StageTimer>,
    ) {
        self.encode_with(enc, desc, rows, row_limit, None, timer)
    }

    /// Workgroups along x (output tiles of [`Tiles::outputs`]) of each layer's dispatch, in
    /// dispatch order: with [`GpuMlp::encode_with`]'s indirect arguments, a GPU pass writes
    /// (tiles, ⌈rows / [`TILE_ROWS`]⌉, 1) for each.
    pub fn layer_tiles(&self) -> Vec<u32> {
        self.steps
            .iter()
            .map(|(s, _)| s.params.outputs.div_ceil(self.tiles.outputs()))
            .collect()
    }

    /// [`GpuMlp::encode`], with the workgroup counts of layer k read from `indirect` at byte
    /// offset `base + 12 k` (see [`GpuMlp::layer_tiles`]) when given: a batch whose size only
    /// the GPU knows dispatches no empty row tiles.
    pub fn encode_with(
        &self,
        enc: &mut wgpu::CommandEncoder,
        desc: &wgpu::Buffer,
        rows: usize,
        row_limit: Option<&wgpu::Buffer>,
        indirect: Option<(&wgpu::Buffer, u64)>,
        timer: Option<&mut StageTimer>,
    ) {
        let bound = self.bind(desc, rows, row_limit);
        self.encode_bound(enc, &bound, indirect, timer);
    }

    /// Sets every layer's row count to `rows` ≤ `max_batch` and makes the bind groups that read
    /// `desc` (and `row_limit`): what [`GpuMlp::encode_bound`] records, as often as wanted. The
    /// layer uniforms are this network's own, so one row count holds for everything recorded
    /// before the next submission: a caller with batches of several sizes in one command
    /// buffer binds the largest and lowers it with `row_limit`.
    pub fn bind(
        &self,
        desc: &wgpu::Buffer,
        rows: usize,
        row_limit: Option<&wgpu::Buffer>,
    ) -> BoundMlp {
        assert!(rows <= self.max_batch, "batch larger than max_batch");
        let buf = |i: usize| if i == OUT { &self.out } else { &self.acts[i] };
        let groups = self
            .steps
            .iter()
            .map(|(s, u)| {
                let params = LayerParams {
                    rows: rows as u32,
                    ..s.params
                };
                self.gpu
                    .queue
                    .write_buffer(u, 0, bytemuck::bytes_of(&params));
                let a = match s.a {
                    Src::Descriptor => desc,
                    Src::Act(i) => buf(i),
                };
                self.gpu.bind(
                    &self.pipeline,
                    &[
                        (0, u),
                        (1, &self.weights),
                        (2, a),
                        (3, s.b.map_or(&self.dummy, buf)),
                        (4, s.res.map_or(&self.dummy, buf)),
                        (5, buf(s.out)),
                        (6, row_limit.unwrap_or(&self.no_limit)),
                    ],
                )
            })
            .collect();
        BoundMlp { groups, rows }
    }

    /// Records the layer passes of `bound` ([`GpuMlp::bind`]); with `indirect` the workgroup
    /// counts of layer k are read at byte offset `base + 12 k` (see [`GpuMlp::layer_tiles`]).
    pub fn encode_bound(
        &self,
        enc: &mut wgpu::CommandEncoder,
        bound: &BoundMlp,
        indirect: Option<(&wgpu::Buffer, u64)>,
        mut timer: Option<&mut StageTimer>,
    ) {
        for (k, ((s, _), bind)) in self.steps.iter().zip(&bound.groups).enumerate() {
            let tw = timer.as_mut().and_then(|t| t.pass("inference"));
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("rpnn layer"),
                timestamp_writes: tw,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, bind, &[]);
            match indirect {
                Some((buf, base)) => pass.dispatch_workgroups_indirect(buf, base + 12 * k as u64),
                None => pass.dispatch_workgroups(
                    s.params.outputs.div_ceil(self.tiles.outputs()),
                    (bound.rows as u32).div_ceil(TILE_ROWS).max(1),
                    1,
                ),
            }
        }
    }

    /// The buffer holding the last batch's predictions (`rows × outputs`).
    pub fn output(&self) -> &wgpu::Buffer {
        &self.out
    }

    /// Predictions for `n` descriptors `x` (row-major), uploaded from the CPU (tests, and any
    /// caller with CPU descriptors).
    pub fn predict(&self, x: &[f32], n: usize) -> Result<Vec<f32>, GpuError> {
        let mut out = Vec::with_capacity(n * self.outputs);
        for lo in (0..n).step_by(self.max_batch) {
            let hi = (lo + self.max_batch).min(n);
            let desc = self
                .gpu
                .storage("descriptors", &x[lo * self.input_len..hi * self.input_len]);
            let mut enc = self.gpu.device.create_command_encoder(&Default::default());
            self.encode(&mut enc, &desc, hi - lo, None, None);
            self.gpu.queue.submit([enc.finish()]);
            let y: Vec<f32> = self.gpu.read(&self.out)?;
            out.extend_from_slice(&y[..(hi - lo) * self.outputs]);
        }
        Ok(out)
    }
}

/// The bind groups of one input for every layer ([`GpuMlp::bind`]).
pub struct BoundMlp {
    groups: Vec<wgpu::BindGroup>,
    rows: usize,
}

/// Descriptor construction and network on the GPU in one command buffer per batch.
pub struct GpuRpnn<'g> {
    gpu: &'g Gpu,
    pub desc: GpuDescriptor<'g>,
    pub mlp: GpuMlp<'g>,
    timer: StageTimer,
    /// GPU milliseconds of the last [`GpuRpnn::predict`]: (descriptor, inference); zero without
    /// timestamp support.
    pub last_ms: (f64, f64),
}

/// Network queries per GPU dispatch that the renderers ask for (the CLI, the evaluation and the
/// viewer alike); [`GpuMlp::new`] lowers it to what the adapter's storage-binding limit holds
/// (2¹⁶ descriptors of 2 251 floats are 590 MB).
pub const DEFAULT_BATCH: usize = 1 << 16;

impl<'g> GpuRpnn<'g> {
    pub fn new(
        gpu: &'g Gpu,
        pyr: &crate::pyramid::Pyramid,
        model: &Rpnn,
        max_batch: usize,
    ) -> Result<Self, GpuError> {
        Self::with_precision(gpu, pyr, model, max_batch, Precision::F32)
    }

    /// [`GpuRpnn::new`] with the network stored in `precision`.
    pub fn with_precision(
        gpu: &'g Gpu,
        pyr: &crate::pyramid::Pyramid,
        model: &Rpnn,
        max_batch: usize,
        precision: Precision,
    ) -> Result<Self, GpuError> {
        Self::with_options(gpu, pyr, model, max_batch, precision.into())
    }

    /// [`GpuRpnn::new`] with the network built as `opts` says.
    pub fn with_options(
        gpu: &'g Gpu,
        pyr: &crate::pyramid::Pyramid,
        model: &Rpnn,
        max_batch: usize,
        opts: NetOptions,
    ) -> Result<Self, GpuError> {
        Ok(Self {
            gpu,
            desc: GpuDescriptor::new(gpu, pyr)?,
            mlp: GpuMlp::with_options(gpu, model, max_batch, opts)?,
            timer: StageTimer::new(gpu, 1 + 64),
            last_ms: (0.0, 0.0),
        })
    }

    /// Network predictions (`configs.len() × outputs`) for shading configurations.
    pub fn predict(&mut self, configs: &[Config]) -> Result<Vec<f32>, GpuError> {
        let mut out = Vec::with_capacity(configs.len() * self.mlp.outputs);
        self.last_ms = (0.0, 0.0);
        for chunk in configs.chunks(self.mlp.max_batch) {
            let mut enc = self.gpu.device.create_command_encoder(&Default::default());
            let desc = self
                .desc
                .encode(&mut enc, chunk, self.timer.pass("descriptor"))?;
            self.mlp
                .encode(&mut enc, &desc, chunk.len(), None, Some(&mut self.timer));
            self.timer.resolve(&mut enc);
            self.gpu.queue.submit([enc.finish()]);
            let y: Vec<f32> = self.gpu.read(self.mlp.output())?;
            out.extend_from_slice(&y[..chunk.len() * self.mlp.outputs]);
            for (name, ms) in self.timer.read(self.gpu) {
                match name {
                    "descriptor" => self.last_ms.0 += ms,
                    _ => self.last_ms.1 += ms,
                }
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layer_struct_matches_wgsl() {
        let (members, size) = shaders::struct_layout("rpnn_mlp.wgsl", "Layer");
        assert_eq!(size as usize, std::mem::size_of::<LayerParams>());
        let names = [
            "rows",
            "outputs",
            "ka",
            "kb",
            "a_stride",
            "a_offset",
            "a_gamma_col",
            "b_stride",
            "wa_offset",
            "wb_offset",
            "bias_offset",
            "out_stride",
            "residual",
            "res_stride",
            "relu",
            "out_offset",
            "flags",
            "_p0",
            "_p1",
            "_p2",
        ];
        for (i, (name, off)) in members.iter().enumerate() {
            assert_eq!(name, names[i]);
            assert_eq!(*off as usize, 4 * i);
        }
    }
}
