//! The int8 copy's runs at a sample's sizes (`ort_backend::INT8_ROWS_PER_RUN`): batches of
//! 200, 648, 1 297 and 12 175 queries of the demo cumulus through `OrtModel::predict_rows` on
//! one single-threaded session per core, cut as an f32 model's batch is (each worker's share in
//! pieces of at most 1 024) and as an int8 copy's is (by the batch's size alone, in pairs of
//! pieces of at most 256, so that any number of cores gives the same answers). Two rounds of
//! each; median and 10th percentile of the µs per query.
//!
//! `cargo run --release -p nimbus-rpnn --example int8_split`
#[path = "../benches/common/mod.rs"]
mod common;
use nimbus_rpnn::descriptor::{DESCRIPTOR_LEN, descriptor};
use nimbus_rpnn::ort_backend::{Cores, OrtModel};
use std::time::Instant;
fn main() {
    let model = common::root().join("models/rpnn-hg-sky.onnx");
    let (pyr, configs) = common::demo_configs(16384);
    let fill = |i: usize, row: &mut [f32]| {
        let c = &configs[i];
        descriptor(&pyr, c.x, c.view, c.to_light, row)
    };
    let mut m = OrtModel::load_int8(&model, Cores::Workers(0)).unwrap();
    for n in [200usize, 648, 1297, 12175] {
        let reps = (200_000 / n).max(5);
        for round in 0..2 {
            for (label, int8, rows) in [
                ("per worker, ≤ 1 024 (f32)", false, 1024),
                ("by n, pairs of ≤ 256 (int8)", true, 256),
            ] {
                m.int8 = int8;
                m.rows_per_run = rows;
                let mut ts = Vec::new();
                for _ in 0..reps {
                    let c = Instant::now();
                    m.predict_rows(n, DESCRIPTOR_LEN, fill).unwrap();
                    ts.push(c.elapsed().as_secs_f64() * 1e6 / n as f64);
                }
                ts.sort_by(f64::total_cmp);
                println!(
                    "{n} queries, round {round}, {label}: median {:.2} µs per query, 10th percentile {:.2}",
                    ts[ts.len() / 2],
                    ts[ts.len() / 10]
                );
            }
        }
    }
}
