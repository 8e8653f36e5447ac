//! RPNN's secondary files through the binary: the model card beside `--model`, the files a
//! resumed `datagen` reads and `datagen merge`'s inputs. Each is replaced by a named pipe, a link
//! to `/dev/zero`, a link that loops and a link to nothing; every run must end within 20 s (it
//! is killed then and the test fails: a pipe opened for reading waits for a writer forever) with
//! a failure status and an error naming the file, never exit 0.

use std::path::{Path, PathBuf};

use crate::common::{nimbus_within, root, text, tmp};

/// The four things put at a file's name, with a word their error holds.
const BADS: [&str; 4] = ["fifo", "dev-zero", "loop", "dangling"];

fn put(bad: &str, path: &Path) {
    let _ = std::fs::remove_file(path);
    match bad {
        "fifo" => assert!(
            std::process::Command::new("mkfifo")
                .arg(path)
                .status()
                .unwrap()
                .success()
        ),
        "dev-zero" => std::os::unix::fs::symlink("/dev/zero", path).unwrap(),
        "loop" => std::os::unix::fs::symlink(path, path).unwrap(),
        _ => std::os::unix::fs::symlink(path.with_extension("nothing-here"), path).unwrap(),
    }
}

fn word(bad: &str) -> &'static str {
    match bad {
        "fifo" | "dev-zero" => "not a regular file",
        "loop" => "loops",
        _ => "dangling",
    }
}

/// Runs `args` under the 20 s limit and checks a refusal naming `path` and what it is.
fn refused(args: &[&str], path: &Path, bad: &str) {
    let o = nimbus_within(args, 20)
        .unwrap_or_else(|| panic!("{} as {bad}: still running after 20 s", path.display()));
    let t = text(&o);
    assert!(
        !o.status.success() && t.contains(&*path.to_string_lossy()) && t.contains(word(bad)),
        "{} as {bad}: {t}",
        path.display()
    );
}

/// The model card (`<model>.json`, read for a model without an albedo in its metadata) as each
/// bad thing: 4 cases.
#[test]
fn rpnn_model_card_that_is_not_a_file() {
    let d = tmp("card");
    let model = d.join("m.onnx");
    std::fs::copy(
        root().join("crates/rpnn/tests/data/rpnn-micro.onnx"),
        &model,
    )
    .unwrap();
    let scene = root().join("scenes/refs/cube_iso.toml");
    let card = d.join("m.json");
    let out = d.join("img");
    for bad in BADS {
        put(bad, &card);
        refused(
            &[
                "render",
                scene.to_str().unwrap(),
                "--method",
                "rpnn",
                "--model",
                model.to_str().unwrap(),
                "-q",
                "-o",
                out.to_str().unwrap(),
            ],
            &card,
            bad,
        );
    }
}

/// A one-record datagen into `out` (16 samples, CPU).
fn datagen(out: &Path) -> Vec<String> {
    [
        "datagen",
        "--clouds",
        "gen:5",
        "--records",
        "1",
        "--test-records",
        "0",
        "--val-records",
        "0",
        "--shard-size",
        "1",
        "--samples",
        "16",
        "--device",
        "cpu",
        "-q",
        "-o",
    ]
    .into_iter()
    .map(String::from)
    .chain([out.display().to_string()])
    .collect()
}

/// Each file a resumed datagen reads (a shard's three `.npy` files, its `.sha256`,
/// `settings.json`, `manifest.json`) as each bad thing: 24 cases; then `datagen merge` with a
/// part's `settings.json`, `manifest.json` and a shard as each: 12 more.
#[test]
fn rpnn_datagen_and_merge_files_that_are_not_files() {
    let d = tmp("datagen");
    let good = d.join("good");
    let args = datagen(&good);
    let o = nimbus_within(&args.iter().map(String::as_str).collect::<Vec<_>>(), 120)
        .expect("a one-record datagen within 120 s");
    assert!(o.status.success(), "{}", text(&o));
    let files = [
        "train_00000_x.npy",
        "train_00000_y.npy",
        "train_00000_meta.npy",
        "train_00000.sha256",
        "settings.json",
        "manifest.json",
    ];
    let copy = |to: &PathBuf| {
        std::fs::create_dir_all(to).unwrap();
        for f in files {
            std::fs::copy(good.join(f), to.join(f)).unwrap();
        }
    };
    let mut cases = 0;
    for (i, file) in files.iter().enumerate() {
        for bad in BADS {
            let out = d.join(format!("resume-{i}-{bad}"));
            copy(&out);
            put(bad, &out.join(file));
            let args = datagen(&out);
            refused(
                &args.iter().map(String::as_str).collect::<Vec<_>>(),
                &out.join(file),
                bad,
            );
            cases += 1;
        }
    }
    for (i, file) in ["settings.json", "manifest.json", "train_00000_x.npy"]
        .iter()
        .enumerate()
    {
        for bad in BADS {
            let part = d.join(format!("part-{i}-{bad}"));
            copy(&part);
            put(bad, &part.join(file));
            let merged = d.join(format!("merged-{i}-{bad}"));
            refused(
                &[
                    "datagen",
                    "merge",
                    part.to_str().unwrap(),
                    "-o",
                    merged.to_str().unwrap(),
                ],
                &part.join(file),
                bad,
            );
            assert!(!merged.exists(), "nothing is written when a check fails");
            cases += 1;
        }
    }
    assert_eq!(cases, 36);
}
