//! Reading a trained RPNN from its ONNX file (the only model format; written by
//! `training/train.py`, contract in `training/README.md`) and the CPU reference of its forward
//! pass, which the WGSL kernels are tested against.
//!
//! The graph is not executed generically: it is matched, node by node, against the architecture
//! of Kallweit 2017 §4.3 — for k = 1..K, z_k = Concat(Slice(x, level k), Slice(x, γ)),
//! F1 = Relu(Gemm(z_k, V, b1) [+ MatMul(o_{k−1}, W1ᵀ)]), o_k = Relu(Gemm(F1, W2, b2) [+ o_{k−1}]),
//! then Relu(Gemm(·)) head layers — and the weights are taken from the initializers; a model with
//! a sky head (`training/train_sky.py`) has a second chain on the last block's output,
//! Relu(Gemm(·)) layers and a last plain Gemm, and its output is Concat(sun head, sky head).
//! Anything
//! else (another op, another wiring, a shape mismatch) is refused with a message naming the
//! file and the node, so a model that is not an RPNN cannot be rendered silently wrong.

use std::collections::HashMap;
use std::path::Path;

use onnx_protobuf::{ModelProto, NodeProto, TensorProto};
use protobuf::Message;

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

/// `rel` in the working directory or the executable's folder, or one of their ancestors.
fn find_model(rel: &str) -> std::path::PathBuf {
    let rel = Path::new(rel);
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
    /// The sky head (`crate::sky`): ReLU layers and a last linear one from the last block's
    /// output to the sky's transfer coefficients; empty for a sun-only model.
    pub sky_head: Vec<Dense>,
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
        }
        let trunk = o.clone();
        for l in &self.head {
            let mut next = vec![0.0; l.outputs];
            l.apply(&o, &mut next);
            next.iter_mut().for_each(|v| *v = v.max(0.0));
            o = next;
        }
        let mut s = trunk;
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

    /// Reads and checks an ONNX file.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let err = |msg: String| ModelError {
            file: path.display().to_string(),
            msg,
        };
        if !path.exists() {
            return Err(err(
                "model not found (train one with training/train.py, or use the \
                            shipped models/rpnn-hg.onnx)"
                    .into(),
            ));
        }
        // A regular file whose bytes fit the memory budget, before it is read whole (a 6 GiB
        // file named as a model was once read to the end before the protobuf parser refused it).
        nimbus_scene::memory::check_file(path, 1).map_err(|e| {
            let t = e.to_string();
            let prefix = format!("{}: ", path.display());
            err(t.strip_prefix(&prefix).unwrap_or(&t).to_string())
        })?;
        let bytes = std::fs::read(path).map_err(|e| err(e.to_string()))?;
        let mut m = Self::from_bytes(&bytes).map_err(err)?;
        if m.albedo.is_none() {
            // Models exported before the albedo entered the metadata: read the card.
            m.albedo = std::fs::read_to_string(path.with_extension("json"))
                .ok()
                .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
                .and_then(|v| v["data"]["albedo"].as_f64());
        }
        Ok(m)
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
        let graph = model.graph.as_ref().ok_or("the model has no graph")?;
        let mut tensors: HashMap<&str, &TensorProto> = graph
            .initializer
            .iter()
            .map(|t| (t.name.as_str(), t))
            .collect();
        for n in &graph.node {
            if n.op_type == "Constant" {
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
        rpnn.albedo = meta
            .get("nimbus.rpnn.albedo")
            .and_then(|a| a.parse::<f64>().ok())
            .filter(|a| a.is_finite());
        if let Some(cfg) = meta.get("nimbus.rpnn.config") {
            let v: serde_json::Value = serde_json::from_str(cfg)
                .map_err(|e| format!("metadata nimbus.rpnn.config: {e}"))?;
            for (key, have) in [
                ("levels", rpnn.levels),
                ("points", rpnn.points),
                ("width", rpnn.width),
                ("outputs", rpnn.outputs),
                ("head_layers", rpnn.head.len()),
            ] {
                if v.get(key).and_then(|x| x.as_u64()) != Some(have as u64) {
                    return Err(format!(
                        "metadata nimbus.rpnn.config says {key} = {}, the graph has {have}",
                        v.get(key).map_or("nothing".into(), |x| x.to_string())
                    ));
                }
            }
        }
        Ok(rpnn)
    }
}

