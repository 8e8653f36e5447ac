//! What the RPNN benches share: `n` shading configurations at random points of positive
//! density inside the demo cumulus of `scenes/bench/rpnn_720p.toml`, random views, its sun, and
//! the cloud's density pyramid.

use std::path::Path;

use glam::DVec3;
use nimbus_rpnn::descriptor::Config;
use nimbus_rpnn::pyramid::Pyramid;
use nimbus_scene::Scene;
use nimbus_scene::frame::uniform_sphere;
use nimbus_trace::Pcg32;

/// The workspace's root.
pub fn root() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The demo cumulus's pyramid and `n` configurations in it (seeded: the same every run).
pub fn demo_configs(n: usize) -> (Pyramid, Vec<Config>) {
    let scene = Scene::load(root().join("scenes/bench/rpnn_720p.toml")).expect("demo scene");
    let vol = &scene.volume;
    let pyr = Pyramid::new(vol).expect("pyramid");
    let sun = scene.sun.as_ref().expect("the scene has a sun").dir;
    let (lo, hi) = (vol.aabb().min, vol.aabb().max);
    let mut rng = Pcg32::new(7, 0);
    let mut configs = Vec::with_capacity(n);
    while configs.len() < n {
        let (u, v) = (rng.next2(), rng.next2());
        let x = lo + (hi - lo) * DVec3::new(u[0], u[1], v[0]);
        if vol.lookup(x) <= 0.0 {
            continue;
        }
        configs.push(Config {
            x: x.as_vec3(),
            view: uniform_sphere(rng.next2()).as_vec3(),
            to_light: sun.as_vec3(),
        });
    }
    (pyr, configs)
}
