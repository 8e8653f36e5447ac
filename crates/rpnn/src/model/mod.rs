//! Reading a trained RPNN from its ONNX file (the only model format; written by
//! `training/train.py`, contract in `training/README.md`) and the CPU reference of its forward
//! pass, which the WGSL kernels are tested against.
//!
//! The graph is not executed generically: it is matched, node by node, against the architecture
//! of Kallweit 2017 §4.3 — for k = 1..K, z_k = Concat(Slice(x, level k), Slice(x, γ)),
//! F1 = Relu(Gemm(z_k, V, b1) [+ MatMul(o_{k−1}, W1ᵀ)]), o_k = Relu(Gemm(F1, W2, b2) [+ o_{k−1}]),
//! then Relu(Gemm(·)) head layers — and the weights are taken from the initializers; a model with
//! a sky head (`training/train_sky.py`) has a second chain on the last block's output or on
//! Concat(o_a, o_b, …) of block outputs ([`Rpnn::sky_blocks`]), Relu(Gemm(·)) layers and a last
//! plain Gemm, and its output is Concat(sun head, sky head).
//! Anything
//! else (another op, another wiring, a shape mismatch) is refused with a message naming the
//! file and the node, so a model that is not an RPNN cannot be rendered silently wrong.

use std::collections::HashMap;
use std::path::Path;

use onnx_protobuf::{ModelProto, TensorProto};
use protobuf::Message;

mod graph;
use graph::{Matcher, structure};

/// The metadata key of an int8 copy that holds the sha256 of the f32 model it was made from
/// (`training/quantize.py`; [`crate::ort_backend::OrtModel::load_int8`] checks it).
pub const INT8_OF: &str = "nimbus.rpnn.int8_of";

/// The shipped model, `models/rpnn-hg.onnx`: looked up from the current folder and its parents,
/// then from the executable's folder and its parents; the plain relative path if not found (the
/// error then names it).
pub fn default_model_path() -> std::path::PathBuf {
    find_model("models/rpnn-hg.onnx")
}

/// The shipped model for a scene's phase function: `models/rpnn-mie.onnx` for a Lorenz–Mie
/// medium (`phase_desc` starting with `mie`) when it is there, else [`default_model_path`]
/// (HG g = 0.857; RPNN warns about the mismatch).
pub fn model_path_for(phase_desc: &str) -> std::path::PathBuf {
    if phase_desc.starts_with("mie") {
        let p = find_model("models/rpnn-mie.onnx");
        if p.is_file() {
            return p;
        }
    }
    default_model_path()
}

/// The shipped model with a sky head for a scene's phase function
/// (`models/rpnn-hg-sky.onnx`, HG g = 0.857), when it is there.
pub fn sky_model_path_for(phase_desc: &str) -> Option<std::path::PathBuf> {
    if phase_desc.starts_with("mie") {
        return None;
    }
    let p = find_model("models/rpnn-hg-sky.onnx");
    p.is_file().then_some(p)
}

/// The folder of the shipped models when they are installed elsewhere than `models/` above the
/// working directory or the executable (the Python package sets it to the models it ships).
pub const MODELS_ENV: &str = "NIMBUS_MODELS";

/// `rel`'s file in the folder [`MODELS_ENV`] names, else `rel` in the working directory or the
/// executable's folder, or one of their ancestors.
fn find_model(rel: &str) -> std::path::PathBuf {
    let rel = Path::new(rel);
    if let (Some(dir), Some(name)) = (std::env::var_os(MODELS_ENV), rel.file_name()) {
        let p = Path::new(&dir).join(name);
        if p.is_file() {
            return p;
        }
    }
    let starts = [std::env::current_dir().ok(), std::env::current_exe().ok()];
    for s in starts.into_iter().flatten() {
        for dir in s.ancestors() {
            let p = dir.join(rel);
            if p.is_file() {
                return p;
            }
        }
    }
    rel.to_path_buf()
}

/// Errors reading a model; every message names the file.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {msg}")]
pub struct ModelError {
    pub file: String,
    pub msg: String,
}

/// A dense layer: `out = W · in + b`, W row-major `[outputs][inputs]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Dense {
    pub inputs: usize,
    pub outputs: usize,
    pub w: Vec<f32>,
    pub b: Vec<f32>,
}

