//! The ONNX Runtime backend: runs any exported model on the CPU through the `ort` crate.
//!
//! Nothing is downloaded at build time (`ort` with `load-dynamic`): the shared library is the one
//! of the PyPI `onnxruntime==1.31.x` wheel, found at run time, in this order:
//! 1. `ORT_DYLIB_PATH` (the library file);
//! 2. `training/.venv` (created by `training/setup.sh`) in the current folder or above it, or
//!    above the `nimbus` executable;
//! 3. the `onnxruntime` package of the `python3` in `PATH`.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Errors of the ONNX Runtime backend.
#[derive(Debug, thiserror::Error)]
pub enum OrtError {
    #[error(
        "ONNX Runtime not found: install it with `bash training/setup.sh` (or `pip install onnxruntime==1.31.1`), or set ORT_DYLIB_PATH to its libonnxruntime.so{0}"
    )]
    NotFound(String),
    #[error("ONNX Runtime ({path}): {msg}")]
    Load { path: String, msg: String },
    #[error("{file}: {msg}")]
    Model { file: String, msg: String },
    #[error("ONNX Runtime inference: {0}")]
    Run(String),
}

fn lib_in(dir: &Path) -> Option<PathBuf> {
    let capi = dir.join("onnxruntime/capi");
    let mut found: Vec<PathBuf> = std::fs::read_dir(&capi)
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("libonnxruntime.so") || n == "libonnxruntime.dylib")
        })
        .collect();
    found.sort();
    found.pop()
}

fn venv_site_packages(root: &Path) -> Vec<PathBuf> {
    let lib = root.join("training/.venv/lib");
    std::fs::read_dir(lib)
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .map(|e| e.path().join("site-packages"))
                .collect()
        })
        .unwrap_or_default()
}

/// Finds the ONNX Runtime shared library (see the module docs for the order).
pub fn find_onnxruntime() -> Result<PathBuf, OrtError> {
    if let Ok(p) = std::env::var("ORT_DYLIB_PATH") {
        let p = PathBuf::from(p);
        return if p.is_file() {
            Ok(p)
        } else {
            Err(OrtError::NotFound(format!(
                " (ORT_DYLIB_PATH={} is not a file)",
                p.display()
            )))
        };
    }
    let mut starts = Vec::new();
    if let Ok(cwd) = std::env::current_dir() {
        starts.push(cwd);
    }
    if let Ok(exe) = std::env::current_exe() {
        starts.push(exe);
    }
    for s in starts {
        for dir in s.ancestors() {
            for sp in venv_site_packages(dir) {
                if let Some(p) = lib_in(&sp) {
                    return Ok(p);
                }
            }
        }
    }
    let out = std::process::Command::new("python3")
        .args([
            "-c",
            "import onnxruntime, os; print(os.path.dirname(os.path.dirname(onnxruntime.__file__)))",
        ])
        .output();
    if let Ok(o) = out
        && o.status.success()
    {
        let dir = PathBuf::from(String::from_utf8_lossy(&o.stdout).trim());
        if let Some(p) = lib_in(&dir) {
            return Ok(p);
        }
    }
    Err(OrtError::NotFound(String::new()))
}

static ENV: OnceLock<Result<(ort::environment::Environment, PathBuf), String>> = OnceLock::new();

fn environment() -> Result<&'static (ort::environment::Environment, PathBuf), OrtError> {
    let r = ENV.get_or_init(|| {
        let path = find_onnxruntime().map_err(|e| e.to_string())?;
        let env = ort::init_from(&path)
            .map_err(|e| format!("ONNX Runtime ({}): {e}", path.display()))?
            .build()
            .map_err(|e| format!("ONNX Runtime ({}): {e}", path.display()))?;
        Ok((env, path))
    });
    match r {
        Ok(e) => Ok(e),
        Err(msg) => Err(OrtError::Load {
            path: "libonnxruntime".into(),
            msg: msg.clone(),
        }),
    }
}

/// The metadata key of an int8 copy that holds the sha256 of the f32 model it was made from.
pub const INT8_OF: &str = "nimbus.rpnn.int8_of";

/// Where the int8 copy of the model `path` sits: `x.onnx` → `x.int8.onnx` beside it.
pub fn int8_path_for(path: &Path) -> PathBuf {
    let mut name = path.file_stem().unwrap_or_default().to_os_string();
    name.push(".int8.onnx");
    path.with_file_name(name)
}

/// The metadata value `key` of an ONNX Runtime session (None when absent).
fn metadata(session: &ort::session::Session, key: &str) -> Result<Option<String>, String> {
    session
        .metadata()
        .map(|m| m.custom(key))
        .map_err(|e| format!("its metadata cannot be read: {e}"))
}

/// An ONNX model in an ONNX Runtime session.
pub struct OrtModel {
    session: ort::session::Session,
    input: String,
    output: String,
    /// Where the runtime library came from.
    pub library: PathBuf,
    /// Whether this is a model's int8 copy ([`OrtModel::load_int8`]).
    pub int8: bool,
}

