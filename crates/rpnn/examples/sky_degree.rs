//! What a spherical-harmonic degree keeps of a sky (`nimbus_rpnn::sky`), two ways:
//! 1. the sky's own energy ∫ |L|² dω kept by degrees 0 … 4 (Parseval), for a constant sky and
//!    the clear-sky model (`SkyModel`) at several sun elevations and turbidities;
//! 2. what the product with real transfers keeps: for held-out records with the sky's transfer
//!    (`nimbus datagen --sky-transfer`, test split), the indirect radiance Σ t_lm c_lm of each
//!    sky up to degree L against degree 4, median and 95th percentile of the relative change
//!    over the records (each record's sky rotated into its frame).
//!
//!     cargo run --release -p nimbus-rpnn --example sky_degree [RECORD_SET]

use glam::DVec3;
use nimbus_rpnn::sky::{self, SH_COEFFS, SH_DEGREE, SkyModel};

/// A named sky: radiance by direction.
type NamedSky = (String, Box<dyn Fn(DVec3) -> DVec3>);

fn skies() -> Vec<NamedSky> {
    let mut v: Vec<NamedSky> = vec![(
        "constant".to_string(),
        Box::new(|_| DVec3::new(0.12, 0.2, 0.38)),
    )];
    for (el, turb) in [(10.0, 2.0), (30.0, 3.0), (30.0, 8.0), (60.0, 3.0)] {
        let m = SkyModel {
            sun_elevation_deg: el,
            sun_azimuth_deg: 40.0,
            turbidity: turb,
            zenith: DVec3::new(0.08, 0.16, 0.36),
            ground: DVec3::new(0.06, 0.055, 0.05),
        };
        v.push((
            format!("clear sky, sun {el}°, turbidity {turb}"),
            Box::new(move |d| m.radiance(d)),
        ));
    }
    v
}

fn main() {
    println!("| sky | kept energy, degree 0 | 1 | 2 | 3 | 4 |\n|---|---:|---:|---:|---:|---:|");
    for (name, f) in skies() {
        let e: Vec<String> = (0..=SH_DEGREE)
            .map(|l| format!("{:.4}", sky::kept_energy(&f, l, 64)))
            .collect();
        println!("| {name} | {} |", e.join(" | "));
    }
    let Some(set) = std::env::args().nth(1) else {
        return;
    };
    let dir = std::path::Path::new(&set);
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).unwrap();
    let mut rows: Vec<Vec<f32>> = Vec::new();
    for s in manifest["shards"].as_array().unwrap() {
        let f = std::fs::File::open(dir.join(s["meta"].as_str().unwrap())).unwrap();
        let npy = npyz::NpyFile::new(std::io::BufReader::new(f)).unwrap();
        let cols = npy.shape()[1] as usize;
        assert_eq!(cols, 15 + SH_COEFFS, "a set made with --sky-transfer");
        let v: Vec<f32> = npy.into_vec().unwrap();
        rows.extend(v.chunks(cols).map(<[f32]>::to_vec));
    }
    println!(
        "\n{} records of {set}: relative change of Σ t_lm c_lm up to degree L against degree 4\n",
        rows.len()
    );
    println!("| sky | L = 0: median / p95 | L = 1 | L = 2 | L = 3 |\n|---|---:|---:|---:|---:|");
    for (name, f) in skies() {
        let world = sky::project(&f, 64);
        let mut changes: Vec<Vec<f64>> = vec![Vec::new(); SH_DEGREE];
        for r in &rows {
            let view = DVec3::new(r[4] as f64, r[5] as f64, r[6] as f64);
            let light = DVec3::new(r[7] as f64, r[8] as f64, r[9] as f64);
            let (ex, ey, ez) = nimbus_rpnn::descriptor::frame(view.as_vec3(), light.as_vec3());
            let local = sky::rotate_to_frame(&world, (ex.as_dvec3(), ey.as_dvec3(), ez.as_dvec3()));
            let t = &r[15..15 + SH_COEFFS];
            let full = sky::apply(t, &local, SH_DEGREE).element_sum();
            if full.abs() < 1e-12 {
                continue;
            }
            for (l, c) in changes.iter_mut().enumerate() {
                c.push((sky::apply(t, &local, l).element_sum() / full - 1.0).abs());
            }
        }
        let cells: Vec<String> = changes
            .iter_mut()
            .map(|c| {
                c.sort_by(f64::total_cmp);
                let q = |p: f64| c[((c.len() as f64 - 1.0) * p) as usize];
                format!("{:.4} / {:.4}", q(0.5), q(0.95))
            })
            .collect();
        println!("| {name} | {} |", cells.join(" | "));
    }
}