impl Dense {
    fn apply(&self, x: &[f32], out: &mut [f32]) {
        for (o, (row, b)) in out
            .iter_mut()
            .zip(self.w.chunks_exact(self.inputs).zip(&self.b))
        {
            let mut s = 0.0f32;
            for (w, v) in row.iter().zip(x) {
                s += w * v;
            }
            *o += s + b;
        }
    }
}

/// One residual block (§4.3).
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    /// V with bias b1, on z_k = (Σ^k, γ).
    pub v: Dense,
    /// W1 (no bias) on o_{k−1}; `None` for the first block (o_0 = 0).
    pub w1: Option<Dense>,
    /// W2 with bias b2.
    pub w2: Dense,
}

/// The weights of an RPNN and its shape.
#[derive(Debug, Clone, PartialEq)]
pub struct Rpnn {
    pub levels: usize,
    pub points: usize,
    pub width: usize,
    pub outputs: usize,
    pub blocks: Vec<Block>,
    pub head: Vec<Dense>,
    /// The sky head (`crate::sky`): ReLU layers and a last linear one from block outputs to
    /// the sky's transfer coefficients; empty for a sun-only model.
    pub sky_head: Vec<Dense>,
    /// The blocks (0-based) whose outputs the sky head's first layer reads, concatenated in
    /// this order: the last block alone for the first sky heads, an earlier one beside it for
    /// a head that sees more of the medium's structure
    /// (docs/experiments/2026-12-07-sky-head-size.md); empty without a sky head.
    pub sky_blocks: Vec<usize>,
    /// `nimbus.rpnn.phase` from the metadata (`hg`, `mie`, or `unknown`).
    pub phase: String,
    /// The single-scattering albedo of the training data: `nimbus.rpnn.albedo` from the
    /// metadata, else `data.albedo` of the model card (`<model>.json`) beside the file.
    pub albedo: Option<f64>,
}

impl Rpnn {
    pub fn input_len(&self) -> usize {
        self.levels * self.points + 1
    }

    pub fn parameters(&self) -> usize {
        let d = |l: &Dense| l.w.len() + l.b.len();
        self.blocks
            .iter()
            // W1 has no bias (its zero bias is an implementation detail).
            .map(|b| d(&b.v) + b.w1.as_ref().map_or(0, |w| w.w.len()) + d(&b.w2))
            .sum::<usize>()
            + self.head.iter().chain(&self.sky_head).map(d).sum::<usize>()
    }

    /// Coefficients of the sky's transfer the model predicts after its `outputs` (0: none).
    pub fn sky_coeffs(&self) -> usize {
        self.sky_head.last().map_or(0, |l| l.outputs)
    }

    /// The same network without its sky head (for a render with nothing to contract the sky
    /// head's transfer with: its sun column is unchanged).
    pub fn without_sky_head(&self) -> Self {
        Self {
            sky_head: Vec::new(),
            sky_blocks: Vec::new(),
            ..self.clone()
        }
    }

    /// Values per query: the sun head's outputs, then the sky head's.
    pub fn outputs_per_query(&self) -> usize {
        self.outputs + self.sky_coeffs()
    }

    /// Multiply-adds per query (2 FLOPs each).
    pub fn macs(&self) -> usize {
        let m = |l: &Dense| l.w.len();
        self.blocks
            .iter()
            .map(|b| m(&b.v) + b.w1.as_ref().map_or(0, m) + m(&b.w2))
            .sum::<usize>()
            + self.head.iter().chain(&self.sky_head).map(m).sum::<usize>()
    }