/// What a graph value is, symbolically.
#[derive(Debug, Clone)]
enum Sym {
    Input,
    /// Columns [a, b) of the input.
    Cols(usize, usize),
    /// Concatenated column ranges.
    Cat(Vec<(usize, usize)>),
    /// `W · src + b` with the layer's index in [`Matcher::denses`] (weights are kept out of
    /// the tree: residual blocks share subtrees, so cloning weights would be exponential).
    Lin(Box<Sym>, usize),
    /// Computed values concatenated (the sun and sky heads' outputs).
    Out(Vec<Sym>),
    Add(Box<Sym>, Box<Sym>),
    Relu(Box<Sym>),
}

struct Matcher<'a> {
    tensors: HashMap<&'a str, &'a TensorProto>,
    values: HashMap<String, Sym>,
    input: &'a str,
    denses: Vec<Dense>,
}

fn floats(t: &TensorProto) -> Result<Vec<f32>, String> {
    if t.data_type != 1 {
        return Err(format!(
            "tensor `{}`: data type {} is not float32",
            t.name, t.data_type
        ));
    }
    let n: i64 = t.dims.iter().product();
    let v: Vec<f32> = if !t.raw_data.is_empty() {
        if !t.raw_data.len().is_multiple_of(4) {
            return Err(format!(
                "tensor `{}`: raw data is not a whole number of floats",
                t.name
            ));
        }
        t.raw_data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    } else {
        t.float_data.clone()
    };
    if v.len() as i64 != n {
        return Err(format!(
            "tensor `{}`: {} values for shape {:?}",
            t.name,
            v.len(),
            t.dims
        ));
    }
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(format!("tensor `{}`: value {i} is {}", t.name, v[i]));
    }
    if let Some(i) = v.iter().position(|x| x.abs() > MAX_WEIGHT) {
        return Err(format!(
            "tensor `{}`: value {i} is {:e}, beyond ±{MAX_WEIGHT:e}: not a trained network's \
             weight (the shipped models' are within ±1.2); its activations would overflow \
             float32 and the two inference backends would disagree",
            t.name, v[i]
        ));
    }
    Ok(v)
}

/// The largest weight or bias magnitude a model may hold. Trained weights are O(1) (the shipped
/// models': ≤ 1.16); a network of 23 layers with weights far beyond that drives its float32
/// activations to overflow, where ONNX Runtime and the WGSL MLP give different non-answers.
const MAX_WEIGHT: f32 = 1e3;

