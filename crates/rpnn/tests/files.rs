//! RPNN's secondary files get the care of its main inputs: the datagen lock, the model card,
//! datagen's resume files and `datagen merge`'s inputs. Something at such a name that is not a
//! regular file — a named pipe, a link to `/dev/zero`, a link that loops, a link to nothing —
//! is a clear error naming the file, given at once: every case runs under a 20 s limit (a pipe
//! opened for reading would wait for a writer forever; `/dev/zero` read whole would fill the
//! memory), far above the milliseconds a refusal takes.

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Duration;

use nimbus_rpnn::data::datagen::DatagenError;
use nimbus_rpnn::data::dataset::{self, DatagenOptions};
use nimbus_rpnn::data::shards::merge;
use nimbus_rpnn::model::Rpnn;

/// Runs `f` on its own thread and fails the test when it has not returned after 20 s (a hang;
/// the thread is left behind and ends with the test process).
fn within<T: Send + 'static>(what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(Duration::from_secs(20))
        .unwrap_or_else(|_| panic!("{what}: no answer within 20 s (a hang)"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nimbus-rpnn-files-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn mkfifo(path: &Path) {
    let ok = std::process::Command::new("mkfifo")
        .arg(path)
        .status()
        .unwrap()
        .success();
    assert!(ok, "mkfifo {}", path.display());
}

/// The four things put at a file's name, with a word its error must hold.
#[derive(Debug, Clone, Copy)]
enum Bad {
    Fifo,
    DevZero,
    Loop,
    Dangling,
}

const BADS: [Bad; 4] = [Bad::Fifo, Bad::DevZero, Bad::Loop, Bad::Dangling];

impl Bad {
    /// Replaces whatever is at `path` with this.
    fn put(self, path: &Path) {
        let _ = std::fs::remove_file(path);
        match self {
            Bad::Fifo => mkfifo(path),
            Bad::DevZero => std::os::unix::fs::symlink("/dev/zero", path).unwrap(),
            Bad::Loop => std::os::unix::fs::symlink(path, path).unwrap(),
            Bad::Dangling => {
                std::os::unix::fs::symlink(path.with_extension("nothing-here"), path).unwrap()
            }
        }
    }

    /// What the error says of it (fsio's words).
    fn word(self) -> &'static str {
        match self {
            Bad::Fifo | Bad::DevZero => "not a regular file",
            Bad::Loop => "loops",
            Bad::Dangling => "dangling",
        }
    }
}

/// Tiny settings: one training record, no validation or test records, 16 samples.
fn opts() -> DatagenOptions {
    DatagenOptions {
        records: 1,
        val_records: 0,
        test_records: 0,
        shard_size: 1,
        seed: 3,
        max_samples: 256,
        samples: 16,
        eval_samples: 16,
        eval_noise: 0.0,
        light: nimbus_rpnn::data::datagen::LightSampling::Sphere,
        albedo: 1.0,
        phase: "hg".into(),
        progress: false,
        gpu: false,
        part: None,
        f16_descriptors: false,
        sky_transfer: false,
    }
}

/// Five generated clouds at 24 × 18 × 24 (the datagen tests' small set).
fn small_set() -> Vec<dataset::CloudSpec> {
    dataset::generated_set(5, 1)
        .into_iter()
        .map(|mut c| {
            if let dataset::CloudSource::Generated { resolution, .. } = &mut c.source {
                *resolution = [24, 18, 24];
            }
            c
        })
        .collect()
}

fn run(out: &Path, o: DatagenOptions) -> Result<dataset::RunSummary, DatagenError> {
    let out = out.to_path_buf();
    within(&format!("datagen into {}", out.display()), move || {
        dataset::run(&small_set(), &o, &out)
    })
}

fn run_merge(parts: &[PathBuf], out: &Path) -> Result<(), DatagenError> {
    let (parts, out) = (parts.to_vec(), out.to_path_buf());
    within(&format!("merge into {}", out.display()), move || {
        merge(&parts, &out).map(|_| ())
    })
}

/// A `.lock` that links to another file: datagen and merge refuse it, naming the lock, and the
/// file it points to keeps its bytes (it was once truncated and overwritten with a process id).
/// A named pipe there is refused at once.
#[test]
fn datagen_lock_is_never_written_through_a_link() {
    let d = tmp("lock");
    let victim = d.join("victim.txt");
    std::fs::write(&victim, "precious bytes").unwrap();
    let out = d.join("out");
    std::fs::create_dir_all(&out).unwrap();
    std::os::unix::fs::symlink(&victim, out.join(".lock")).unwrap();
    let e = run(&out, opts()).unwrap_err().to_string();
    assert!(
        e.contains(&*out.join(".lock").to_string_lossy()) && e.contains("symbolic link"),
        "{e}"
    );
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious bytes");
    // Merge shares the lock: its output folder with the same link.
    let part = d.join("part");
    run(&part, opts()).unwrap();
    let e = run_merge(std::slice::from_ref(&part), &out)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&*out.join(".lock").to_string_lossy()) && e.contains("symbolic link"),
        "{e}"
    );
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious bytes");
    // A pipe at `.lock`: refused at once (within() bounds it), not waited on.
    std::fs::remove_file(out.join(".lock")).unwrap();
    mkfifo(&out.join(".lock"));
    let e = run(&out, opts()).unwrap_err().to_string();
    assert!(
        e.contains(".lock") && e.contains("not a regular file"),
        "{e}"
    );
    // Nothing was written into the folder but what the test put there.
    let names: Vec<_> = std::fs::read_dir(&out).unwrap().flatten().collect();
    assert_eq!(names.len(), 1, "{names:?}");
    // The lock taken properly (a regular file) holds the run's process id; a second run finds
    // it free again afterwards.
    std::fs::remove_file(out.join(".lock")).unwrap();
    assert_eq!(run(&out, opts()).unwrap().records, 1);
    assert_eq!(
        std::fs::read_to_string(out.join(".lock")).unwrap(),
        std::process::id().to_string()
    );
    assert_eq!(run(&out, opts()).unwrap().computed, 0);
}

