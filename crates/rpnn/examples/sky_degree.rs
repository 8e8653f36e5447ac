//! What a spherical-harmonic degree keeps of a sky (`nimbus_rpnn::sky`), two ways:
//! 1. the sky's own energy ∫ |L|² dω kept by degrees 0 … 4 (Parseval), and the share of its
//!    varying part (the energy above degree 0) that they keep, for a constant sky, the
//!    clear-sky model (`SkyModel`) at several sun elevations and turbidities, the bench suite's
//!    three environment maps (`sun+env`: 256×128 lat-long maps of `SkyModel`, sun at the
//!    suite's front, side and back placements) and any `.exr` environment map given — maps
//!    projected texel by texel as the renderer does (`sky::project_env`);
//! 2. what the product with real transfers keeps: for held-out records with the sky's transfer
//!    (`nimbus datagen --sky-transfer`, test split), the indirect radiance Σ t_lm c_lm of each
//!    sky up to degree L against degree 4, median and 95th percentile of the relative change
//!    over the records (each record's sky rotated into its frame).
//!
//!     cargo run --release -p nimbus-rpnn --example sky_degree [RECORD_SET] [MAP.exr …]

use glam::DVec3;
use nimbus_rpnn::sky::{self, SH_COEFFS, SH_DEGREE, SkyModel};

/// A named sky: its coefficients in the world and its energy ∫ |L|² dω.
struct NamedSky {
    name: String,
    coeffs: [[f64; 3]; SH_COEFFS],
    energy: f64,
}

/// The clear-sky model's parameters shared by the rows (the bench suite's `sun+env` colours).
fn model(el: f64, az: f64, turb: f64) -> SkyModel {
    SkyModel {
        sun_elevation_deg: el,
        sun_azimuth_deg: az,
        turbidity: turb,
        zenith: DVec3::new(0.08, 0.16, 0.36),
        ground: DVec3::new(0.06, 0.055, 0.05),
    }
}

/// A sky given as a function, by the quadrature of `sky::project` (64 nodes).
fn of_function(name: String, f: impl Fn(DVec3) -> DVec3 + Copy) -> NamedSky {
    // kept_energy(…, 4, …) = Σ|c|² / E: E from the same quadrature.
    let coeffs = sky::project(f, 64);
    let kept4 = sky::kept_energy(f, SH_DEGREE, 64);
    let sum: f64 = coeffs.iter().flatten().map(|v| v * v).sum();
    NamedSky {
        name,
        coeffs,
        energy: if kept4 > 0.0 { sum / kept4 } else { 0.0 },
    }
}

/// A lat-long map, texel by texel (its energy with each texel's exact solid angle).
fn of_map(name: String, env: &nimbus_scene::EnvMap) -> NamedSky {
    let img = env.image();
    let (w, h) = (img.width, img.height);
    let mut energy = 0.0;
    for y in 0..h {
        let omega =
            sky::latlong_cell_solid_angle(w, y as f64 / h as f64, (y + 1) as f64 / h as f64);
        for x in 0..w {
            let p = img.get(x, y);
            let l = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64) * env.scale();
            energy += omega * l.length_squared();
        }
    }
    NamedSky {
        name,
        coeffs: sky::project_env(env),
        energy,
    }
}

fn skies(maps: &[String]) -> Vec<NamedSky> {
    let mut v = vec![of_function("constant".to_string(), |_| {
        DVec3::new(0.12, 0.2, 0.38)
    })];
    for (el, turb) in [(10.0, 2.0), (30.0, 3.0), (30.0, 8.0), (60.0, 3.0)] {
        let m = model(el, 40.0, turb);
        v.push(of_function(
            format!("clear sky, sun {el}°, turbidity {turb}"),
            move |d| m.radiance(d),
        ));
    }
    // The bench suite's maps (`nimbus_eval::suite::env_map`) at its sun directions
    // (`nimbus_eval::suite::Lighting::sun_dir`; that crate depends on this one).
    for (name, d) in [
        ("front", [0.25, 0.5, 1.0]),
        ("side", [1.0, 0.5, 0.0]),
        ("back", [-0.25, 0.5, -1.0]),
    ] {
        let d = DVec3::from_array(d).normalize();
        let m = model(d.y.asin().to_degrees(), d.x.atan2(d.z).to_degrees(), 3.0);
        let env = nimbus_scene::EnvMap::new(m.latlong(256, 128), 1.0).unwrap();
        v.push(of_map(format!("bench suite's `sun+env` map, {name}"), &env));
    }
    for path in maps {
        let env = nimbus_scene::EnvMap::load(std::path::Path::new(path), 1.0)
            .unwrap_or_else(|e| panic!("{path}: {e}"));
        v.push(of_map(path.clone(), &env));
    }
    v
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (maps, sets): (Vec<String>, Vec<String>) =
        args.into_iter().partition(|a| a.ends_with(".exr"));
    let skies = skies(&maps);
    println!(
        "| sky | energy kept, degree 0 | 1 | 2 | 3 | 4 | of the varying part (above degree 0): 1 | 2 | 3 | 4 |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for s in &skies {
        let kept = |l: usize| -> f64 {
            let k: f64 = s.coeffs[..sky::coeffs(l)]
                .iter()
                .flatten()
                .map(|v| v * v)
                .sum();
            if s.energy > 0.0 { k / s.energy } else { 1.0 }
        };
        let e: Vec<String> = (0..=SH_DEGREE).map(|l| format!("{:.4}", kept(l))).collect();
        let varying: Vec<String> = (1..=SH_DEGREE)
            .map(|l| {
                let above0 = 1.0 - kept(0);
                if above0 < 1e-9 {
                    "–".to_string()
                } else {
                    format!("{:.3}", (kept(l) - kept(0)) / above0)
                }
            })
            .collect();
        println!(
            "| {} | {} | {} |",
            s.name,
            e.join(" | "),
            varying.join(" | ")
        );
    }
    let Some(set) = sets.first() else {
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
    for s in &skies {
        let (name, world) = (&s.name, s.coeffs);
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
