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
use std::time::Instant;

use rayon::prelude::*;

pub use crate::model::INT8_OF;

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

/// How an [`OrtModel`] uses the CPU's cores.
///
/// A renderer's batches alternate with the descriptors that fill them. `Workers` runs one
/// single-threaded session per core, each on its own contiguous share of the batch, its
/// descriptors included, with nothing shared until the outputs are joined; `Pool` runs one
/// session whose intra-op threads meet at each operator, with the descriptors written by rayon's
/// threads. On 2 cores, pieces of 1 024 queries: 10.7–11.1 against 13.8–14.3 µs per query for
/// descriptors and network (`cargo run --release -p nimbus-rpnn --example ort_cores`;
/// docs/experiments/2026-12-07-rpnn-sample-rounds.md, "The CPU sample, third round").
///
/// With an f32 model the outputs do not depend on the split: equal to the bit with one session
/// or any number of workers and pieces (tested). An int8 copy ([`OrtModel::load_int8`]) scales
/// each layer's input per run, so its outputs depend on which queries share a run: its runs
/// are cut from the batch by the number of queries alone ([`OrtModel::predict_rows`]), never by
/// the number of workers, so an int8 image is the same on any number of cores (tested).
///
/// Each session holds the weights (5.2 MB for the paper's network) and a kept buffer of up to
/// `rows_per_run` rows (9 MB at 1 024), so memory grows with the number of workers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cores {
    /// One session whose intra-op pool has this many threads (0: ONNX Runtime's default).
    Pool(usize),
    /// This many single-threaded sessions, run side by side on rayon's threads (0: as many as
    /// rayon has).
    Workers(usize),
}

/// The most sessions [`Cores::Workers`] may ask for.
pub const MAX_WORKERS: usize = 1024;

impl From<usize> for Cores {
    fn from(threads: usize) -> Self {
        Cores::Pool(threads)
    }
}

/// Queries per run of a session in [`OrtModel::predict_rows`]: the rows of a batch are made and
/// run this many at a time, so that a piece's descriptors (9 KB a query) and activations stay
/// in the caches and the kept buffers stay small. A whole 1280×720 frame in
/// one run (≈ 195 000 queries, 1.75 GB of descriptors) took 6.6 µs per query for the
/// descriptors and 15–27 for the network; in pieces of 1 024 on two workers, 3.5 and 7.2–7.6
/// (docs/experiments/2026-12-07-rpnn-sample-rounds.md, "The CPU sample, third round"). Between 128 and 2 048 the time hardly
/// changes.
pub const ROWS_PER_RUN: usize = 1024;

/// [`ROWS_PER_RUN`] of an int8 copy. Its runs are cut by the batch's size alone, in pairs
/// (2 ⌈n / 512⌉ pieces), so that two workers always get equal shares, however small the batch:
/// the bench suite's samples hold 200–1 300 queries. `cargo run --release -p nimbus-rpnn
/// --example int8_split`, two workers (2-core Intel Xeon, the int8 sky model), 10th percentile
/// of µs per query at 200 / 648 / 1 297 / 12 175 queries: cut per worker as an f32 model's
/// batch 12.7–13.0 / 11.8–12.1 / 11.9–12.0 / 12.6–12.9, by n in pairs 12.8–12.9 / 12.2–12.3 /
/// 12.0–12.2 / 12.1–12.3. (Unpaired, ⌈n / 256⌉ pieces, 200 queries were one run on one worker,
/// at twice the time.) On more cores a batch keeps at most 2 ⌈n / 512⌉ of them busy.
pub const INT8_ROWS_PER_RUN: usize = 256;

/// Milliseconds of one [`OrtModel::predict_rows`] call: making the rows and running the
/// network. With [`Cores::Workers`] the call's wall time is split between the two in the
/// proportion of the workers' summed times, so the two add up to the call's time (a worker
/// that waits for the other is counted in both, not left to a renderer's "rest").
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RowTimes {
    pub rows_ms: f64,
    pub network_ms: f64,
}