fn ints(t: &TensorProto) -> Result<Vec<i64>, String> {
    match t.data_type {
        7 if !t.raw_data.is_empty() => Ok(t
            .raw_data
            .chunks_exact(8)
            .map(|c| i64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect()),
        7 => Ok(t.int64_data.clone()),
        6 if !t.raw_data.is_empty() => Ok(t
            .raw_data
            .chunks_exact(4)
            .map(|c| i32::from_le_bytes(c.try_into().expect("4 bytes")) as i64)
            .collect()),
        6 => Ok(t.int32_data.iter().map(|&v| v as i64).collect()),
        d => Err(format!(
            "tensor `{}`: data type {d} is not an integer",
            t.name
        )),
    }
}

impl<'a> Matcher<'a> {
    fn value(&self, n: &NodeProto, i: usize) -> Result<Sym, String> {
        let name = n
            .input
            .get(i)
            .ok_or_else(|| format!("node `{}` ({}): input {i} missing", n.name, n.op_type))?;
        if name == self.input {
            return Ok(Sym::Input);
        }
        self.values.get(name).cloned().ok_or_else(|| {
            format!(
                "node `{}` ({}): input `{name}` is not a computed value",
                n.name, n.op_type
            )
        })
    }

    fn tensor(&self, n: &NodeProto, i: usize) -> Result<&'a TensorProto, String> {
        let name = n
            .input
            .get(i)
            .ok_or_else(|| format!("node `{}` ({}): input {i} missing", n.name, n.op_type))?;
        self.tensors.get(name.as_str()).copied().ok_or_else(|| {
            format!(
                "node `{}` ({}): `{name}` is not a constant",
                n.name, n.op_type
            )
        })
    }

    fn attr_i(n: &NodeProto, name: &str, default: i64) -> i64 {
        n.attribute
            .iter()
            .find(|a| a.name == name)
            .map_or(default, |a| a.i)
    }

    fn attr_f(n: &NodeProto, name: &str, default: f32) -> f32 {
        n.attribute
            .iter()
            .find(|a| a.name == name)
            .map_or(default, |a| a.f)
    }

    fn node(&mut self, n: &NodeProto) -> Result<(), String> {
        let bad = |msg: &str| {
            format!(
                "node `{}` ({}): {msg}; this is not an RPNN graph",
                n.name, n.op_type
            )
        };
        let sym = match n.op_type.as_str() {
            "Slice" => {
                if !matches!(self.value(n, 0)?, Sym::Input) {
                    return Err(bad("only slices of the input are expected"));
                }
                let one = |i: usize| -> Result<i64, String> {
                    let v = ints(self.tensor(n, i)?)?;
                    if v.len() != 1 {
                        return Err(bad("multi-axis slice"));
                    }
                    Ok(v[0])
                };
                let (start, end) = (one(1)?, one(2)?);
                let axis = if n.input.len() > 3 { one(3)? } else { 0 };
                let step = if n.input.len() > 4 { one(4)? } else { 1 };
                if axis != 1 && axis != -1 || step != 1 || start < 0 {
                    return Err(bad("expected a unit-step slice of columns"));
                }
                Sym::Cols(start as usize, end.min(1 << 40) as usize)
            }
            "Concat" => {
                if Self::attr_i(n, "axis", 0) != 1 && Self::attr_i(n, "axis", 0) != -1 {
                    return Err(bad("concatenation along another axis than the features"));
                }
                let values: Vec<Sym> = (0..n.input.len())
                    .map(|i| self.value(n, i))
                    .collect::<Result<_, _>>()?;
                if values.iter().all(|v| matches!(v, Sym::Cols(..))) {
                    Sym::Cat(
                        values
                            .into_iter()
                            .map(|v| match v {
                                Sym::Cols(a, b) => (a, b),
                                _ => unreachable!("checked above"),
                            })
                            .collect(),
                    )
                } else if values
                    .iter()
                    .any(|v| matches!(v, Sym::Cols(..) | Sym::Input))
                {
                    return Err(bad(
                        "input slices and computed values concatenated together",
                    ));
                } else {
                    Sym::Out(values)
                }
            }
            "Gemm" | "MatMul" => {
                let src = self.value(n, 0)?;
                let wt = self.tensor(n, 1)?;
                let w = floats(wt)?;
                if wt.dims.len() != 2 {
                    return Err(bad("weights must be a matrix"));
                }
                let (d0, d1) = (wt.dims[0] as usize, wt.dims[1] as usize);
                let gemm = n.op_type == "Gemm";
                if gemm
                    && (Self::attr_i(n, "transA", 0) != 0
                        || Self::attr_f(n, "alpha", 1.0) != 1.0
                        || Self::attr_f(n, "beta", 1.0) != 1.0)
                {
                    return Err(bad("Gemm with transA, alpha or beta is not supported"));
                }
                // Store W as [out][in].
                let trans_b = gemm && Self::attr_i(n, "transB", 0) == 1;
                let (outputs, inputs, w) = if trans_b {
                    (d0, d1, w)
                } else {
                    let mut t = vec![0.0; w.len()];
                    for i in 0..d0 {
                        for o in 0..d1 {
                            t[o * d0 + i] = w[i * d1 + o];
                        }
                    }
                    (d1, d0, t)
                };
                let b = if gemm && n.input.len() > 2 && !n.input[2].is_empty() {
                    let b = floats(self.tensor(n, 2)?)?;
                    if b.len() != outputs {
                        return Err(bad("bias length differs from the output count"));
                    }
                    b
                } else {
                    vec![0.0; outputs]
                };
                self.denses.push(Dense {
                    inputs,
                    outputs,
                    w,
                    b,
                });
                Sym::Lin(Box::new(src), self.denses.len() - 1)
            }
            "Add" => Sym::Add(Box::new(self.value(n, 0)?), Box::new(self.value(n, 1)?)),
            "Relu" => Sym::Relu(Box::new(self.value(n, 0)?)),
            _ => return Err(bad("operator not used by the RPNN architecture")),
        };
        for o in &n.output {
            self.values.insert(o.clone(), sym.clone());
        }
        Ok(())
    }
}