    /// CPU forward pass of one descriptor (f32, the reference of the GPU kernels).
    pub fn forward(&self, x: &[f32]) -> Vec<f32> {
        assert_eq!(x.len(), self.input_len(), "descriptor length");
        let (p, w) = (self.points, self.width);
        let gamma = x[self.levels * p];
        let mut z = vec![0.0f32; p + 1];
        let mut o = vec![0.0f32; w];
        let mut f1 = vec![0.0f32; w];
        // The sky head's input: the outputs of `sky_blocks`, concatenated in their order.
        let mut sky_in = vec![0.0f32; w * self.sky_blocks.len()];
        for (k, b) in self.blocks.iter().enumerate() {
            z[..p].copy_from_slice(&x[k * p..(k + 1) * p]);
            z[p] = gamma;
            f1.iter_mut().for_each(|v| *v = 0.0);
            b.v.apply(&z, &mut f1);
            if let Some(w1) = &b.w1 {
                w1.apply(&o, &mut f1);
            }
            f1.iter_mut().for_each(|v| *v = v.max(0.0));
            // o_k = ReLU(W2 F1 + b2 + o_{k−1}): start from o_{k−1} (zero for k = 1).
            let mut next = if k == 0 { vec![0.0; w] } else { o.clone() };
            b.w2.apply(&f1, &mut next);
            next.iter_mut().for_each(|v| *v = v.max(0.0));
            o = next;
            for (slot, _) in self.sky_blocks.iter().enumerate().filter(|(_, b)| **b == k) {
                sky_in[slot * w..(slot + 1) * w].copy_from_slice(&o);
            }
        }
        for l in &self.head {
            let mut next = vec![0.0; l.outputs];
            l.apply(&o, &mut next);
            next.iter_mut().for_each(|v| *v = v.max(0.0));
            o = next;
        }
        let mut s = sky_in;
        for (i, l) in self.sky_head.iter().enumerate() {
            let mut next = vec![0.0; l.outputs];
            l.apply(&s, &mut next);
            if i + 1 < self.sky_head.len() {
                next.iter_mut().for_each(|v| *v = v.max(0.0));
            }
            s = next;
        }
        if !self.sky_head.is_empty() {
            o.extend_from_slice(&s);
        }
        o
    }

    /// Checks the float tensors of an int8 copy (`training/quantize.py`): the scales, biases and
    /// f32 heads that ONNX Runtime reads unchecked. Each must be finite and within the bound
    /// of an f32 model's weights, and each quantization scale positive, so that a damaged copy
    /// is refused on load instead of rendering a wrong image. Errors without the file name.
    pub fn check_int8_tensors(bytes: &[u8]) -> Result<(), String> {
        let model = ModelProto::parse_from_bytes(bytes)
            .map_err(|e| format!("not a valid ONNX (protobuf) file: {e}"))?;
        let graph = model.graph.as_ref().ok_or("the model has no graph")?;
        let constants = graph
            .node
            .iter()
            .filter(|n| n.op_type == "Constant")
            .flat_map(|n| n.attribute.iter().filter_map(|a| a.t.as_ref()));
        let mut checked = 0;
        for t in graph.initializer.iter().chain(constants) {
            if t.data_type != 1 {
                continue; // int8/uint8 weights and zero points: every value is one
            }
            let v = graph::floats(t)?;
            if t.name.ends_with("scale")
                && let Some(i) = v.iter().position(|&x| x <= 0.0)
            {
                return Err(format!(
                    "tensor `{}`: scale {i} is {:e}, not positive",
                    t.name, v[i]
                ));
            }
            checked += 1;
        }
        if checked == 0 {
            return Err("no float tensors: not an int8 copy made by training/quantize.py".into());
        }
        Ok(())
    }