/// An ONNX model in ONNX Runtime sessions (one, or one per worker: [`Cores`]).
pub struct OrtModel {
    sessions: Vec<ort::session::Session>,
    /// Each session's rows, kept across calls.
    buffers: Vec<Vec<f32>>,
    input: String,
    output: String,
    /// Where the runtime library came from.
    pub library: PathBuf,
    /// The model file the sessions run (for errors about its answers).
    pub model: PathBuf,
    /// Whether this is a model's int8 copy ([`OrtModel::load_int8`]).
    pub int8: bool,
    /// The most queries per run of a session in [`OrtModel::predict_rows`] ([`ROWS_PER_RUN`],
    /// [`INT8_ROWS_PER_RUN`] for an int8 copy; 0 counts as 1).
    pub rows_per_run: usize,
}

fn session(
    env: &ort::environment::Environment,
    model: &[u8],
    intra: usize,
) -> Result<ort::session::Session, String> {
    let mut b = ort::session::Session::builder(env).map_err(|e| e.to_string())?;
    // With more than one intra-op thread ([`Cores::Pool`]; a worker's session has none to
    // spin): intra-op threads spin within a run and stop at its end. A renderer alternates the
    // network with descriptors and shading on the same cores, and threads spinning after
    // the run take them from rayon's. On 2 cores a 32-spp render at 128×72 took 29 ms per
    // spp so, 37 ms with spinning left on and 38 ms with it off (the network ≈ 40 % slower
    // then): docs/experiments/2026-12-07-rpnn-sample-rounds.md, "The CPU sample".
    b = b
        .with_config_entry("session.force_spinning_stop", "1")
        .map_err(|e| e.to_string())?;
    if intra > 0 {
        b = b.with_intra_threads(intra).map_err(|e| e.to_string())?;
    }
    b.commit_from_memory(model).map_err(|e| e.to_string())
}

impl OrtModel {
    /// Loads `path` to run on `cores`: a number is one session with that many intra-op
    /// threads (0: ONNX Runtime's default), [`Cores::Workers`] one session per worker.
    pub fn load(path: &Path, cores: impl Into<Cores>) -> Result<Self, OrtError> {
        Self::load_checked(path, cores.into(), |_| Ok(()))
    }

    /// [`OrtModel::load`], with `check` run on the first session before the others are made.
    fn load_checked(
        path: &Path,
        cores: Cores,
        check: impl FnOnce(&ort::session::Session) -> Result<(), OrtError>,
    ) -> Result<Self, OrtError> {
        let (env, library) = environment()?;
        let library = library.clone();
        let err = |e: String| OrtError::Model {
            file: path.display().to_string(),
            msg: e,
        };
        if matches!(std::fs::symlink_metadata(path), Err(e) if e.kind() == std::io::ErrorKind::NotFound)
        {
            return Err(err("model not found".into()));
        }
        // Read once, as every input is (a regular file within the memory budget: never a
        // pipe waited on or a device read without end), and given to every session.
        let model = crate::model::read_bytes(path).map_err(err)?;
        let (count, intra) = match cores {
            Cores::Pool(t) => (1, t),
            Cores::Workers(0) => (rayon::current_num_threads().max(1), 1),
            Cores::Workers(w) if w <= MAX_WORKERS => (w, 1),
            Cores::Workers(w) => {
                return Err(err(format!(
                    "{w} worker sessions asked for, at most {MAX_WORKERS} (each holds the weights)"
                )));
            }
        };
        let first = session(env, &model, intra).map_err(err)?;
        check(&first)?;
        let rest = (1..count)
            .into_par_iter()
            .map(|_| session(env, &model, intra))
            .collect::<Result<Vec<_>, _>>()
            .map_err(err)?;
        let mut sessions = vec![first];
        sessions.extend(rest);
        let input = sessions[0]
            .inputs()
            .first()
            .map(|i| i.name().to_string())
            .ok_or_else(|| err("the model has no input".into()))?;
        let output = sessions[0]
            .outputs()
            .first()
            .map(|o| o.name().to_string())
            .ok_or_else(|| err("the model has no output".into()))?;
        Ok(Self {
            buffers: vec![Vec::new(); sessions.len()],
            sessions,
            input,
            output,
            library,
            model: path.to_path_buf(),
            int8: false,
            rows_per_run: ROWS_PER_RUN,
        })
    }

    /// The sessions that run side by side: 1, or the workers of [`Cores::Workers`].
    pub fn workers(&self) -> usize {
        self.sessions.len()
    }

