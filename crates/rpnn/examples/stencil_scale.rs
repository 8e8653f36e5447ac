//! Descriptors of stored shading configurations with the stencil scaled by S, for the A/B of
//! `training/experiments/stencil_ab.py` (BENCHMARKS.md, "One million mixed records").
//!
//! `stencil_scale CLOUDS.json CFG S OUT`: CLOUDS.json is a record set's `clouds` list, CFG rows
//! of 10 little-endian f32 (cloud index, x, view, direction to the light), OUT rows of 2 251
//! f32. Level k's points step S · 0.5 · 2^(k−1) mean free paths and read the pyramid level
//! chosen for that spacing as `Pyramid::level_for` does (Kallweit 2017 §4.2); S = 1 gives
//! `descriptor::descriptor`'s numbers (checked against stored records: equal to their float16
//! rounding, 5e-4 relative).
use glam::Vec3;
use nimbus_rpnn::clouds::{CloudSpec, build_volume};
use nimbus_rpnn::descriptor::{LEVELS, POINTS, frame, stencil_point};
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
    let s: f64 = a[3].parse().unwrap();
    let n = cfg.len() / 10;
    let used: std::collections::BTreeSet<usize> = (0..n).map(|i| cfg[i * 10] as usize).collect();
    let pyrs: std::collections::BTreeMap<usize, Pyramid> = used
        .par_iter()
        .map(|&c| {
            let v = build_volume(&clouds[c]).unwrap();
            (c, Pyramid::with_every_level(&v).unwrap())
        })
        .collect();
    let len = LEVELS * POINTS + 1;
    let mut out = vec![0f32; n * len];
    out.par_chunks_mut(len).enumerate().for_each(|(i, row)| {
        let r = &cfg[i * 10..i * 10 + 10];
        let pyr = &pyrs[&(r[0] as usize)];
        let x = Vec3::new(r[1], r[2], r[3]);
        let (view, l) = (Vec3::new(r[4], r[5], r[6]), Vec3::new(r[7], r[8], r[9]));
        let (ex, ey, ez) = frame(view, l);
        let mfp = 1.0 / pyr.mean_sigma;
        for k in 1..=LEVELS {
            let spacing = s * 0.5 * 2f64.powi(k as i32 - 1) * mfp;
            let h_vox = spacing / pyr.voxel;
            let lv = (h_vox / 2.0).log2().floor();
            let lv = if lv.is_nan() || lv < 0.0 {
                0
            } else {
                (lv as usize).min(pyr.levels.len() - 1)
            };
            let scale = (s * 2f64.powi(k as i32 - 1) * mfp) as f32;
            for p in 0..POINTS {
                let st = stencil_point(p);
                let q = x + (ex * st.x + ey * st.y + ez * st.z) * scale;
                row[(k - 1) * POINTS + p] = pyr.lookup(lv, q);
            }
        }
        let (v, l) = (view.normalize(), l.normalize());
        row[LEVELS * POINTS] = v.cross(l).length().atan2(v.dot(l));
    });
    let mut f = std::io::BufWriter::new(std::fs::File::create(&a[4]).unwrap());
    for v in out {
        f.write_all(&v.to_le_bytes()).unwrap();
    }
}
