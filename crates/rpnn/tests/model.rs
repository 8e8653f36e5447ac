//! Reading RPNN models from ONNX: the CPU forward pass reproduces torch; other graphs are refused.

use std::path::{Path, PathBuf};

use nimbus_rpnn::model::Rpnn;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// (descriptors, torch outputs) of the fixture (`training/make_fixtures.py`).
pub fn fixture_io() -> (Vec<Vec<f32>>, Vec<f32>) {
    let f = std::fs::File::open(data("rpnn-tiny-io.npy")).unwrap();
    let npy = npyz::NpyFile::new(std::io::BufReader::new(f)).unwrap();
    let cols = npy.shape()[1] as usize;
    let v: Vec<f32> = npy.into_vec().unwrap();
    let rows: Vec<&[f32]> = v.chunks(cols).collect();
    (
        rows.iter().map(|r| r[..cols - 1].to_vec()).collect(),
        rows.iter().map(|r| r[cols - 1]).collect(),
    )
}

#[test]
fn tiny_model_matches_torch() {
    let m = Rpnn::load(&data("rpnn-tiny.onnx")).unwrap();
    assert_eq!((m.levels, m.points, m.width, m.outputs), (10, 225, 16, 1));
    assert_eq!(m.head.len(), 3);
    assert_eq!(m.phase, "hg");
    assert!(m.blocks[0].w1.is_none() && m.blocks[1..].iter().all(|b| b.w1.is_some()));
    let (xs, ys) = fixture_io();
    let mut nonzero = 0;
    for (x, y) in xs.iter().zip(&ys) {
        let got = m.forward(x)[0];
        // Same f32 operations in another order: agreement to float32 rounding (1e-5 of the
        // output scale; the fixture's outputs are O(1)).
        assert!((got - y).abs() <= 1e-5 * y.abs().max(1.0), "{got} vs {y}");
        nonzero += (*y > 0.0) as usize;
    }
    assert!(nonzero > 8, "the fixture should exercise live outputs");
}

#[test]
fn parameter_count_matches_the_training_script() {
    let m = Rpnn::load(&data("rpnn-tiny.onnx")).unwrap();
    // Width 16: 10 (226·16 + 16) + 10 (16·16 + 16) + 9 · 16·16 + 2 (16·16 + 16) + 17.
    let expected = 10 * (226 * 16 + 16) + 10 * (16 * 16 + 16) + 9 * 256 + 2 * (256 + 16) + 17;
    assert_eq!(m.parameters(), expected);
}

#[test]
fn other_graphs_and_bad_files_are_refused() {
    let e = Rpnn::load(&data("not-rpnn.onnx")).unwrap_err().to_string();
    assert!(
        e.contains("not-rpnn.onnx") && e.contains("not the RPNN architecture"),
        "{e}"
    );
    let e = Rpnn::load(&data("missing.onnx")).unwrap_err().to_string();
    assert!(e.contains("missing.onnx") && e.contains("not found"), "{e}");
    let dir = std::env::temp_dir().join(format!("nimbus-model-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("garbage.onnx");
    std::fs::write(
        &bad,
        b"\x08\x96\x01garbage that is not protobuf \xff\xff\xff",
    )
    .unwrap();
    let e = Rpnn::load(&bad).unwrap_err().to_string();
    assert!(e.contains("garbage.onnx"), "{e}");
    // A truncated copy of a real model.
    let bytes = std::fs::read(data("rpnn-tiny.onnx")).unwrap();
    let cut = dir.join("cut.onnx");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let e = Rpnn::load(&cut).unwrap_err().to_string();
    assert!(e.contains("cut.onnx"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn onnx_runtime_agrees_with_torch_and_the_cpu_reference() {
    use nimbus_rpnn::ort_backend::OrtModel;
    let mut ort = OrtModel::load(&data("rpnn-tiny.onnx"), 1).unwrap_or_else(|e| panic!("{e}"));
    let (xs, ys) = fixture_io();
    let flat: Vec<f32> = xs.iter().flatten().copied().collect();
    let got = ort.predict(&flat, xs.len()).unwrap();
    let m = Rpnn::load(&data("rpnn-tiny.onnx")).unwrap();
    for ((x, y), g) in xs.iter().zip(&ys).zip(&got) {
        let cpu = m.forward(x)[0];
        // Three float32 evaluations of the same function: 1e-5 of the O(1) output scale.
        assert!(
            (g - y).abs() <= 1e-5 * y.abs().max(1.0),
            "ort {g} vs torch {y}"
        );
        assert!(
            (g - cpu).abs() <= 1e-5 * cpu.abs().max(1.0),
            "ort {g} vs cpu {cpu}"
        );
    }
    // Batch of one, and an empty batch.
    assert_eq!(ort.predict(&flat[..2251], 1).unwrap().len(), 1);
    assert!(ort.predict(&[], 0).unwrap().is_empty());
    // A missing model names the file.
    let e = OrtModel::load(&data("nope.onnx"), 1)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("nope.onnx"), "{e}");
}