    /// Loads the int8 copy of the f32 model `f32_path` ([`int8_path_for`], made by
    /// `training/quantize.py`: weights int8 per output channel, the blocks' input activations
    /// u8 with one scale per run of a session (at most [`INT8_ROWS_PER_RUN`] queries, cut by the
    /// batch's size alone, see [`Cores`]), the heads f32; beyond the paper, see
    /// docs/experiments/2026-12-07-rpnn-sample-rounds.md, "The int8 network"). A missing copy, or a copy of another model (its metadata
    /// `nimbus.rpnn.int8_of` is not the sha256 of `f32_path`), is an error naming the file and
    /// the command that makes it.
    pub fn load_int8(f32_path: &Path, cores: impl Into<Cores>) -> Result<Self, OrtError> {
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
        // Its own float tensors (scales, biases, the f32 heads), which ONNX Runtime runs
        // unchecked: a damaged copy would render a wrong image without a word.
        let bytes = crate::model::read_bytes(&path).map_err(err)?;
        crate::model::Rpnn::check_int8_tensors(&bytes).map_err(err)?;
        drop(bytes);
        // Checked on the first session, before the workers' sessions are made.
        let check = |first: &ort::session::Session| match metadata(first, INT8_OF).map_err(err)? {
            Some(g) if g == want => Ok(()),
            Some(g) => Err(err(format!(
                "made from another model (metadata {INT8_OF} = sha256 {g:.12}…), not from {} (sha256 {want:.12}…): {remake}",
                f32_path.display()
            ))),
            None => Err(err(format!(
                "no metadata {INT8_OF}: not an int8 copy made by training/quantize.py; {remake}"
            ))),
        };
        let mut model = Self::load_checked(&path, cores.into(), check)?;
        model.int8 = true;
        model.rows_per_run = INT8_ROWS_PER_RUN;
        Ok(model)
    }

    /// Runs `n` rows of `x` (row-major, `x.len() / n` columns) through the first session;
    /// returns the outputs row-major.
    pub fn predict(&mut self, x: &[f32], n: usize) -> Result<Vec<f32>, OrtError> {
        if n == 0 {
            return Ok(Vec::new());
        }
        run(&mut self.sessions[0], &self.input, &self.output, x, n)
    }

    /// Runs `n` queries of `cols` inputs each whose rows `fill(i, row)` writes (`row` has
    /// `cols` values, all to be written), in runs (pieces) of at most
    /// [`OrtModel::rows_per_run`]: with one session the rows of a piece are written in parallel
    /// on rayon's threads and the session's own threads run it; with workers
    /// ([`Cores::Workers`]) worker w takes the w-th contiguous share of the pieces and writes
    /// and runs them alone. Returns the outputs row-major (query order) and the time of each
    /// part.
    ///
    /// The pieces are equal to within one query. An f32 model's are cut per worker (each
    /// worker's share of the queries, in as few pieces as fit): its outputs do not depend on
    /// the split. An int8 copy's are cut from the whole batch by `n` alone, in pairs:
    /// 2 ⌈n / (2 rows_per_run)⌉ of them, which the workers share out. The same queries share a
    /// run, so the same answers come back, whatever the number of workers or threads
    /// ([`Cores`]).
    pub fn predict_rows<F>(
        &mut self,
        n: usize,
        cols: usize,
        fill: F,
    ) -> Result<(Vec<f32>, RowTimes), OrtError>
    where
        F: Fn(usize, &mut [f32]) + Sync,
    {
        if n == 0 {
            return Ok((Vec::new(), RowTimes::default()));
        }
        if cols == 0 {
            return Err(OrtError::Run(format!("{n} queries of no inputs")));
        }
        let (input, output) = (self.input.as_str(), self.output.as_str());
        let k = self.sessions.len();
        let most = self.rows_per_run.max(1);
        let share = Share {
            input,
            output,
            n,
            pieces: if self.int8 {
                // By n alone, in pairs: two workers (a 2-core machine) get equal shares.
                2 * n.div_ceil(most.saturating_mul(2))
            } else {
                // k shares of ⌈n / k⌉ or fewer, each in pieces of at most `most`; a multiple
                // of k, so that worker w's share starts at n w / k.
                k * n.div_ceil(k).div_ceil(most)
            },
            cols,
            // One session: rayon's threads write its rows; workers write their own.
            parallel: k == 1,
        };
        if share.parallel {
            return share.run(
                &mut self.sessions[0],
                &mut self.buffers[0],
                0..share.pieces,
                &fill,
            );
        }
        let p = share.pieces;
        let clock = Instant::now();
        let shares: Vec<_> = self
            .sessions
            .par_iter_mut()
            .zip(self.buffers.par_iter_mut())
            .enumerate()
            .map(|(w, (session, buf))| share.run(session, buf, p * w / k..p * (w + 1) / k, &fill))
            .collect::<Result<_, _>>()?;
        let wall = clock.elapsed().as_secs_f64() * 1e3;
        let mut y = Vec::with_capacity(shares.iter().map(|(p, _)| p.len()).sum());
        let (mut rows, mut network) = (0.0, 0.0);
        for (part, pt) in shares {
            y.extend_from_slice(&part);
            rows += pt.rows_ms;
            network += pt.network_ms;
        }
        let rows_share = if rows + network > 0.0 {
            rows / (rows + network)
        } else {
            0.0
        };
        let t = RowTimes {
            rows_ms: wall * rows_share,
            network_ms: wall * (1.0 - rows_share),
        };
        Ok((y, t))
    }
}

