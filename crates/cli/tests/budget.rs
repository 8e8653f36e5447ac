//! The memory budget end to end: every input-sized allocation (volume files, generators,
//! EXR data windows, RPNN's pyramid, the photon map's buffers, datagen's split) is refused with
//! the field, the bytes and the budget, never an allocator abort.

use crate::common::{nimbus, root, text, tmp};
use std::process::Command;

/// Inputs that size an allocation (a sparse VDB's index box, a generator's resolution, an EXR's
/// data window) are checked against the memory budget: a clear error naming the field, the bytes
/// and the budget, never an allocator abort.
#[test]
fn memory_budget_refuses_instead_of_aborting() {
    let d = tmp("budget");
    std::fs::create_dir_all(&d).unwrap();
    // 11 kB written by OpenVDB's own bindings (make_far_tiles.py): two tiles in a 1288³ box,
    // kept sparse — a brick index of 161³ × 4 bytes = 15.9 MiB, checked before it is allocated.
    let vdb = root().join("crates/scene/tests/data/far_tiles.vdb");
    let o = nimbus(&["info", vdb.to_str().unwrap(), "--max-memory", "8M"]);
    let t = text(&o);
    assert!(!o.status.success(), "{t}");
    assert!(
        t.contains("far_tiles.vdb")
            && t.contains("grid.bounds")
            && t.contains("1288×1288×1288")
            && t.contains("15.9 MiB")
            && t.contains("8.0 MiB"),
        "{t}"
    );
    // Within a budget of 64 MiB it reads: 16 MiB of index, not 8 GiB of dense grid.
    let o = nimbus(&["info", vdb.to_str().unwrap(), "--max-memory", "64M"]);
    assert!(o.status.success(), "{}", text(&o));
    // A grid written as .npy is generated in memory first, as 8³ bricks: refused from the
    // shape's bound before any noise is evaluated — 1 724 038 reachable bricks of 2 KiB, held
    // twice, + the index = 6.6 GiB (dense: 8.0 GiB).
    let npy = d.join("big.npy");
    let o = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .env("NIMBUS_MAX_MEMORY", "4G")
        .args(["generate", "cumulus", "--res", "1290,1290,1290", "-o"])
        .arg(&npy)
        .output()
        .unwrap();
    let t = text(&o);
    assert!(
        !o.status.success() && t.contains("resolution") && t.contains("6.6 GiB"),
        "{t}"
    );
    assert!(!npy.exists());
    // A .vol is streamed: only the slab buffers count (one per worker, two queued, one being
    // written: ≥ 4 × 1290² × 8 × 4 B = 213 MB), checked before the file is created.
    let vol = d.join("big.vol");
    let o = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .env("NIMBUS_MAX_MEMORY", "64M")
        .args(["generate", "cumulus", "--res", "1290,1290,1290", "-o"])
        .arg(&vol)
        .output()
        .unwrap();
    let t = text(&o);
    assert!(
        !o.status.success() && t.contains("resolution") && t.contains("slab buffers"),
        "{t}"
    );
    assert!(!vol.exists());
    // An EXR whose data window claims 10⁶ × 10⁶ pixels (11.4 TiB as RGB floats).
    let small = d.join("small.exr");
    nimbus_scene::Image::new(4, 3)
        .write_exr(&small, None)
        .unwrap();
    let mut bytes = std::fs::read(&small).unwrap();
    let key = b"dataWindow\0box2i\0";
    let at = bytes
        .windows(key.len())
        .position(|w| w == key)
        .expect("an EXR header has a data window")
        + key.len()
        + 4;
    for (i, v) in [0i32, 0, 999_999, 999_999].iter().enumerate() {
        bytes[at + 4 * i..at + 4 * i + 4].copy_from_slice(&v.to_le_bytes());
    }
    let huge = d.join("huge.exr");
    std::fs::write(&huge, &bytes).unwrap();
    // RPNN's density pyramid is sized before it is built: its stored levels (all of them for the
    // demo's 128×96×128 grid: 1 797 561 voxels) and a bound of 40 level-0 planes for the
    // streaming windows, 8.7 MiB; the grid itself (6.0 MiB) fits the budget of 7 MiB.
    let o = Command::new(env!("CARGO_BIN_EXE_nimbus"))
        .current_dir(root())
        .env("XDG_RUNTIME_DIR", std::env::temp_dir())
        .args([
            "render",
            "scenes/demo-cumulus.toml",
            "--method",
            "rpnn",
            "--backend",
            "ort",
        ])
        .args(["--spp", "1", "-q", "--max-memory", "7M", "-o"])
        .arg(d.join("p.exr"))
        .output()
        .unwrap();
    let t = text(&o);
    assert!(
        !o.status.success() && t.contains("RPNN density pyramid") && t.contains("8.7 MiB"),
        "{t}"
    );
    // The model file itself is checked before it is read whole (a 6 GiB file named as a model
    // was once read to the end).
    let (scene, model) = (
        root().join("crates/cli/tests/bad-inputs/files/good.toml"),
        root().join("models/rpnn-hg.onnx"),
    );
    let out = d.join("m.exr");
    let o = nimbus(&[
        "render",
        scene.to_str().unwrap(),
        "--method",
        "rpnn",
        "--model",
        model.to_str().unwrap(),
        "--spp",
        "1",
        "-q",
        "--max-memory",
        "4M",
        "-o",
        out.to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(
        !o.status.success()
            && t.contains("rpnn-hg.onnx")
            && t.contains("5.0 MiB")
            && t.contains("4.0 MiB"),
        "{t}"
    );
    let o = nimbus(&["compare", huge.to_str().unwrap(), small.to_str().unwrap()]);
    let t = text(&o);
    assert!(
        !o.status.success()
            && t.contains("huge.exr")
            && t.contains("dataWindow")
            && t.contains("TiB"),
        "{t}"
    );
    // The photon map's buffers live in host memory on lavapipe: a ring of 1 000 partial
    // caches (≈ 105 MB, within one storage binding) on top of density and J is over 150 MB.
    if nimbus_gpu::testing::has_adapter("budget: the photon map's buffers") {
        let o = Command::new(env!("CARGO_BIN_EXE_nimbus"))
            .current_dir(root())
            .args(["render", "scenes/demo-cumulus.toml", "--method", "pm"])
            .args(["--ring", "1000", "--max-memory", "150M", "-o"])
            .arg(d.join("pm.exr"))
            .output()
            .unwrap();
        let t = text(&o);
        assert!(
            !o.status.success()
                && t.contains("field `ring`")
                && t.contains("photon map's buffers")
                && t.contains("150.0 MiB"),
            "{t}"
        );
    }
    // Datagen sizes a split's clouds and one shard of records before building anything:
    // 100 000 records of ≈ 18 kB each are 1.7 GiB.
    let o = nimbus(&[
        "datagen",
        "--clouds",
        "gen:5",
        "--records",
        "100000",
        "--shard-size",
        "100000",
        "--samples",
        "4",
        "--device",
        "cpu",
        "-q",
        "--max-memory",
        "500M",
        "-o",
        d.join("set").to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(
        !o.status.success() && t.contains("shard_size") && t.contains("--shard-size"),
        "{t}"
    );
    let o = nimbus(&["info", vdb.to_str().unwrap(), "--max-memory", "lots"]);
    assert!(
        !o.status.success() && text(&o).contains("--max-memory"),
        "{}",
        text(&o)
    );
}
