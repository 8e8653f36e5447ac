//! The secondary files of `view` and `compare` get the care of the main inputs
//! (`nimbus_scene::fsio`): a named pipe, `/dev/zero`, a symbolic link loop or a dangling link
//! in their place is refused at once, naming the file, never read forever or waited on. And
//! every output is written whole or not at all: a full disk leaves the old file and no partial,
//! the partials of a killed run are removed by the next run into the folder.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::common::{nimbus, nimbus_within, text, tmp};

/// Seconds a refused case may take: a refusal is at once (under a second here); a pipe that is
/// waited on, or `/dev/zero` read to the end, never finishes.
const LIMIT_S: u64 = 20;

/// What is put in a file's place.
#[derive(Debug, Clone, Copy)]
enum Bad {
    Fifo,
    DevZero,
    Loop,
    Dangling,
}

const BAD: [Bad; 4] = [Bad::Fifo, Bad::DevZero, Bad::Loop, Bad::Dangling];

/// Replaces whatever is at `path` by `bad`.
fn place(bad: Bad, path: &Path) {
    let _ = std::fs::remove_file(path);
    match bad {
        Bad::Fifo => {
            let s = Command::new("mkfifo").arg(path).status().unwrap();
            assert!(s.success(), "mkfifo {}", path.display());
        }
        Bad::DevZero => std::os::unix::fs::symlink("/dev/zero", path).unwrap(),
        Bad::Loop => std::os::unix::fs::symlink(path, path).unwrap(),
        Bad::Dangling => {
            std::os::unix::fs::symlink(path.with_file_name("nothing-here"), path).unwrap()
        }
    }
}

/// Runs `args` bounded by [`LIMIT_S`]; checks a non-zero exit whose message names `path`.
fn refused(args: &[&str], path: &Path, what: &str) {
    let o = nimbus_within(args, LIMIT_S)
        .unwrap_or_else(|| panic!("{what}: still running after {LIMIT_S} s (a hang)"));
    let t = text(&o);
    assert!(!o.status.success(), "{what}: exit 0: {t}");
    assert!(t.contains(path.to_str().unwrap()), "{what}: {t}");
}

#[test]
fn a_view_script_that_is_not_a_file_is_refused_at_once() {
    let d = tmp("secondary-script");
    let script = d.join("script.txt");
    let mut cases = 0;
    for bad in BAD {
        place(bad, &script);
        // The default scene, headless: the script is read before any GPU work.
        let args = ["view", "--headless", "--script", script.to_str().unwrap()];
        refused(&args, &script, &format!("--script as {bad:?}"));
        cases += 1;
    }
    assert_eq!(cases, 4);
    std::fs::remove_dir_all(&d).ok();
}

const TINY: &str = r#"
[volume]
generator = { kind = "cumulus", seed = 3, resolution = [12, 10, 12] }
density_scale = 20.0
albedo = 1.0
phase = { kind = "hg", g = 0.6 }

[sun]
direction = [1.0, 0.4, 0.3]
irradiance = [3.0, 2.85, 2.6]

[camera]
origin = [0.0, 0.2, 3.2]
target = [0.0, 0.0, 0.0]
vfov_deg = 30.0
width = 16
height = 12

[render]
spp = 1
seed = 1
"#;

