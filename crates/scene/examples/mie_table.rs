//! Prints the mean cosine and chopped-peak fraction of the Mie phase function for a few droplet
//! sizes: `cargo run --release -p nimbus-scene --example mie_table`.

use nimbus_scene::phase::mie::{MieParams, compute};

fn main() {
    println!("r_eff_um  g_table  g_series  peak_fraction(chop 5°)");
    for r in [2.0, 5.0, 8.0, 10.0, 15.0] {
        let m = compute(&MieParams {
            effective_radius_um: r,
            chop_deg: 5.0,
            ..Default::default()
        })
        .expect("valid parameters");
        println!(
            "{r:8.1}  {:.4}   {:.4}    {:.4}",
            m.full.mean_cosine(),
            m.series_g,
            m.chopped.as_ref().map_or(0.0, |c| c.peak_fraction)
        );
    }
}