/// Each file a resumed datagen reads — the three `.npy` files of a shard, its `.sha256`,
/// `settings.json` and `manifest.json` — replaced by each of the four bad things: 24 cases,
/// each refused with an error naming the file and what it is, and never replaced (a pipe or a
/// link at a shard's name is not a file datagen wrote).
#[test]
fn datagen_resume_files_that_are_not_files_are_refused() {
    let d = tmp("resume");
    let good = d.join("good");
    run(&good, opts()).unwrap();
    let files = [
        "train_00000_x.npy",
        "train_00000_y.npy",
        "train_00000_meta.npy",
        "train_00000.sha256",
        "settings.json",
        "manifest.json",
    ];
    let mut cases = 0;
    for (i, file) in files.iter().enumerate() {
        for bad in BADS {
            let out = d.join(format!("case-{i}-{bad:?}"));
            std::fs::create_dir_all(&out).unwrap();
            for f in files {
                std::fs::copy(good.join(f), out.join(f)).unwrap();
            }
            let path = out.join(file);
            bad.put(&path);
            let e = run(&out, opts())
                .map(|r| format!("ran: {} records, {} computed", r.records, r.computed))
                .unwrap_or_else(|e| format!("refused: {e}"));
            assert!(
                e.starts_with("refused")
                    && e.contains(&*path.to_string_lossy())
                    && e.contains(bad.word()),
                "{file} as {bad:?}: {e}"
            );
            // Left as it was found.
            assert_eq!(
                std::fs::symlink_metadata(&path).unwrap().is_symlink(),
                !matches!(bad, Bad::Fifo),
                "{file} as {bad:?}"
            );
            cases += 1;
        }
    }
    assert_eq!(cases, 24);
    // The intact folder resumes with nothing to compute.
    assert_eq!(run(&good, opts()).unwrap().computed, 0);
}

/// `datagen merge`'s inputs — a part's `settings.json`, `manifest.json` and a shard file, and
/// the output folder's `settings.json` — each replaced by each bad thing: 16 cases, each refused
/// naming the file, with nothing written to the output folder.
#[test]
fn merge_inputs_that_are_not_files_are_refused() {
    let d = tmp("merge");
    let part = d.join("part");
    run(&part, opts()).unwrap();
    let mut cases = 0;
    for (i, file) in [
        "settings.json",
        "manifest.json",
        "train_00000_y.npy",
        "out/settings.json",
    ]
    .iter()
    .enumerate()
    {
        for bad in BADS {
            let case = d.join(format!("case-{i}-{bad:?}"));
            let p = case.join("part");
            std::fs::create_dir_all(&p).unwrap();
            for f in std::fs::read_dir(&part).unwrap().flatten() {
                if f.file_type().unwrap().is_file() && f.file_name() != ".lock" {
                    std::fs::copy(f.path(), p.join(f.file_name())).unwrap();
                }
            }
            let out = case.join("out");
            std::fs::create_dir_all(&out).unwrap();
            let path = match file.strip_prefix("out/") {
                Some(f) => out.join(f),
                None => p.join(file),
            };
            bad.put(&path);
            let e = run_merge(std::slice::from_ref(&p), &out)
                .map(|()| "merged".to_string())
                .unwrap_or_else(|e| format!("refused: {e}"));
            assert!(
                e.starts_with("refused")
                    && e.contains(&*path.to_string_lossy())
                    && e.contains(bad.word()),
                "{file} as {bad:?}: {e}"
            );
            // Nothing written to the output folder (only what the test put there).
            let names: Vec<_> = std::fs::read_dir(&out).unwrap().flatten().collect();
            assert_eq!(
                names.len(),
                file.starts_with("out/") as usize,
                "{file} as {bad:?}: {names:?}"
            );
            cases += 1;
        }
    }
    assert_eq!(cases, 16);
    // The intact part merges.
    let out = d.join("merged");
    run_merge(std::slice::from_ref(&part), &out).unwrap();
    assert!(out.join("train_00000_x.npy").is_file());
}

