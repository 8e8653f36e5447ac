//! Descriptors of stored shading configurations with the stencil scaled by S, for the A/B of
//! `training/experiments/stencil_ab.py` (BENCHMARKS.md, "One million mixed records").
//!
//! `stencil_scale CLOUDS.json CFG S OUT`: CLOUDS.json is a record set's `clouds` list, CFG rows
//! of 10 little-endian f32 (cloud index, x, view, direction to the light), OUT rows of 2 251
//! f32, from `descriptor::descriptor_scaled` (Kallweit 2017 §4.2 with level k's points
//! S · 0.5 · 2^(k−1) mean free paths apart; S = 1 is the stored records' descriptor).
use glam::Vec3;
use nimbus_rpnn::clouds::{CloudSpec, build_volume};
use nimbus_rpnn::descriptor::{DESCRIPTOR_LEN, descriptor_scaled};
use nimbus_rpnn::pyramid::Pyramid;
use rayon::prelude::*;
use std::io::Write;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let clouds: Vec<CloudSpec> =
        serde_json::from_str(&std::fs::read_to_string(&a[1]).unwrap()).unwrap();
    let raw = std::fs::read(&a[2]).unwrap();
    let cfg: Vec<f32> = raw
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let s: f32 = a[3].parse().unwrap();
    let n = cfg.len() / 10;
    let used: std::collections::BTreeSet<usize> = (0..n).map(|i| cfg[i * 10] as usize).collect();
    let pyrs: std::collections::BTreeMap<usize, Pyramid> = used
        .par_iter()
        .map(|&c| {
            let v = build_volume(&clouds[c]).unwrap();
            (c, Pyramid::with_every_level(&v).unwrap())
        })
        .collect();
    let len = DESCRIPTOR_LEN;
    let mut out = vec![0f32; n * len];
    out.par_chunks_mut(len).enumerate().for_each(|(i, row)| {
        let r = &cfg[i * 10..i * 10 + 10];
        let v = |j: usize| Vec3::new(r[j], r[j + 1], r[j + 2]);
        descriptor_scaled(&pyrs[&(r[0] as usize)], v(1), v(4), v(7), s, row);
    });
    let mut f = std::io::BufWriter::new(std::fs::File::create(&a[4]).unwrap());
    for v in out {
        f.write_all(&v.to_le_bytes()).unwrap();
    }
}