/// Every file of a `compare` reference-cache entry (the JSON, the EXR, the two `.npy` arrays),
/// in each of the four bad forms: with `--ref-cached-only` the run stops, naming the file;
/// without it the entry is ignored with a line naming the file, the reference rendered again
/// and the entry stored whole again (regular files replacing the pipe or links).
#[test]
fn a_compare_cache_entry_that_is_not_a_file_is_refused_at_once() {
    let d = tmp("secondary-cache");
    let scene = d.join("tiny.toml");
    std::fs::write(&scene, TINY).unwrap();
    let (cache, out) = (d.join("cache"), d.join("report"));
    let mut args = vec![
        "compare",
        scene.to_str().unwrap(),
        "--methods",
        "pt",
        "--budgets",
        "pt=1",
        "--ref-spp",
        "1",
        "--ref-noise",
        "0",
        "--ref-device",
        "cpu",
        "--cache",
        cache.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    let o = nimbus(&args);
    assert!(o.status.success(), "{}", text(&o));
    let mut entry: Vec<PathBuf> = std::fs::read_dir(&cache)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .collect();
    entry.sort();
    // KEY.exr, KEY.json, KEY_diff.npy, KEY_tau.npy, and nothing else (no temporary left).
    assert_eq!(entry.len(), 4, "{entry:?}");
    let mut cases = 0;
    for file in &entry {
        for bad in BAD {
            place(bad, file);
            let what = format!("{} as {bad:?}", file.display());
            let mut only = args.clone();
            only.push("--ref-cached-only");
            refused(&only, file, &format!("--ref-cached-only, {what}"));
            let o = nimbus_within(&args, 60).unwrap_or_else(|| panic!("{what}: a hang"));
            let t = text(&o);
            assert!(o.status.success(), "{what}: {t}");
            assert!(
                t.contains("ignoring cache entry") && t.contains(file.to_str().unwrap()),
                "{what}: {t}"
            );
            for f in &entry {
                let m = std::fs::symlink_metadata(f).unwrap();
                assert!(
                    m.is_file() && m.len() > 0,
                    "{what}: {} not rewritten",
                    f.display()
                );
            }
            cases += 1;
        }
    }
    assert_eq!(cases, 16);
    args.push("--ref-cached-only");
    let o = nimbus(&args);
    assert!(
        o.status.success() && text(&o).contains("reference: cached"),
        "{}",
        text(&o)
    );
    std::fs::remove_dir_all(&d).ok();
}

/// Names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// A tmpfs of 64 KiB mounted at `dir` while this lives (root only).
struct SmallDisk(PathBuf);

impl SmallDisk {
    fn mount(dir: &Path) -> Option<Self> {
        let root = Command::new("id")
            .arg("-u")
            .output()
            .is_ok_and(|o| o.stdout.trim_ascii() == b"0");
        if !root {
            println!("skipped: a full disk needs root to mount a small tmpfs");
            return None;
        }
        std::fs::create_dir_all(dir).unwrap();
        let ok = Command::new("mount")
            .args(["-t", "tmpfs", "-o", "size=64k", "tmpfs"])
            .arg(dir)
            .status()
            .is_ok_and(|s| s.success());
        if !ok {
            println!("skipped: cannot mount a tmpfs at {}", dir.display());
            return None;
        }
        Some(Self(dir.to_path_buf()))
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

/// A full disk: `generate` (a `.npy` and a streamed `.vol`) and `render` (its EXR) into a 64 KiB
/// tmpfs, each output 4 to 10 times that: an error naming the file, the file already there
/// unchanged, no partial or empty file left.
#[test]
fn a_full_disk_leaves_the_old_file_and_no_partial() {
    let d = tmp("secondary-full");
    let disk = d.join("disk");
    let Some(_mounted) = SmallDisk::mount(&disk) else {
        return;
    };
    let scene = d.join("wide.toml");
    // 256×192 pixels of noise (1 spp): its EXR (RGB and variance, f32) is about 1 MB before
    // compression, which noise barely shrinks; far over 64 KiB.
    std::fs::write(
        &scene,
        TINY.replace("width = 16", "width = 256")
            .replace("height = 12", "height = 192"),
    )
    .unwrap();
    let npy = disk.join("cloud.npy");
    let vol = disk.join("cloud.vol");
    let exr = disk.join("image.exr");
    // 48³ voxels: 442 KB of f32 (the .vol's zero pages are holes, the cloud's are not).
    let runs: [(Vec<&str>, &Path); 3] = [
        (
            vec![
                "generate",
                "cumulus",
                "--res",
                "48,48,48",
                "-o",
                npy.to_str().unwrap(),
            ],
            &npy,
        ),
        (
            vec![
                "generate",
                "cumulus",
                "--res",
                "48,48,48",
                "-o",
                vol.to_str().unwrap(),
            ],
            &vol,
        ),
        (
            vec![
                "render",
                scene.to_str().unwrap(),
                "-q",
                "--spp",
                "1",
                "-o",
                exr.to_str().unwrap(),
            ],
            &exr,
        ),
    ];
    for (args, file) in runs {
        std::fs::write(file, b"the old file").unwrap();
        let before = names(&disk);
        refused(&args, file, &format!("{} on a full disk", file.display()));
        assert_eq!(std::fs::read(file).unwrap(), b"the old file");
        assert_eq!(names(&disk), before, "a partial or new file left");
    }
    drop(_mounted);
    std::fs::remove_dir_all(&d).ok();
}

/// A run's temporaries are `.NAME.partial-PID-N.EXT`, locked while written: a later run into
/// the folder removes those whose lock is free (their writer died) and leaves a locked one.
#[test]
fn the_partials_of_a_killed_run_are_removed_by_the_next() {
    let d = tmp("secondary-partials");
    let scene = d.join("tiny.toml");
    std::fs::write(&scene, TINY).unwrap();
    let out = d.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let dead = out.join(".x.exr.partial-123-0.exr");
    std::fs::write(&dead, b"torn").unwrap();
    let live = out.join(".y.exr.partial-456-0.exr");
    std::fs::write(&live, b"being written").unwrap();
    // Another process's writer holds its lock (this test plays it: flock on an open file).
    let held = std::fs::File::open(&live).unwrap();
    held.try_lock().unwrap();
    let exr = out.join("x.exr");
    let o = nimbus(&[
        "render",
        scene.to_str().unwrap(),
        "-q",
        "--spp",
        "1",
        "-o",
        exr.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(!dead.exists(), "the dead run's partial is still there");
    assert_eq!(std::fs::read(&live).unwrap(), b"being written");
    assert_eq!(
        names(&out),
        [".y.exr.partial-456-0.exr", "x.exr", "x.png"],
        "only the outputs and the live partial"
    );
    drop(held);
    std::fs::remove_dir_all(&d).ok();
}