    /// Reads and checks an ONNX file.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let err = |msg: String| ModelError {
            file: path.display().to_string(),
            msg,
        };
        if matches!(std::fs::symlink_metadata(path), Err(e) if e.kind() == std::io::ErrorKind::NotFound)
        {
            return Err(err(
                "model not found (train one with training/train.py, or use the \
                            shipped models/rpnn-hg.onnx)"
                    .into(),
            ));
        }
        let bytes = read_bytes(path).map_err(err)?;
        let mut m = Self::from_bytes(&bytes).map_err(err)?;
        if m.albedo.is_none() {
            // Models exported before the albedo entered the metadata: read the card.
            m.albedo = m.read_card(&path.with_extension("json"))?;
        }
        Ok(m)
    }

    /// Reads the model card `card` (`<model>.json`, optional) and checks it as the metadata is
    /// checked: its `data.albedo` must be an albedo (a number in [0, 1]) and its shape
    /// (`architecture` or `config`: levels, points, width, outputs, head layers, sky
    /// coefficients) the graph's. Returns the card's albedo. Every error names the card and
    /// the field; a card that is there but not a readable file (a pipe, a device, a dangling
    /// or looping link, over the memory budget) is an error too, never skipped.
    fn read_card(&self, card: &Path) -> Result<Option<f64>, ModelError> {
        let err = |msg: String| ModelError {
            file: card.display().to_string(),
            msg,
        };
        let Some(text) = crate::read_optional_text(card).map_err(|e| err(without_path(e)))? else {
            return Ok(None);
        };
        let v: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| err(format!("not valid JSON ({e}): a model card")))?;
        if !v.is_object() {
            return Err(err("not a model card (a JSON object)".into()));
        }
        for section in ["architecture", "config"] {
            if let Some(c) = v.get(section)
                && let Err((key, msg)) = self.check_config(c)
            {
                return Err(err(format!("field `{section}.{key}`: {msg}")));
            }
        }
        match v.get("data").and_then(|d| d.get("albedo")) {
            None => Ok(None),
            Some(a) => match a.as_f64() {
                Some(x) if (0.0..=1.0).contains(&x) => Ok(Some(x)),
                _ => Err(err(format!(
                    "field `data.albedo` = {a}: not an albedo (a number in [0, 1])"
                ))),
            },
        }
    }

    /// The shape a model states of itself (the metadata's `nimbus.rpnn.config`, a card's
    /// `architecture` or `config`) against the graph's: `Err((key, why))` at the first
    /// difference. The five shape keys must be there; `sky_sh_coeffs` is checked when given.
    fn check_config(&self, v: &serde_json::Value) -> Result<(), (String, String)> {
        for (key, have) in [
            ("levels", self.levels),
            ("points", self.points),
            ("width", self.width),
            ("outputs", self.outputs),
            ("head_layers", self.head.len()),
        ] {
            if v.get(key).and_then(|x| x.as_u64()) != Some(have as u64) {
                return Err((
                    key.into(),
                    format!(
                        "says {key} = {}, the graph has {have}",
                        v.get(key).map_or("nothing".into(), |x| x.to_string())
                    ),
                ));
            }
        }
        if let Some(n) = v.get("sky_sh_coeffs")
            && n.as_u64() != Some(self.sky_coeffs() as u64)
        {
            return Err((
                "sky_sh_coeffs".into(),
                format!(
                    "says sky_sh_coeffs = {n}, the graph's sky head has {}",
                    self.sky_coeffs()
                ),
            ));
        }
        Ok(())
    }

    /// Parses ONNX bytes (errors without the file name).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, String> {
        let model = ModelProto::parse_from_bytes(bytes)
            .map_err(|e| format!("not a valid ONNX (protobuf) file: {e}"))?;
        let meta: HashMap<&str, &str> = model
            .metadata_props
            .iter()
            .map(|p| (p.key.as_str(), p.value.as_str()))
            .collect();
        if meta.contains_key(INT8_OF) {
            return Err(
                "an int8 copy (training/quantize.py), which only ONNX Runtime runs: pass \
                        the f32 model it was made from, with --backend ort-int8 to run this copy"
                    .into(),
            );
        }
        let graph = model.graph.as_ref().ok_or("the model has no graph")?;
        let mut tensors: HashMap<&str, &TensorProto> = graph
            .initializer
            .iter()
            .map(|t| (t.name.as_str(), t))
            .collect();
        for n in &graph.node {
            if n.op_type == "Constant" {
                graph::check_attributes(n)?;
                let t = n
                    .attribute
                    .iter()
                    .find(|a| a.name == "value")
                    .and_then(|a| a.t.as_ref())
                    .ok_or_else(|| format!("node `{}`: Constant without a tensor value", n.name))?;
                for o in &n.output {
                    tensors.insert(o.as_str(), t);
                }
            }
        }
        if graph.input.len() != 1 || graph.output.len() != 1 {
            return Err(format!(
                "expected one input and one output, found {} and {}",
                graph.input.len(),
                graph.output.len()
            ));
        }
        let input = graph.input[0].name.as_str();
        let mut m = Matcher {
            tensors,
            values: HashMap::new(),
            input,
            denses: Vec::new(),
        };
        for n in &graph.node {
            if n.op_type != "Constant" {
                m.node(n)?;
            }
        }
        let out = m
            .values
            .get(graph.output[0].name.as_str())
            .cloned()
            .ok_or_else(|| {
                format!(
                    "output `{}` is not computed by any node",
                    graph.output[0].name
                )
            })?;
        let mut rpnn = structure(out, m.denses)?;
        rpnn.phase = meta
            .get("nimbus.rpnn.phase")
            .map_or("unknown".into(), |s| s.to_string());
        // Stated, the albedo must be one (a model of albedo −3 or NaN is a broken file, not an
        // old one without the entry).
        rpnn.albedo = match meta.get("nimbus.rpnn.albedo") {
            None => None,
            Some(a) => match a.trim().parse::<f64>() {
                Ok(v) if (0.0..=1.0).contains(&v) => Some(v),
                _ => {
                    return Err(format!(
                        "metadata nimbus.rpnn.albedo = {a:?}: not an albedo (a number in [0, 1])"
                    ));
                }
            },
        };
        // The input's declared width, where it is a number, is the width the layers read: ONNX
        // Runtime refuses a graph whose declaration and weights disagree, so the WGSL network
        // must too.
        if let Some(w) = declared_width(&graph.input[0])
            && w != rpnn.input_len() as i64
        {
            return Err(format!(
                "input `{}` is declared {w} wide, the layers read {}",
                graph.input[0].name,
                rpnn.input_len()
            ));
        }
        // `nimbus.rpnn.sky` names the sky head's basis (train_sky.py writes `sh4`).
        if let Some(sky) = meta.get("nimbus.rpnn.sky") {
            let want = format!("sh{}", crate::sky::SH_DEGREE);
            if rpnn.sky_coeffs() == 0 || *sky != want {
                return Err(format!(
                    "metadata nimbus.rpnn.sky = {sky:?}, but the graph has {}: Nimbus reads \
                     `{want}`, a head of {} spherical-harmonic coefficients",
                    match rpnn.sky_coeffs() {
                        0 => "no sky head".to_string(),
                        n => format!("a sky head of {n} outputs"),
                    },
                    crate::sky::SH_COEFFS
                ));
            }
        }
        if let Some(cfg) = meta.get("nimbus.rpnn.config") {
            let v: serde_json::Value = serde_json::from_str(cfg)
                .map_err(|e| format!("metadata nimbus.rpnn.config: {e}"))?;
            rpnn.check_config(&v)
                .map_err(|(_, msg)| format!("metadata nimbus.rpnn.config {msg}"))?;
        }
        // The renderers contract the sky head's outputs with the sky's coefficients to degree
        // 4 (`crate::sky`); a head of another size would be misread or cut short.
        if !matches!(rpnn.sky_coeffs(), 0 | crate::sky::SH_COEFFS) {
            return Err(format!(
                "the sky head predicts {} values; Nimbus reads {} (spherical harmonics to \
                 degree {}: train_sky.py)",
                rpnn.sky_coeffs(),
                crate::sky::SH_COEFFS,
                crate::sky::SH_DEGREE
            ));
        }
        Ok(rpnn)
    }
}

/// A model file's bytes: a regular file whose bytes fit the memory budget, checked before it
/// is read whole (a 6 GiB file named as a model was once read to the end before the protobuf
/// parser refused it). Errors without the file name.
pub(crate) fn read_bytes(path: &Path) -> Result<Vec<u8>, String> {
    nimbus_scene::fsio::read(path).map_err(without_path)
}

/// A file error's message without the path it names (the caller's error names it).
fn without_path(e: nimbus_scene::Error) -> String {
    match e {
        nimbus_scene::Error::Io { err, .. } => err.to_string(),
        nimbus_scene::Error::Invalid { field, msg, .. } => format!("field `{field}`: {msg}"),
        nimbus_scene::Error::Parse { msg, .. } => msg,
    }
}

/// The second dimension of a graph input's declared shape, where it is a number.
fn declared_width(v: &onnx_protobuf::ValueInfoProto) -> Option<i64> {
    let t = v.type_.as_ref()?;
    if !t.has_tensor_type() {
        return None;
    }
    let d = t.tensor_type().shape.as_ref()?.dim.get(1)?;
    d.has_dim_value().then(|| d.dim_value())
}
