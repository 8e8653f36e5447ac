//! Matching an ONNX graph, node by node, against the RPNN architecture (see the parent module):
//! the symbolic value of each graph value, the dense layers taken from the initializers, and
//! the block / head / sky-head structure assembled from them.

use std::collections::HashMap;

use onnx_protobuf::{NodeProto, TensorProto};

use super::{Block, Dense, Rpnn};

/// What a graph value is, symbolically.
#[derive(Debug, Clone)]
pub(super) enum Sym {
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

pub(super) struct Matcher<'a> {
    pub(super) tensors: HashMap<&'a str, &'a TensorProto>,
    pub(super) values: HashMap<String, Sym>,
    pub(super) input: &'a str,
    pub(super) denses: Vec<Dense>,
}

pub(super) fn floats(t: &TensorProto) -> Result<Vec<f32>, String> {
    if t.data_type != 1 {
        return Err(format!(
            "tensor `{}`: data type {} is not float32",
            t.name, t.data_type
        ));
    }
    // Each dimension at least 1 and the whole within MAX_VALUES: a crafted shape (negative,
    // zero or 2⁴⁰ wide with no data) must not reach an allocation or an index.
    let mut n: i64 = 1;
    for &d in &t.dims {
        n = match n.checked_mul(d) {
            Some(m) if d >= 1 && m <= MAX_VALUES => m,
            _ => {
                return Err(format!(
                    "tensor `{}`: shape {:?} is not a weight's (each dimension 1 or more, at \
                     most {MAX_VALUES} values in all)",
                    t.name, t.dims
                ));
            }
        };
    }
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

/// The most values one weight tensor may hold: 2²⁶ (256 MB of float32), 149× a layer reading
/// the whole descriptor at width 200 (2 251 × 200; the shipped models' largest matrices are a
/// block's 226 × 200).
const MAX_VALUES: i64 = 1 << 26;

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

    pub(super) fn node(&mut self, n: &NodeProto) -> Result<(), String> {
        let bad = |msg: &str| {
            format!(
                "node `{}` ({}): {msg}; this is not an RPNN graph",
                n.name, n.op_type
            )
        };
        check_attributes(n)?;
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
                // `end` may be ONNX's "to the end" (i64::MAX), never before `start` or negative
                // (counted from the end: the graph's slices are written with explicit columns).
                if axis != 1 && axis != -1 || step != 1 || start < 0 || end <= start {
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

/// The attributes each operator of the architecture may carry, with their types (the ONNX
/// operator schemas, default domain). ONNX Runtime refuses a node with any other attribute, an
/// attribute of another type, or another domain; so does this reader, so that the WGSL network
/// never runs a graph that ONNX Runtime would not. (A damaged name, `t+ansB` for `transB`, was
/// read as an absent attribute: a square layer silently transposed.)
pub(super) fn check_attributes(n: &NodeProto) -> Result<(), String> {
    use onnx_protobuf::attribute_proto::AttributeType as T;
    let node = || format!("node `{}` ({})", n.name, n.op_type);
    if !n.domain.is_empty() && n.domain != "ai.onnx" {
        return Err(format!(
            "{}: operator domain `{}`; the RPNN graph uses ONNX's own operators",
            node(),
            n.domain
        ));
    }
    let allowed: &[(&str, T)] = match n.op_type.as_str() {
        "Gemm" => &[
            ("alpha", T::FLOAT),
            ("beta", T::FLOAT),
            ("transA", T::INT),
            ("transB", T::INT),
        ],
        "Concat" => &[("axis", T::INT)],
        "Constant" => &[("value", T::TENSOR)],
        _ => &[],
    };
    for (i, a) in n.attribute.iter().enumerate() {
        let Some((_, want)) = allowed.iter().find(|(name, _)| *name == a.name) else {
            let names: Vec<&str> = allowed.iter().map(|(name, _)| *name).collect();
            return Err(format!(
                "{}: attribute `{}` is not one of the operator's ({})",
                node(),
                a.name,
                if names.is_empty() {
                    "it has none".to_string()
                } else {
                    names.join(", ")
                }
            ));
        };
        let have = a.type_.enum_value();
        if have != Ok(*want) {
            return Err(format!(
                "{}: attribute `{}` is of type {}, expected {want:?}",
                node(),
                a.name,
                match have {
                    Ok(t) => format!("{t:?}"),
                    Err(code) => format!("code {code}"),
                }
            ));
        }
        if n.attribute[..i].iter().any(|b| b.name == a.name) {
            return Err(format!("{}: attribute `{}` given twice", node(), a.name));
        }
    }
    Ok(())
}

fn not_rpnn(msg: &str) -> String {
    format!("the graph is not the RPNN architecture (Kallweit 2017 §4.3): {msg}")
}

/// Matches the output's expression against the architecture, innermost block first.
pub(super) fn structure(out: Sym, denses: Vec<Dense>) -> Result<Rpnn, String> {
    let mut arena: Vec<Option<Dense>> = denses.into_iter().map(Some).collect();
    let mut take = |i: usize| -> Result<Dense, String> {
        arena
            .get_mut(i)
            .and_then(Option::take)
            .ok_or_else(|| not_rpnn("a layer is used twice"))
    };
    // With a sky head: Concat(sun head, sky head); the sun head on the last block's output,
    // the sky head on one or more block outputs.
    let (out, sky) = match out {
        Sym::Out(mut parts) if parts.len() == 2 => {
            let sky = parts.pop().expect("two parts");
            (parts.pop().expect("two parts"), Some(sky))
        }
        Sym::Out(_) => return Err(not_rpnn("the output concatenates other than (sun, sky)")),
        o => (o, None),
    };
    // Sky head: a last Lin, then Relu(Lin(…)) layers down to a block output, or to the
    // concatenation of several block outputs (its first layer reads them all).
    let mut sky_head = Vec::new();
    let mut sky_sources: Vec<String> = Vec::new();
    if let Some(s) = sky {
        let Sym::Lin(mut src, d) = s else {
            return Err(not_rpnn("the sky head's last layer is not W x + b"));
        };
        sky_head.push(take(d)?);
        loop {
            if is_block(&src) {
                sky_sources.push(format!("{src:?}"));
                break;
            }
            match *src {
                Sym::Out(parts) if parts.iter().all(is_block) => {
                    sky_sources.extend(parts.iter().map(|p| format!("{p:?}")));
                    break;
                }
                Sym::Relu(inner) => match *inner {
                    Sym::Lin(s2, d) => {
                        sky_head.push(take(d)?);
                        src = s2;
                    }
                    _ => return Err(not_rpnn("a sky head layer is not ReLU(W x + b)")),
                },
                _ => return Err(not_rpnn("the sky head does not start at block outputs")),
            }
        }
        sky_head.reverse();
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
    // Blocks, last to first; each one's output, to find the sky head's sources.
    let mut blocks = Vec::new();
    let mut levels_seen = Vec::new();
    let mut outputs_seen = Vec::new();
    loop {
        if !sky_sources.is_empty() {
            outputs_seen.push(format!("{cur:?}"));
        }
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
    outputs_seen.reverse();
    let levels = blocks.len();
    // The blocks the sky head reads, in the order its first layer concatenates them.
    let sky_blocks = sky_sources
        .iter()
        .map(|s| {
            outputs_seen
                .iter()
                .position(|o| o == s)
                .ok_or_else(|| not_rpnn("the sky head reads a value that is no block output"))
        })
        .collect::<Result<Vec<_>, _>>()?;
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
    let mut sky_inputs = width * sky_blocks.len();
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
        sky_blocks,
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