fn not_rpnn(msg: &str) -> String {
    format!("the graph is not the RPNN architecture (Kallweit 2017 §4.3): {msg}")
}

/// Matches the output's expression against the architecture, innermost block first.
fn structure(out: Sym, denses: Vec<Dense>) -> Result<Rpnn, String> {
    let mut arena: Vec<Option<Dense>> = denses.into_iter().map(Some).collect();
    let mut take = |i: usize| -> Result<Dense, String> {
        arena
            .get_mut(i)
            .and_then(Option::take)
            .ok_or_else(|| not_rpnn("a layer is used twice"))
    };
    // With a sky head: Concat(sun head, sky head), both on the last block's output.
    let (out, sky) = match out {
        Sym::Out(mut parts) if parts.len() == 2 => {
            let sky = parts.pop().expect("two parts");
            (parts.pop().expect("two parts"), Some(sky))
        }
        Sym::Out(_) => return Err(not_rpnn("the output concatenates other than (sun, sky)")),
        o => (o, None),
    };
    // Sky head: a last Lin, then Relu(Lin(…)) layers down to a block output.
    let mut sky_head = Vec::new();
    let mut sky_base = None;
    if let Some(s) = sky {
        let Sym::Lin(mut src, d) = s else {
            return Err(not_rpnn("the sky head's last layer is not W x + b"));
        };
        sky_head.push(take(d)?);
        while !is_block(&src) {
            match *src {
                Sym::Relu(inner) => match *inner {
                    Sym::Lin(s2, d) => {
                        sky_head.push(take(d)?);
                        src = s2;
                    }
                    _ => return Err(not_rpnn("a sky head layer is not ReLU(W x + b)")),
                },
                _ => return Err(not_rpnn("the sky head does not start at a block output")),
            }
        }
        sky_head.reverse();
        sky_base = Some(format!("{src:?}"));
    }
    // Head: Relu(Lin(…)) layers down to the last block's output.
    let mut head = Vec::new();
    let mut cur = out;
    while !is_block(&cur) {
        match cur {
            Sym::Relu(inner) => match *inner {
                Sym::Lin(src, d) => {
                    head.push(take(d)?);
                    cur = *src;
                }
                _ => return Err(not_rpnn("a head layer is not ReLU(W x + b)")),
            },
            _ => return Err(not_rpnn("the output is not a ReLU layer")),
        }
    }
    head.reverse();
    if head.is_empty() {
        return Err(not_rpnn("no fully connected head layers"));
    }
    if sky_base.is_some_and(|b| b != format!("{cur:?}")) {
        return Err(not_rpnn(
            "the sun and sky heads read different block outputs",
        ));
    }
    // Blocks, last to first.
    let mut blocks = Vec::new();
    let mut levels_seen = Vec::new();
    loop {
        // o_k = Relu(Add(Lin_W2(F1), o_{k−1})) or, for k = 1, Relu(Lin_W2(F1)).
        let Sym::Relu(inner) = cur else {
            return Err(not_rpnn("a block output is not a ReLU"));
        };
        let (f1, w2, prev) = match *inner {
            Sym::Add(a, b) => match (*a, *b) {
                (Sym::Lin(f1, w2), prev) | (prev, Sym::Lin(f1, w2)) => (f1, w2, Some(prev)),
                _ => return Err(not_rpnn("a residual sum without the W2 layer")),
            },
            Sym::Lin(f1, w2) => (f1, w2, None),
            _ => return Err(not_rpnn("unexpected block output")),
        };
        // F1 = Relu(Lin_V(z_k) [+ Lin_W1(o_{k−1})]).
        let Sym::Relu(a) = *f1 else {
            return Err(not_rpnn("F1 is not a ReLU"));
        };
        let (v, z, w1) = match *a {
            Sym::Lin(z, v) => (v, z, None),
            Sym::Add(x, y) => match (*x, *y) {
                (Sym::Lin(z, v), Sym::Lin(o, w1)) | (Sym::Lin(o, w1), Sym::Lin(z, v))
                    if matches!(*z, Sym::Cat(_)) =>
                {
                    (v, z, Some((o, w1)))
                }
                _ => return Err(not_rpnn("F1 is not V z_k + W1 o_(k-1)")),
            },
            _ => return Err(not_rpnn("F1 is not V z_k + W1 o_(k-1)")),
        };
        let Sym::Cat(parts) = *z else {
            return Err(not_rpnn("z_k is not a concatenation of input slices"));
        };
        if parts.len() != 2 {
            return Err(not_rpnn("z_k must be (Σ^k, γ)"));
        }
        levels_seen.push(parts);
        match (&prev, &w1) {
            (Some(p), Some((o, _))) => {
                if format!("{p:?}") != format!("{o:?}") {
                    return Err(not_rpnn("W1 and the residual read different values"));
                }
            }
            (None, None) => {}
            _ => {
                return Err(not_rpnn(
                    "a block has W1 without the residual or vice versa",
                ));
            }
        }
        blocks.push(Block {
            v: take(v)?,
            w1: w1.map(|(_, d)| take(d)).transpose()?,
            w2: take(w2)?,
        });
        match prev {
            Some(p) => cur = p,
            None => break,
        }
    }
    blocks.reverse();
    levels_seen.reverse();
    let levels = blocks.len();
    let width = blocks[0].w2.outputs;
    let points = levels_seen[0][0].1 - levels_seen[0][0].0;
    for (k, parts) in levels_seen.iter().enumerate() {
        let want = [
            (k * points, (k + 1) * points),
            (levels * points, levels * points + 1),
        ];
        if parts[0] != want[0] || parts[1].0 != want[1].0 || parts[1].1 < want[1].1 {
            return Err(not_rpnn(&format!(
                "block {} reads columns {:?}, expected level {} = {:?} and γ = column {}",
                k + 1,
                parts,
                k + 1,
                want[0],
                levels * points
            )));
        }
    }
    for (k, b) in blocks.iter().enumerate() {
        let ok = b.v.inputs == points + 1
            && b.v.outputs == width
            && b.w2.inputs == width
            && b.w2.outputs == width
            && b.w1
                .as_ref()
                .is_none_or(|w| w.inputs == width && w.outputs == width)
            && (k == 0) == b.w1.is_none();
        if !ok {
            return Err(not_rpnn(&format!(
                "block {} has inconsistent layer shapes",
                k + 1
            )));
        }
    }
    let mut inputs = width;
    for (i, l) in head.iter().enumerate() {
        if l.inputs != inputs {
            return Err(not_rpnn(&format!(
                "head layer {} reads {} values, expected {inputs}",
                i + 1,
                l.inputs
            )));
        }
        inputs = l.outputs;
    }
    let mut sky_inputs = width;
    for (i, l) in sky_head.iter().enumerate() {
        if l.inputs != sky_inputs {
            return Err(not_rpnn(&format!(
                "sky head layer {} reads {} values, expected {sky_inputs}",
                i + 1,
                l.inputs
            )));
        }
        sky_inputs = l.outputs;
    }
    Ok(Rpnn {
        levels,
        points,
        width,
        outputs: inputs,
        blocks,
        head,
        sky_head,
        phase: String::new(),
        albedo: None,
    })
}

/// Whether `s` is a block output (Relu of a residual sum or of the first block's W2 layer).
fn is_block(s: &Sym) -> bool {
    match s {
        Sym::Relu(inner) => match inner.as_ref() {
            Sym::Add(a, b) => matches!(**a, Sym::Lin(..)) || matches!(**b, Sym::Lin(..)),
            Sym::Lin(src, _) => {
                matches!(**src, Sym::Relu(ref f1) if matches!(**f1, Sym::Lin(ref z, _) if matches!(**z, Sym::Cat(_))))
            }
            _ => false,
        },
        _ => false,
    }
}