impl OrtModel {
    /// Loads `path` with `threads` intra-op threads (0: ONNX Runtime's default).
    pub fn load(path: &Path, threads: usize) -> Result<Self, OrtError> {
        let (env, library) = environment()?;
        let library = library.clone();
        let err = |e: String| OrtError::Model {
            file: path.display().to_string(),
            msg: e,
        };
        if !path.is_file() {
            return Err(err("model not found".into()));
        }
        let mut b = ort::session::Session::builder(env).map_err(|e| err(e.to_string()))?;
        // Intra-op threads spin within a run and stop at its end: a renderer alternates the
        // network with descriptors and shading on the same cores, and threads spinning after
        // the run take them from rayon's. On 2 cores a 32-spp render at 128×72 took 29 ms per
        // spp so, 37 ms with spinning left on and 38 ms with it off (the network ≈ 40 % slower
        // then): BENCHMARKS.md, "The CPU sample".
        b = b
            .with_config_entry("session.force_spinning_stop", "1")
            .map_err(|e| err(e.to_string()))?;
        if threads > 0 {
            b = b
                .with_intra_threads(threads)
                .map_err(|e| err(e.to_string()))?;
        }
        let session = b.commit_from_file(path).map_err(|e| err(e.to_string()))?;
        let input = session
            .inputs()
            .first()
            .map(|i| i.name().to_string())
            .ok_or_else(|| err("the model has no input".into()))?;
        let output = session
            .outputs()
            .first()
            .map(|o| o.name().to_string())
            .ok_or_else(|| err("the model has no output".into()))?;
        Ok(Self {
            session,
            input,
            output,
            library,
            int8: false,
        })
    }

    /// Loads the int8 copy of the f32 model `f32_path` ([`int8_path_for`], made by
    /// `training/quantize.py`: weights int8 per output channel, the blocks' input activations
    /// u8 with one scale per batch, the heads f32; beyond the paper, see BENCHMARKS.md "The
    /// int8 network"). A missing copy, or a copy of another model (its metadata
    /// `nimbus.rpnn.int8_of` is not the sha256 of `f32_path`), is an error naming the file and
    /// the command that makes it.
    pub fn load_int8(f32_path: &Path, threads: usize) -> Result<Self, OrtError> {
        let path = int8_path_for(f32_path);
        let remake = format!(
            "make it with `training/.venv/bin/python training/quantize.py {}`",
            f32_path.display()
        );
        let err = |msg: String| OrtError::Model {
            file: path.display().to_string(),
            msg,
        };
        // `--model X.int8.onnx`: the copy given as the model (Rpnn::load refuses it by its
        // metadata first in a render).
        if f32_path.to_string_lossy().ends_with(".int8.onnx") {
            return Err(OrtError::Model {
                file: f32_path.display().to_string(),
                msg: "an int8 copy already: pass the f32 model it was made from \
                      (--backend ort-int8 runs the copy beside it)"
                    .into(),
            });
        }
        if !path.is_file() {
            return Err(err(format!(
                "no int8 copy of {} (--backend ort-int8): {remake}",
                f32_path.display()
            )));
        }
        let mut model = Self::load(&path, threads)?;
        model.int8 = true;
        // Streamed (the data sets' checksum): the model is never held whole for this.
        let want = crate::data::sha256_file(f32_path).map_err(|e| match e {
            crate::data::datagen::DatagenError::Set { what, msg } => {
                OrtError::Model { file: what, msg }
            }
            other => OrtError::Model {
                file: f32_path.display().to_string(),
                msg: other.to_string(),
            },
        })?;
        let got = metadata(&model.session, INT8_OF).map_err(err)?;
        match got {
            Some(g) if g == want => Ok(model),
            Some(g) => Err(err(format!(
                "made from another model (metadata {INT8_OF} = sha256 {g:.12}…), not from {} (sha256 {want:.12}…): {remake}",
                f32_path.display()
            ))),
            None => Err(err(format!(
                "no metadata {INT8_OF}: not an int8 copy made by training/quantize.py; {remake}"
            ))),
        }
    }

    /// Runs `n` rows of `x` (row-major, `x.len() / n` columns); returns the outputs row-major.
    pub fn predict(&mut self, x: &[f32], n: usize) -> Result<Vec<f32>, OrtError> {
        if n == 0 {
            return Ok(Vec::new());
        }
        let cols = x.len() / n;
        let t = ort::value::TensorRef::from_array_view(([n, cols], x))
            .map_err(|e| OrtError::Run(e.to_string()))?;
        let outputs = self
            .session
            .run(ort::inputs![self.input.as_str() => t])
            .map_err(|e| OrtError::Run(e.to_string()))?;
        let (_, y) = outputs[self.output.as_str()]
            .try_extract_tensor::<f32>()
            .map_err(|e| OrtError::Run(e.to_string()))?;
        Ok(y.to_vec())
    }
}
