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
    io_of("rpnn-tiny-io.npy")
}

fn io_of(name: &str) -> (Vec<Vec<f32>>, Vec<f32>) {
    let f = std::fs::File::open(data(name)).unwrap();
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

/// The reader takes the architecture's shape from the graph: the smallest RPNN (2 levels of 3
/// points, width 2, one head layer) reads and reproduces torch too.
#[test]
fn micro_model_matches_torch() {
    let m = Rpnn::load(&data("rpnn-micro.onnx")).unwrap();
    assert_eq!((m.levels, m.points, m.width, m.outputs), (2, 3, 2, 1));
    assert_eq!(m.head.len(), 1);
    assert_eq!(m.input_len(), 7);
    let (xs, ys) = io_of("rpnn-micro-io.npy");
    assert_eq!((xs.len(), xs[0].len()), (8, 7));
    for (x, y) in xs.iter().zip(&ys) {
        let got = m.forward(x)[0];
        // As above: float32 rounding of O(1) outputs.
        assert!((got - y).abs() <= 1e-5 * y.abs().max(1.0), "{got} vs {y}");
    }
    assert!(
        ys.iter().any(|y| *y > 0.0),
        "the fixture should exercise a live output"
    );
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
    // Weights far beyond a trained network's (×10³⁰: once rendered without a word, the two
    // backends disagreeing by 10²⁹) are refused, naming the tensor.
    use protobuf::Message;
    let mut m = onnx_protobuf::ModelProto::parse_from_bytes(&bytes).unwrap();
    let t = m.graph.as_mut().unwrap().initializer.first_mut().unwrap();
    if t.raw_data.is_empty() {
        t.float_data[0] = 1e30;
    } else {
        t.raw_data[..4].copy_from_slice(&1e30f32.to_le_bytes());
    }
    let name = t.name.clone();
    let huge = dir.join("huge-weight.onnx");
    std::fs::write(&huge, m.write_to_bytes().unwrap()).unwrap();
    let e = Rpnn::load(&huge).unwrap_err().to_string();
    assert!(
        e.contains("huge-weight.onnx") && e.contains(&name) && e.contains("1e30"),
        "{e}"
    );
    // A folder is not read as a model.
    let e = Rpnn::load(&dir).unwrap_err().to_string();
    assert!(e.contains("a folder"), "{e}");
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

/// A paper-sized RPNN (width 200, 1.3 M parameters) with random weights scaled so activations
/// stay O(1) through the 23 layers.
fn random_paper_model(seed: u64) -> Rpnn {
    use nimbus_rpnn::model::{Block, Dense};
    let mut rng = nimbus_trace::rng::Pcg32::new(seed, 1);
    let mut dense = |inputs: usize, outputs: usize, bias: bool| {
        let s = (3.0 / inputs as f32).sqrt();
        Dense {
            inputs,
            outputs,
            w: (0..inputs * outputs)
                .map(|_| ((rng.next_f64() as f32) * 2.0 - 1.0) * s)
                .collect(),
            b: (0..outputs)
                .map(|_| {
                    if bias {
                        (rng.next_f64() as f32) * 0.1
                    } else {
                        0.0
                    }
                })
                .collect(),
        }
    };
    let blocks = (0..10)
        .map(|k| Block {
            v: dense(226, 200, true),
            w1: (k > 0).then(|| dense(200, 200, false)),
            w2: dense(200, 200, true),
        })
        .collect();
    let mut head = vec![
        dense(200, 200, true),
        dense(200, 200, true),
        dense(200, 1, true),
    ];
    // Keep the final ReLU alive: outputs around 1 with a spread from every input.
    head[2].b[0] = 1.0;
    head[2].w.iter_mut().for_each(|w| *w *= 0.1);
    Rpnn {
        levels: 10,
        points: 225,
        width: 200,
        outputs: 1,
        blocks,
        head,
        sky_head: Vec::new(),
        sky_blocks: Vec::new(),
        phase: "hg".into(),
        albedo: Some(1.0),
    }
}

fn max_rel(a: &[f32], b: &[f32]) -> f32 {
    let scale = b.iter().map(|v| v.abs()).sum::<f32>() / b.len() as f32;
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() / y.abs().max(scale))
        .fold(0.0, f32::max)
}

#[test]
fn wgsl_network_agrees_with_the_cpu_reference() {
    use nimbus_rpnn::gpu_mlp::{GpuMlp, NetOptions, Tiles};
    let Some(gpu) = nimbus_gpu::testing::gpu("model::wgsl_network_agrees_with_the_cpu_reference")
    else {
        return;
    };
    let tiny = Rpnn::load(&data("rpnn-tiny.onnx")).unwrap();
    let (xs, _) = fixture_io();
    let flat: Vec<f32> = xs.iter().flatten().copied().collect();
    let m = random_paper_model(3);
    let mut rng = nimbus_trace::rng::Pcg32::new(9, 2);
    let n = 300;
    let x: Vec<f32> = (0..n * 2251)
        .map(|i| {
            if i % 2251 == 2250 {
                (rng.next_f64() as f32) * std::f32::consts::PI
            } else {
                (rng.next_f64() as f32) * 2.0
            }
        })
        .collect();
    let cpu_tiny: Vec<f32> = xs.iter().map(|x| tiny.forward(x)[0]).collect();
    let cpu: Vec<f32> = x.chunks(2251).map(|r| m.forward(r)[0]).collect();
    assert!(cpu.iter().filter(|v| **v > 0.0).count() > n / 4);
    let spread =
        cpu.iter().fold(f32::MIN, |a, v| a.max(*v)) - cpu.iter().fold(f32::MAX, |a, v| a.min(*v));
    assert!(
        spread > 0.05,
        "the random model should depend on its input ({spread})"
    );
    // Both kernels compute the same products.
    for tiles in [Tiles::Square, Tiles::Wide] {
        let opts = NetOptions {
            tiles,
            ..Default::default()
        };
        // The fixture (real export) on its 16 rows …
        let g = GpuMlp::with_options(&gpu, &tiny, 1 << 16, opts).unwrap();
        let got = g.predict(&flat, xs.len()).unwrap();
        // Float32 sums in another order: ≤ 1e-4 relative (to max(|y|, mean |y|)), the issue's
        // bound.
        let e = max_rel(&got, &cpu_tiny);
        assert!(e <= 1e-4, "{tiles:?}: {e}");
        // … and the paper's size on 300 random descriptors, in batches of 128 (tile edges: 300
        // and 128 are not multiples of 64, 200 outputs not of 64 or 128 either).
        let g = GpuMlp::with_options(&gpu, &m, 128, opts).unwrap();
        let got = g.predict(&x, n).unwrap();
        let e = max_rel(&got, &cpu);
        assert!(e <= 1e-4, "{tiles:?}: {e}");
    }
}

/// The density pyramid of a small generated cumulus and 70 shading configurations in it
/// (positions along Lissajous-like curves with frequencies `f`, directions uniform from `seed`).
fn cloud_configs(seed: u64, f: [f32; 3]) -> (nimbus_rpnn::Pyramid, Vec<nimbus_rpnn::Config>) {
    use glam::Vec3;
    let grid = nimbus_scene::generate::generate(nimbus_scene::CloudKind::Cumulus, 4, [32, 24, 32])
        .unwrap();
    let (lo, hi) = nimbus_scene::generate::default_aabb([32, 24, 32]);
    let aabb = nimbus_scene::Aabb::new(lo, hi).unwrap();
    let vol = nimbus_scene::Volume::new(grid, aabb, 30.0).unwrap();
    let pyr = nimbus_rpnn::Pyramid::new(&vol).unwrap();
    let mut rng = nimbus_trace::rng::Pcg32::new(seed, 5);
    let mut dir = || {
        let z = (rng.next_f64() as f32) * 2.0 - 1.0;
        let phi = (rng.next_f64() as f32) * std::f32::consts::TAU;
        let r = (1.0 - z * z).sqrt();
        Vec3::new(r * phi.cos(), z, r * phi.sin())
    };
    let configs = (0..70)
        .map(|i| nimbus_rpnn::Config {
            x: Vec3::new(
                (i as f32 * f[0]).sin() * 0.3,
                (i as f32 * f[1]).cos() * 0.2,
                (i as f32 * f[2]).sin() * 0.3,
            ),
            view: dir(),
            to_light: dir(),
        })
        .collect();
    (pyr, configs)
}

#[test]
fn gpu_descriptor_and_network_equal_cpu_descriptor_and_onnx_runtime() {
    use nimbus_rpnn::descriptors;
    use nimbus_rpnn::gpu_mlp::{GpuRpnn, NetOptions, Tiles};
    use nimbus_rpnn::ort_backend::OrtModel;
    let Some(gpu) = nimbus_gpu::testing::gpu(
        "model::gpu_descriptor_and_network_equal_cpu_descriptor_and_onnx_runtime",
    ) else {
        return;
    };
    let (pyr, configs) = cloud_configs(5, [0.37, 0.11, 0.23]);
    // The test fixtures and the shipped models (paper size, trained; with and without the sky
    // head, whose 25 coefficients follow the sun's value in each row).
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models");
    for model_path in [
        data("rpnn-tiny.onnx"),
        data("rpnn-tiny-sky.onnx"),
        // The sky head on blocks 4 and 9: the kernel's two inputs, block 4's output kept.
        data("rpnn-tiny-sky2.onnx"),
        models.join("rpnn-hg.onnx"),
        models.join("rpnn-hg-sky.onnx"),
    ] {
        let model = Rpnn::load(&model_path).unwrap();
        let desc = descriptors(&pyr, &configs);
        let mut ort = OrtModel::load(&model_path, 1).unwrap();
        let want = ort.predict(&desc, configs.len()).unwrap();
        assert!(want.iter().any(|v| *v > 0.0));
        for tiles in [Tiles::Wide, Tiles::Square] {
            let opts = NetOptions {
                tiles,
                ..Default::default()
            };
            let mut g = GpuRpnn::with_options(&gpu, &pyr, &model, 64, opts).unwrap();
            let got = g.predict(&configs).unwrap();
            assert_eq!(got.len(), configs.len() * model.outputs_per_query());
            // Descriptors agree to 1e-5 (tests/descriptor.rs) and the network to 1e-4:
            // together 1e-4 relative to the output scale is the bound the issue sets for the
            // two backends.
            let d = max_rel(&got, &want);
            assert!(d <= 1e-4, "{} {tiles:?}: {d}", model_path.display());
            // f16 storage on the fixtures (the shipped models' f16 figures, compared as a render
            // uses them, are f16_network_agrees_with_onnx_runtime_within_its_tolerance's): their
            // random weights (±0.3, no training) let rounding grow through the layers (measured
            // 3.9e-3 – 7.2e-3), so 2e-2; a misplaced buffer or flag errs by O(1).
            if !model_path.starts_with(&models) {
                let f16 = NetOptions {
                    tiles,
                    precision: nimbus_rpnn::gpu_mlp::Precision::F16,
                };
                let mut h = GpuRpnn::with_options(&gpu, &pyr, &model, 64, f16).unwrap();
                let d16 = max_rel(&h.predict(&configs).unwrap(), &want);
                assert!(d16 <= 2e-2, "{} {tiles:?} f16: {d16}", model_path.display());
            }
        }
    }
}

/// The shipped model follows the scene's phase function: the Lorenz–Mie model for a Mie medium,
/// the HG one otherwise; both load and say which phase function they were trained for.
#[test]
fn the_model_follows_the_phase_function() {
    let hg = nimbus_rpnn::model::model_path_for("hg g=0.857");
    let mie = nimbus_rpnn::model::model_path_for("mie r_eff=8µm v_eff=0.1 λ=550nm chop=5°");
    assert!(hg.ends_with("models/rpnn-hg.onnx"), "{hg:?}");
    assert!(mie.ends_with("models/rpnn-mie.onnx"), "{mie:?}");
    assert_eq!(Rpnn::load(&hg).unwrap().phase, "hg");
    assert_eq!(Rpnn::load(&mie).unwrap().phase, "mie");
    assert_eq!(nimbus_rpnn::model::model_path_for("isotropic"), hg);
}

/// A model with a sky head (`training/train_sky.py`'s architecture) reads with both heads: its
/// output is the sun head's value and the 25 coefficients, and ONNX Runtime, torch and the CPU
/// forward pass agree on all 26 to 1e-5 of the outputs' scale; the sun column equals the model
/// without the head (the same weights). Both heads: on the last block's output, and on block
/// 4's beside it (`--sky-blocks 4,9`: the first layer reads 2 × 16 values).
#[test]
fn a_sky_head_model_reads_and_agrees_everywhere() {
    for (file, io, blocks) in [
        ("rpnn-tiny-sky.onnx", "rpnn-tiny-sky-io.npy", vec![9]),
        ("rpnn-tiny-sky2.onnx", "rpnn-tiny-sky2-io.npy", vec![4, 9]),
    ] {
        sky_head_model_agrees(file, io, &blocks);
    }
}

fn sky_head_model_agrees(file: &str, io: &str, blocks: &[usize]) {
    use nimbus_rpnn::ort_backend::OrtModel;
    let m = Rpnn::load(&data(file)).unwrap();
    assert_eq!(
        (m.outputs, m.sky_coeffs(), m.outputs_per_query()),
        (1, 25, 26)
    );
    assert_eq!(m.sky_head.len(), 3);
    assert_eq!(m.sky_blocks, blocks, "{file}");
    assert_eq!(m.sky_head[0].inputs, m.width * blocks.len(), "{file}");
    let plain = Rpnn::load(&data("rpnn-tiny.onnx")).unwrap();
    assert!(plain.sky_head.is_empty() && plain.outputs_per_query() == 1);
    let f = std::fs::File::open(data(io)).unwrap();
    let npy = npyz::NpyFile::new(std::io::BufReader::new(f)).unwrap();
    let cols = npy.shape()[1] as usize;
    assert_eq!(cols, 2251 + 26);
    let v: Vec<f32> = npy.into_vec().unwrap();
    let rows: Vec<&[f32]> = v.chunks(cols).collect();
    let flat: Vec<f32> = rows
        .iter()
        .flat_map(|r| r[..2251].iter().copied())
        .collect();
    let mut ort = OrtModel::load(&data(file), 1).unwrap();
    let got = ort.predict(&flat, rows.len()).unwrap();
    assert_eq!(got.len(), rows.len() * 26);
    let scale = rows
        .iter()
        .flat_map(|r| r[2251..].iter())
        .fold(0.0f32, |a, v| a.max(v.abs()))
        .max(1.0);
    for (i, r) in rows.iter().enumerate() {
        let cpu = m.forward(&r[..2251]);
        assert_eq!(cpu.len(), 26);
        assert_eq!(cpu[0], plain.forward(&r[..2251])[0], "row {i}: sun column");
        for j in 0..26 {
            let (t, o, c) = (r[2251 + j], got[i * 26 + j], cpu[j]);
            assert!(
                (o - t).abs() <= 1e-5 * scale,
                "row {i} col {j}: ort {o} vs torch {t}"
            );
            assert!(
                (o - c).abs() <= 1e-5 * scale,
                "row {i} col {j}: ort {o} vs cpu {c}"
            );
        }
    }
}

/// The network with f16 weights and hidden activations (f32 accumulation) against ONNX Runtime
/// (f32): the shipped models, sun and sky head, on 70 GPU descriptors of a generated cloud,
/// compared as a render uses them (the sun head's value; the sky head's transfer contracted
/// with a clear sky in each query's frame). f16 keeps 11 significant bits (relative rounding
/// 4.9e-4 per stored value); through 23 layers of 200-wide sums the errors partly average
/// out: the bound is 0.5 % of the values' scale per value (ten rounding steps) and 0.1 % for
/// their mean (a systematic shift), against 1e-4 for f32.
#[test]
fn f16_network_agrees_with_onnx_runtime_within_its_tolerance() {
    use nimbus_rpnn::descriptors;
    use nimbus_rpnn::gpu_mlp::{GpuRpnn, NetOptions, Precision, Tiles};
    use nimbus_rpnn::ort_backend::OrtModel;
    let Some(gpu) = nimbus_gpu::testing::gpu(
        "model::f16_network_agrees_with_onnx_runtime_within_its_tolerance",
    ) else {
        return;
    };
    let (pyr, configs) = cloud_configs(6, [0.41, 0.13, 0.29]);
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models");
    for model_path in [models.join("rpnn-hg.onnx"), models.join("rpnn-hg-sky.onnx")] {
        let model = Rpnn::load(&model_path).unwrap();
        // The 64 × 64 kernel here, the default 64 × 128 one below.
        let square = NetOptions {
            precision: Precision::F16,
            tiles: Tiles::Square,
        };
        let mut g = GpuRpnn::with_options(&gpu, &pyr, &model, 64, square).unwrap();
        let got = g.predict(&configs).unwrap();
        let mut f32net = GpuRpnn::new(&gpu, &pyr, &model, 64).unwrap();
        let exact = f32net.predict(&configs).unwrap();
        let desc = descriptors(&pyr, &configs);
        let mut ort = OrtModel::load(&model_path, 1).unwrap();
        let want = ort.predict(&desc, configs.len()).unwrap();
        // What a render uses: the sun head's value, and the sky head's transfer contracted with
        // a sky (the clear-sky model, every degree) in each query's frame.
        let per = model.outputs_per_query();
        let sky = nimbus_rpnn::sky::SkyModel {
            sun_elevation_deg: 30.0,
            sun_azimuth_deg: 40.0,
            turbidity: 3.0,
            zenith: glam::DVec3::new(0.1, 0.2, 0.45),
            ground: glam::DVec3::splat(0.05),
        };
        let c = nimbus_rpnn::sky::project(|d| sky.radiance(d), 32);
        let used = |y: &[f32]| -> Vec<f32> {
            y.chunks(per)
                .zip(&configs)
                .flat_map(|(row, cfg)| {
                    let mut v = vec![row[0]];
                    if per > model.outputs {
                        let (ex, ey, ez) = nimbus_rpnn::descriptor::frame(cfg.view, cfg.to_light);
                        let frame = (ex.as_dvec3(), ey.as_dvec3(), ez.as_dvec3());
                        let l =
                            nimbus_rpnn::sky::product_in_frame(&row[model.outputs..], &c, frame, 4);
                        v.push(l.y as f32);
                    }
                    v
                })
                .collect()
        };
        let (got, exact, want) = (used(&got), used(&exact), used(&want));
        let d = max_rel(&got, &want);
        let mean = |v: &[f32]| v.iter().map(|x| *x as f64).sum::<f64>() / v.len() as f64;
        let shift = (mean(&got) - mean(&want)).abs() / mean(&want).abs().max(1e-6);
        eprintln!(
            "{}: f16 max rel {d:.2e}, mean shift {shift:.2e}; f32 max rel {:.2e}",
            model_path.display(),
            max_rel(&exact, &want)
        );
        // Measured: 1.1e-3 and 4.8e-4 (sun head), 7.3e-4 and 1.7e-4 (sky head).
        assert!(d <= 5e-3, "{}: {d}", model_path.display());
        assert!(shift <= 1e-3, "{}: {shift}", model_path.display());
        // f16 does round: it is not the f32 network under another name.
        assert!(max_rel(&got, &exact) > 1e-6);
        // The 64 × 128 kernel in f16: the same bounds (the same sums, but a compiler may fuse
        // multiply-adds differently, so an f16 rounding of a hidden value may fall the other
        // way).
        let opts = NetOptions {
            precision: Precision::F16,
            tiles: Tiles::Wide,
        };
        let mut wide = GpuRpnn::with_options(&gpu, &pyr, &model, 64, opts).unwrap();
        let got_wide = used(&wide.predict(&configs).unwrap());
        let d = max_rel(&got_wide, &want);
        let shift = (mean(&got_wide) - mean(&want)).abs() / mean(&want).abs().max(1e-6);
        assert!(d <= 5e-3, "{} wide: {d}", model_path.display());
        assert!(shift <= 1e-3, "{} wide: {shift}", model_path.display());
    }
}

/// The f16 network against ONNX Runtime on held-out test records (`tests/data/heldout64`:
/// 64 records of the sky head's test set from all 30 of its clouds, none seen in training):
/// the shipped sky model's sun output and its sky transfer contracted with a
/// clear sky in each record's frame. On all 3 000 records of that set (`examples/f16_records`)
/// the per-record difference was 2.9e-4 median and 1.9e-3 at most for the sun, 1.3e-4 and
/// 1.8e-3 for the sky, mean ratio 1.00026, and the error against the labels moved from 6.71 %
/// to 6.69 % median. Bounds: 1e-3 median and 5e-3 largest difference, mean ratio within 1e-3,
/// the median error against the labels within 0.2 points of ONNX Runtime's.
#[test]
fn f16_network_on_held_out_records() {
    use nimbus_rpnn::gpu_mlp::{GpuMlp, Precision};
    use nimbus_rpnn::ort_backend::OrtModel;
    let Some(gpu) = nimbus_gpu::testing::gpu("model::f16_network_on_held_out_records") else {
        return;
    };
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/heldout64");
    let read = |name: &str| -> Vec<f32> {
        let f = std::fs::File::open(dir.join(name)).unwrap();
        let npy = npyz::NpyFile::new(std::io::BufReader::new(f)).unwrap();
        if name == "x.npy" {
            let v: Vec<half::f16> = npy.into_vec().unwrap();
            v.iter().map(|h| h.to_f32()).collect()
        } else {
            npy.into_vec().unwrap()
        }
    };
    let (x, y, frames) = (read("x.npy"), read("y.npy"), read("frame.npy"));
    let n = y.len();
    assert_eq!((n, x.len(), frames.len()), (64, 64 * 2251, 64 * 6));
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rpnn-hg-sky.onnx");
    let model = Rpnn::load(&path).unwrap();
    let per = model.outputs_per_query();
    let f16 = GpuMlp::with_precision(&gpu, &model, 64, Precision::F16)
        .unwrap()
        .predict(&x, n)
        .unwrap();
    let want = OrtModel::load(&path, 1).unwrap().predict(&x, n).unwrap();
    let sky = nimbus_rpnn::sky::SkyModel {
        sun_elevation_deg: 30.0,
        sun_azimuth_deg: 40.0,
        turbidity: 3.0,
        zenith: glam::DVec3::new(0.08, 0.16, 0.36),
        ground: glam::DVec3::new(0.06, 0.055, 0.05),
    };
    let c = nimbus_rpnn::sky::project(|d| sky.radiance(d), 32);
    // What a render uses of each record: the sun's value and the contracted sky.
    let used = |p: &[f32]| -> (Vec<f32>, Vec<f32>) {
        (0..n)
            .map(|i| {
                let r = &frames[i * 6..i * 6 + 6];
                let view = glam::Vec3::new(r[0], r[1], r[2]);
                let light = glam::Vec3::new(r[3], r[4], r[5]);
                let (ex, ey, ez) = nimbus_rpnn::descriptor::frame(view, light);
                let frame = (ex.as_dvec3(), ey.as_dvec3(), ez.as_dvec3());
                let t = &p[i * per + model.outputs..(i + 1) * per];
                let l = nimbus_rpnn::sky::product_in_frame(t, &c, frame, 4);
                (p[i * per], l.y as f32)
            })
            .unzip()
    };
    let ((sun16, sky16), (sun32, sky32)) = (used(&f16), used(&want));
    let diffs = |a: &[f32], b: &[f32]| -> Vec<f64> {
        let scale = b.iter().map(|v| v.abs() as f64).sum::<f64>() / b.len() as f64;
        let mut d: Vec<f64> = a
            .iter()
            .zip(b)
            .map(|(p, q)| (p - q).abs() as f64 / (q.abs() as f64).max(scale))
            .collect();
        d.sort_by(f64::total_cmp);
        d
    };
    let mean = |v: &[f32]| v.iter().map(|x| *x as f64).sum::<f64>() / v.len() as f64;
    for (name, a, b) in [("sun", &sun16, &sun32), ("sky", &sky16, &sky32)] {
        let d = diffs(a, b);
        let (median, largest) = (d[d.len() / 2], d[d.len() - 1]);
        let ratio = mean(a) / mean(b);
        eprintln!(
            "{name}: f16 against ONNX Runtime median {median:.2e}, largest {largest:.2e}, mean ratio {ratio:.6}"
        );
        assert!(median <= 1e-3, "{name}: median {median}");
        assert!(largest <= 5e-3, "{name}: largest {largest}");
        assert!((ratio - 1.0).abs() <= 1e-3, "{name}: mean ratio {ratio}");
        assert!(largest > 0.0, "{name}: f16 rounds");
    }
    let label_error = |p: &[f32]| -> f64 {
        let mut e: Vec<f64> = p
            .iter()
            .zip(&y)
            .filter(|(_, t)| **t > 0.0)
            .map(|(v, t)| ((v - t) / t).abs() as f64)
            .collect();
        e.sort_by(f64::total_cmp);
        e[e.len() / 2]
    };
    let (e16, e32) = (label_error(&sun16), label_error(&sun32));
    eprintln!("against the labels: median error f16 {e16:.4}, ONNX Runtime {e32:.4}");
    assert!((e16 - e32).abs() <= 0.002, "{e16} against {e32}");
    // The network is the trained one: on held-out clouds its error is the card's (6.7 % median
    // over 3 000 records), far from an untrained or mismatched model's.
    assert!(e32 < 0.15, "{e32}");
}

/// The int8 copies of the shipped models (`training/quantize.py`, `--backend ort-int8`, beyond
/// the paper) against the f32 models they were made from, both in ONNX Runtime, on 210
/// descriptors of a generated cumulus, in one batch and split as a render splits them (two
/// workers, here in pieces of 64; the copy scales activations per run, so the split changes its
/// answers slightly, by less than the bounds below, and the same split gives the same answers).
/// On 3 000 test records quantize.py measured the sun output's difference at 0.6 % median,
/// 3.9 % at the 95th percentile and a mean ratio of 1.0007 (BENCHMARKS.md, "The int8
/// network"); the bounds below are those with room for 210 rows: median ≤ 2 %, mean ratio
/// within 1 %. A copy of the wrong model, a file that is no copy, and a missing copy are
/// refused, naming the file and the command that makes it.
#[test]
fn int8_copies_agree_with_their_models_and_refuse_others() {
    use nimbus_rpnn::descriptor::DESCRIPTOR_LEN;
    use nimbus_rpnn::descriptors;
    use nimbus_rpnn::ort_backend::{Cores, OrtModel, int8_path_for};
    let mut desc = Vec::new();
    let mut rows = 0;
    for (seed, f) in [
        (5, [0.37, 0.11, 0.23]),
        (6, [0.13, 0.29, 0.41]),
        (7, [0.21, 0.17, 0.07]),
    ] {
        let (pyr, configs) = cloud_configs(seed, f);
        desc.extend(descriptors(&pyr, &configs));
        rows += configs.len();
    }
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models");
    for name in ["rpnn-hg", "rpnn-hg-sky", "rpnn-mie"] {
        let f32_path = models.join(format!("{name}.onnx"));
        let a = OrtModel::load(&f32_path, 1)
            .unwrap()
            .predict(&desc, rows)
            .unwrap();
        let mut q = OrtModel::load_int8(&f32_path, 1).unwrap_or_else(|e| panic!("{e}"));
        let b = q.predict(&desc, rows).unwrap();
        let mut w = OrtModel::load_int8(&f32_path, Cores::Workers(2)).unwrap();
        w.rows_per_run = 64;
        let copy = |i: usize, row: &mut [f32]| {
            row.copy_from_slice(&desc[i * DESCRIPTOR_LEN..(i + 1) * DESCRIPTOR_LEN])
        };
        let (split, _) = w.predict_rows(rows, DESCRIPTOR_LEN, copy).unwrap();
        let (again, _) = w.predict_rows(rows, DESCRIPTOR_LEN, copy).unwrap();
        assert_eq!(split, again, "{name}: the same split, other answers");
        let cols = a.len() / rows;
        let sun = |v: &[f32]| (0..rows).map(|r| v[r * cols] as f64).collect::<Vec<_>>();
        let sa = sun(&a);
        for (how, got) in [("one batch", &b), ("two workers", &split)] {
            let sb = sun(got);
            let mut rel: Vec<f64> = sa
                .iter()
                .zip(&sb)
                .filter(|(x, _)| **x > 0.0)
                .map(|(x, y)| (y / x - 1.0).abs())
                .collect();
            assert!(rel.len() > rows / 2, "{name}: the sun output is mostly 0");
            rel.sort_by(f64::total_cmp);
            let median = rel[rel.len() / 2];
            let ratio = sb.iter().sum::<f64>() / sa.iter().sum::<f64>();
            eprintln!("{name}, {how}: int8 against f32: median {median:.4}, mean ratio {ratio:.4}");
            assert!(
                median <= 0.02,
                "{name}, {how}: median relative difference {median}"
            );
            assert!(
                (ratio - 1.0).abs() <= 0.01,
                "{name}, {how}: mean ratio {ratio}"
            );
            assert_ne!(
                &a, got,
                "{name}, {how}: the copy computes what the model does, to the bit"
            );
        }
    }
    let dir = std::env::temp_dir().join(format!("nimbus-int8-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let tiny = dir.join("rpnn-tiny.onnx");
    std::fs::copy(data("rpnn-tiny.onnx"), &tiny).unwrap();
    let err = |p: &Path| match OrtModel::load_int8(p, 1) {
        Ok(_) => panic!("{}: accepted", p.display()),
        Err(e) => e.to_string(),
    };
    // Missing.
    let e = err(&tiny);
    assert!(
        e.contains("rpnn-tiny.int8.onnx") && e.contains("training/quantize.py"),
        "{e}"
    );
    // A copy of another model.
    std::fs::copy(models.join("rpnn-hg.int8.onnx"), int8_path_for(&tiny)).unwrap();
    let e = err(&tiny);
    assert!(
        e.contains("made from another model") && e.contains("quantize.py"),
        "{e}"
    );
    // An f32 model under the copy's name: no metadata saying what it was made from.
    std::fs::copy(data("rpnn-micro.onnx"), int8_path_for(&tiny)).unwrap();
    let e = err(&tiny);
    assert!(e.contains("not an int8 copy"), "{e}");
    // The copy given as the model: refused by the ONNX Runtime loader and by the model reader
    // (which every render reads first), naming the file.
    let copy = models.join("rpnn-hg.int8.onnx");
    let e = err(&copy);
    assert!(
        e.contains("rpnn-hg.int8.onnx") && e.contains("an int8 copy already"),
        "{e}"
    );
    let e = Rpnn::load(&copy)
        .map(|_| ())
        .expect_err("an int8 copy is no RPNN graph")
        .to_string();
    assert!(
        e.contains("rpnn-hg.int8.onnx") && e.contains("pass the f32 model"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn ort_workers_and_pieces_reproduce_one_run() {
    use nimbus_rpnn::ort_backend::{Cores, OrtModel, ROWS_PER_RUN};
    // The paper-sized shipped model: its products go through the same kernels as a render's.
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rpnn-hg.onnx");
    let (xs, _) = fixture_io();
    let cols = xs[0].len();
    // Real descriptors, scaled per query so that neighbouring rows differ.
    let row = |i: usize, out: &mut [f32]| {
        let s = 1.0 + (i % 7) as f32 * 0.15;
        for (o, x) in out.iter_mut().zip(&xs[i % xs.len()]) {
            *o = x * s;
        }
    };
    // Two whole pieces and a part of one, split unevenly among 2 and 3 workers.
    let n = 2 * ROWS_PER_RUN + 37;
    let mut flat = vec![0.0; n * cols];
    for (i, r) in flat.chunks_mut(cols).enumerate() {
        row(i, r);
    }
    let mut one = OrtModel::load(&model, 1).unwrap_or_else(|e| panic!("{e}"));
    let want = one.predict(&flat, n).unwrap();
    let outs = want.len() / n;
    assert!(outs >= 1 && want.len() == n * outs);
    // The outputs differ from query to query, so a share or piece out of place shows.
    let distinct = (1..n)
        .filter(|&i| want[i * outs] != want[(i - 1) * outs])
        .count();
    assert!(
        distinct > n / 2,
        "{distinct} of {n} outputs differ from the one before"
    );
    // An f32 model's outputs do not depend on the split: compared to the bit (NaN included).
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for cores in [Cores::Pool(0), Cores::Workers(2), Cores::Workers(3)] {
        let mut m = OrtModel::load(&model, cores).unwrap();
        let (got, t) = m.predict_rows(n, cols, row).unwrap();
        assert_eq!(bits(&got), bits(&want), "{cores:?}");
        assert!(t.rows_ms > 0.0 && t.network_ms > 0.0, "{t:?}");
        // Fewer queries than workers (shares of 0 and 1 row: runs of one row), and none.
        let (few, _) = m.predict_rows(2, cols, row).unwrap();
        assert_eq!(bits(&few), bits(&want[..2 * outs]), "{cores:?}, 2 queries");
        let (none, t) = m.predict_rows(0, cols, row).unwrap();
        assert!(none.is_empty() && t.network_ms == 0.0);
        // Rows of no inputs are an error, not a panic.
        assert!(m.predict_rows(3, 0, |_, _| {}).is_err());
    }
    // An absurd number of workers is refused, naming the model, before any session is made.
    let e = OrtModel::load(
        &model,
        Cores::Workers(nimbus_rpnn::ort_backend::MAX_WORKERS + 1),
    )
    .err()
    .expect("refused")
    .to_string();
    assert!(
        e.contains("rpnn-hg.onnx") && e.contains("worker sessions"),
        "{e}"
    );
}
