//! Descriptors and ONNX Runtime per query against the piece size and the use of the cores
//! (docs/experiments/2026-12-07-rpnn-sample-rounds.md, "The CPU sample, third round"): 65 536 configurations of the demo cumulus
//! (`scenes/bench/rpnn_720p.toml`, as `cargo bench -p nimbus-rpnn --bench network`), run
//! through `OrtModel::predict_rows` in pieces of 65 536 (a third of a 1280×720 sample at a
//! time) down to 128 queries, once with one session on ONNX Runtime's threads (`Cores::Pool`) and
//! once with one single-threaded session per core (`Cores::Workers`, what a render uses).
//! Each setting runs three times; the table gives the fastest and slowest time per query.
//!
//! `cargo run --release -p nimbus-rpnn --example ort_cores [MODEL.onnx]`
#[path = "../benches/common/mod.rs"]
mod common;

use std::time::Instant;

use nimbus_rpnn::descriptor::{DESCRIPTOR_LEN, descriptor};
use nimbus_rpnn::ort_backend::{Cores, OrtModel};

fn main() {
    let model = std::env::args()
        .nth(1)
        .map(Into::into)
        .unwrap_or_else(|| common::root().join("models/rpnn-hg.onnx"));
    let n = 65_536;
    let (pyr, configs) = common::demo_configs(n);
    let fill = |i: usize, row: &mut [f32]| {
        let c = &configs[i];
        descriptor(&pyr, c.x, c.view, c.to_light, row)
    };
    let mut runners = [("pool", Cores::Pool(0)), ("workers", Cores::Workers(0))].map(|(n, c)| {
        let m = OrtModel::load(&model, c).unwrap_or_else(|e| panic!("{e}"));
        (n, m)
    });
    println!(
        "| queries per run | cores | descriptors, µs per query | network, µs per query | both |"
    );
    println!("|---:|---|---|---|---|");
    for piece in [65_536, 8_192, 2_048, 1_024, 512, 256, 128] {
        for (name, m) in runners.iter_mut() {
            m.rows_per_run = piece;
            let mut runs = Vec::new();
            for _ in 0..3 {
                let clock = Instant::now();
                let (y, t) = m.predict_rows(n, DESCRIPTOR_LEN, fill).unwrap();
                assert!(y.len() >= n);
                let us = |ms: f64| ms * 1e3 / n as f64;
                runs.push((
                    us(t.rows_ms),
                    us(t.network_ms),
                    clock.elapsed().as_secs_f64() * 1e6 / n as f64,
                ));
            }
            let span = |f: fn(&(f64, f64, f64)) -> f64| {
                let lo = runs.iter().map(f).fold(f64::INFINITY, f64::min);
                let hi = runs.iter().map(f).fold(0.0, f64::max);
                format!("{lo:.1}–{hi:.1}")
            };
            println!(
                "| {piece} | {name} ({}) | {} | {} | {} |",
                m.workers(),
                span(|r| r.0),
                span(|r| r.1),
                span(|r| r.2)
            );
        }
    }
}