/// How one session runs its part of [`OrtModel::predict_rows`].
struct Share<'a> {
    input: &'a str,
    output: &'a str,
    /// Queries in the whole batch.
    n: usize,
    /// Runs the batch is cut into: piece j holds the queries n j / pieces .. n (j + 1) / pieces.
    pieces: usize,
    cols: usize,
    /// Rows written by rayon's threads, or by the calling one.
    parallel: bool,
}

impl Share<'_> {
    /// The pieces `pieces`, one run each, through `session` (rows in `buf`).
    fn run<F>(
        &self,
        session: &mut ort::session::Session,
        buf: &mut Vec<f32>,
        pieces: std::ops::Range<usize>,
        fill: F,
    ) -> Result<(Vec<f32>, RowTimes), OrtError>
    where
        F: Fn(usize, &mut [f32]) + Sync,
    {
        let cols = self.cols;
        let mut y = Vec::new();
        let mut t = RowTimes::default();
        // u128: n × pieces would overflow 32-bit sizes long before a frame is too large.
        let bound = |j: usize| (self.n as u128 * j as u128 / self.pieces as u128) as usize;
        for j in pieces {
            let (start, m) = (bound(j), bound(j + 1) - bound(j));
            if m == 0 {
                continue;
            }
            let clock = Instant::now();
            // The buffer only grows: a short last piece uses its front (no zeroing again).
            if buf.len() < m * cols {
                buf.resize(m * cols, 0.0);
            }
            let rows = &mut buf[..m * cols];
            if self.parallel {
                rows.par_chunks_mut(cols)
                    .enumerate()
                    .for_each(|(j, row)| fill(start + j, row));
            } else {
                for (j, row) in rows.chunks_mut(cols).enumerate() {
                    fill(start + j, row);
                }
            }
            t.rows_ms += clock.elapsed().as_secs_f64() * 1e3;
            let clock = Instant::now();
            y.extend_from_slice(&run(session, self.input, self.output, &buf[..m * cols], m)?);
            t.network_ms += clock.elapsed().as_secs_f64() * 1e3;
        }
        Ok((y, t))
    }
}

/// One run of `session` on `n` rows of `x`.
fn run(
    session: &mut ort::session::Session,
    input: &str,
    output: &str,
    x: &[f32],
    n: usize,
) -> Result<Vec<f32>, OrtError> {
    let cols = x.len() / n;
    let t = ort::value::TensorRef::from_array_view(([n, cols], x))
        .map_err(|e| OrtError::Run(e.to_string()))?;
    let outputs = session
        .run(ort::inputs![input => t])
        .map_err(|e| OrtError::Run(e.to_string()))?;
    let (_, y) = outputs[output]
        .try_extract_tensor::<f32>()
        .map_err(|e| OrtError::Run(e.to_string()))?;
    Ok(y.to_vec())
}