/// Shards are written whole or not at all: a hidden partial left by a killed run (lock free) is
/// removed by the next run into the folder, and a run leaves no temporary file behind (the old
/// `*_x.npy.tmp` files of a full disk stayed forever).
#[test]
fn shard_writes_leave_no_partials() {
    let out = tmp("partials");
    let dead = out.join(".train_00000_x.npy.partial-999999-0.npy");
    std::fs::write(&dead, b"torn").unwrap();
    assert_eq!(run(&out, opts()).unwrap().computed, 1);
    assert!(!dead.exists());
    let mut names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    // The run's own files and nothing else.
    assert_eq!(
        names,
        [
            ".lock",
            "manifest.json",
            "settings.json",
            "train_00000.sha256",
            "train_00000_meta.npy",
            "train_00000_x.npy",
            "train_00000_y.npy",
        ]
    );
}

/// The test networks carry no albedo in their metadata, so the card beside them is read.
fn model_with_card(dir: &Path, card: Option<&str>) -> PathBuf {
    let model = dir.join("m.onnx");
    // Whatever a case left there (a pipe, a link) goes first: a copy would follow it.
    let _ = std::fs::remove_file(&model);
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/rpnn-micro.onnx"),
        &model,
    )
    .unwrap();
    let _ = std::fs::remove_file(dir.join("m.json"));
    if let Some(c) = card {
        std::fs::write(dir.join("m.json"), c).unwrap();
    }
    model
}

fn load(model: &Path) -> Result<Rpnn, String> {
    let model = model.to_path_buf();
    within(&format!("loading {}", model.display()), move || {
        Rpnn::load(&model).map_err(|e| e.to_string())
    })
}

/// A card's albedo is checked as the metadata's is: 2 and −1 (once taken with a warning) are
/// refused naming the card and `data.albedo`, as are a string and a shape that is not the
/// graph's; a card stating 0.5 gives the model albedo 0.5; no card, no albedo.
#[test]
fn model_card_fields_are_checked_like_the_metadata() {
    let d = tmp("card");
    let card = d.join("m.json");
    for (text, field) in [
        (r#"{"data": {"albedo": 2}}"#, "data.albedo"),
        (r#"{"data": {"albedo": -1}}"#, "data.albedo"),
        (r#"{"data": {"albedo": "0.9"}}"#, "data.albedo"),
        (
            r#"{"architecture": {"levels": 99}, "data": {"albedo": 0.5}}"#,
            "architecture.levels",
        ),
    ] {
        let e = load(&model_with_card(&d, Some(text))).unwrap_err();
        assert!(
            e.contains(&*card.to_string_lossy()) && e.contains(&format!("field `{field}`")),
            "{text}: {e}"
        );
    }
    let e = load(&model_with_card(&d, Some("{not json"))).unwrap_err();
    assert!(e.contains("m.json") && e.contains("not valid JSON"), "{e}");
    let m = load(&model_with_card(&d, Some(r#"{"data": {"albedo": 0.5}}"#))).unwrap();
    assert_eq!(m.albedo, Some(0.5));
    // The card's shape, stated rightly, is read.
    let arch = format!(
        r#"{{"architecture": {{"levels": {}, "points": {}, "width": {}, "outputs": {}, "head_layers": {}}}, "data": {{"albedo": 1}}}}"#,
        m.levels,
        m.points,
        m.width,
        m.outputs,
        m.head.len()
    );
    assert_eq!(
        load(&model_with_card(&d, Some(&arch))).unwrap().albedo,
        Some(1.0)
    );
    assert_eq!(load(&model_with_card(&d, None)).unwrap().albedo, None);
}

/// The card as a pipe, a link to `/dev/zero`, a looping and a dangling link: 4 cases, each
/// refused at once naming the card (a dangling link is not taken for a missing card). The model
/// itself as each of them: 4 more.
#[test]
fn model_card_and_model_that_are_not_files_are_refused() {
    let d = tmp("card-files");
    let card = d.join("m.json");
    let mut cases = 0;
    for bad in BADS {
        let model = model_with_card(&d, None);
        bad.put(&card);
        let e = load(&model).unwrap_err();
        assert!(
            e.contains(&*card.to_string_lossy()) && e.contains(bad.word()),
            "card as {bad:?}: {e}"
        );
        let _ = std::fs::remove_file(&card);
        bad.put(&model);
        let e = load(&model).unwrap_err();
        assert!(
            e.contains(&*model.to_string_lossy()) && e.contains(bad.word()),
            "model as {bad:?}: {e}"
        );
        cases += 2;
    }
    assert_eq!(cases, 8);
}
