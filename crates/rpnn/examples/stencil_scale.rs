//! Descriptors of stored shading configurations with the stencil scaled by S, for the A/B of
//! `training/experiments/stencil_ab.py` (BENCHMARKS.md, "One million mixed records").
//!
//! `stencil_scale CLOUDS.json CFG S OUT`: CLOUDS.json is a record set's `clouds` list, CFG rows
//! of 10 little-endian f32 (cloud index, x, view, direction to the light), OUT rows of 2 251
//! f32, from `descriptor::descriptor_scaled` (Kallweit 2017 §4.2 with level k's points
//! S · 0.5 · 2^(k−1) mean free paths apart; S = 1 is the stored records' descriptor).
use glam::Vec3;
use nimbus_rpnn::data::clouds::{CloudSpec, build_volume};
use nimbus_rpnn::descriptor::{DESCRIPTOR_LEN, descriptor_scaled};
use nimbus_rpnn::pyramid::Pyramid;
use rayon::prelude::*;

fn main() {
    if let Err(e) = run() {
        eprintln!("stencil_scale: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), String> {
    let a: Vec<String> = std::env::args().collect();
    let [_, clouds_path, cfg_path, scale, out_path] = &a[..] else {
        return Err("usage: stencil_scale CLOUDS.json CFG SCALE OUT".into());
    };
    let read = |p: &str| std::fs::read(p).map_err(|e| format!("{p}: {e}"));
    let clouds: Vec<CloudSpec> = serde_json::from_slice(&read(clouds_path)?)
        .map_err(|e| format!("{clouds_path}: not a record set's clouds list: {e}"))?;
    let raw = read(cfg_path)?;
    if raw.len() % 40 != 0 {
        return Err(format!(
            "{cfg_path}: {} bytes, not rows of 10 f32",
            raw.len()
        ));
    }
    let cfg: Vec<f32> = raw
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let s: f32 = match scale.parse() {
        Ok(s) if s > 0.0 && f32::is_finite(s) => s,
        _ => return Err(format!("SCALE {scale}: expected a positive number")),
    };
    let n = cfg.len() / 10;
    let mut used = std::collections::BTreeSet::new();
    for (i, r) in cfg.chunks_exact(10).enumerate() {
        if !r.iter().all(|v| v.is_finite()) || r[0] < 0.0 || r[0] as usize >= clouds.len() {
            return Err(format!(
                "{cfg_path}: row {i}: a non-finite value or no such cloud"
            ));
        }
        used.insert(r[0] as usize);
    }
    let pyrs: std::collections::BTreeMap<usize, Pyramid> = used
        .into_par_iter()
        .map(|c| {
            let v = build_volume(&clouds[c]).map_err(|e| format!("{clouds_path}: {e}"))?;
            let p = Pyramid::with_every_level(&v)
                .map_err(|e| format!("{clouds_path}: cloud {}: {e}", clouds[c].name))?;
            Ok((c, p))
        })
        .collect::<Result<_, String>>()?;
    let mut out = vec![0f32; n * DESCRIPTOR_LEN];
    out.par_chunks_mut(DESCRIPTOR_LEN)
        .zip(cfg.par_chunks_exact(10))
        .for_each(|(row, r)| {
            let v = |j: usize| Vec3::new(r[j], r[j + 1], r[j + 2]);
            descriptor_scaled(&pyrs[&(r[0] as usize)], v(1), v(4), v(7), s, row);
        });
    let bytes: Vec<u8> = out.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(out_path, bytes).map_err(|e| format!("{out_path}: {e}"))
}
