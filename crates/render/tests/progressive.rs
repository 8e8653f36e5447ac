//! The progressive interface every front end drives (`Estimator::accumulate`, `change`,
//! `image`): samples added in steps give the image one render of the same budget gives, bit
//! for bit; a change restarts the image with independent samples.

mod common;

use std::path::Path;

use common::{options, scene};
use glam::DVec3;
use nimbus_render::{Change, GpuSlot, Method, NetBackend, Options, prepare};

/// An environment map that is not 2:1 is read as latitude–longitude anyway, with a warning
/// naming its size; a 2:1 map gets none.
#[test]
fn env_maps_that_are_not_two_to_one_are_named() {
    let gpu = GpuSlot::new();
    for (w, h, warned) in [(16, 8, false), (8, 8, true), (24, 4, true)] {
        let mut s = scene();
        let mut img = nimbus_scene::Image::new(w, h);
        img.pixels.fill([0.2, 0.3, 0.5]);
        s.sky = Some(nimbus_scene::Sky::Env(
            nimbus_scene::EnvMap::new(img, 1.0).unwrap(),
        ));
        let est = prepare(&s, Method::Pt, &options(), &gpu).unwrap();
        let said = est
            .warnings
            .iter()
            .any(|m| m.contains("sky.envmap") && m.contains(&format!("{w}×{h}, not 2:1")));
        assert_eq!(said, warned, "{w}×{h}: {:?}", est.warnings);
    }
}

/// For `method`: `steps` samples accumulated after a restart equal a render of 8 (colour and
/// variance, bit for bit); a camera change restarts the count and draws other samples.
fn steps_equal_one_render(method: Method, gpu: &GpuSlot, steps: [u32; 2]) {
    let s = scene();
    let mut est = prepare(&s, method, &options(), gpu).unwrap();
    let one = est.render(8, 9).unwrap();
    est.restart(9).unwrap();
    est.accumulate(steps[0]).unwrap();
    let step = est.accumulate(steps[1]).unwrap();
    assert_eq!(step.spp, 8, "{method}");
    assert_eq!(est.samples(), 8, "{method}");
    let steps = est.image().unwrap();
    assert_eq!(steps.image.pixels, one.image.pixels, "{method}: colour");
    assert_eq!(steps.variance, one.variance, "{method}: variance");
    // The same view after a change of camera: a restart with other random numbers.
    est.change(Change::Camera(s.camera.clone())).unwrap();
    assert_eq!(est.samples(), 0, "{method}");
    est.accumulate(8).unwrap();
    let again = est.image().unwrap();
    assert_ne!(
        again.image.pixels, one.image.pixels,
        "{method}: samples reused"
    );
}

#[test]
fn cpu_path_tracer_and_rpnn_accumulate_in_steps() {
    let gpu = GpuSlot::new();
    steps_equal_one_render(Method::Pt, &gpu, [3, 5]);
    steps_equal_one_render(Method::Rpnn, &gpu, [3, 5]);
}

#[test]
fn gpu_path_tracer_accumulates_in_steps() {
    if !nimbus_gpu::testing::has_adapter("progressive::gpu_path_tracer_accumulates_in_steps") {
        return;
    }
    // The GPU sums each dispatch's 4 samples per invocation in f32 first: steps on those
    // boundaries add in the same order (3 + 5 differ in the last bits).
    steps_equal_one_render(Method::PtGpu, &GpuSlot::new(), [4, 4]);
}

/// A change is taken into the estimator's scene: a new sun direction moves the path tracer's
/// light (the image changes), a new density is rendered from (an empty grid leaves only the
/// sky).
#[test]
fn changes_reach_the_estimator() {
    let gpu = GpuSlot::new();
    let s = scene();
    let mut est = prepare(&s, Method::Pt, &options(), &gpu).unwrap();
    est.accumulate(4).unwrap();
    let before = est.image().unwrap().image;
    est.change(Change::SunDir(DVec3::new(-1.0, 0.2, -0.5)))
        .unwrap();
    assert!(
        (est.scene().sun.as_ref().unwrap().dir - DVec3::new(-1.0, 0.2, -0.5).normalize()).length()
            < 1e-12
    );
    est.accumulate(4).unwrap();
    assert_ne!(est.image().unwrap().image.pixels, before.pixels);
    let v = s.volume.as_ref();
    let empty = nimbus_scene::Volume::new(
        nimbus_scene::DensityGrid::new(v.grid().res(), vec![0.0; v.grid().res().iter().product()])
            .unwrap(),
        *v.aabb(),
        v.density_scale(),
    )
    .unwrap();
    est.change(Change::Density(std::sync::Arc::new(empty)))
        .unwrap();
    est.accumulate(2).unwrap();
    let img = est.image().unwrap().image;
    let sky = s.sky.as_ref().map(|k| match k {
        nimbus_scene::Sky::Constant(c) => *c,
        _ => unreachable!(),
    });
    let sky = sky.unwrap().as_vec3().to_array();
    assert!(
        img.pixels
            .iter()
            .all(|p| (0..3).all(|c| (p[c] - sky[c]).abs() < 1e-6))
    );
}

/// Photon mapping with a renewed ring (`GatherSettings::ring_refresh` = 2): a still scene's
/// accumulation from a full ring traces a new generation before every second sample after the first two (3 in 8
/// samples) and keeps averaging (the count goes on); with 0 the ring stays as built.
#[test]
fn a_still_photon_map_renews_its_ring_when_asked() {
    if !nimbus_gpu::testing::has_adapter(
        "progressive::a_still_photon_map_renews_its_ring_when_asked",
    ) {
        return;
    }
    let gpu = GpuSlot::new();
    let s = scene();
    for (refresh, want) in [(0, 0), (2, 3)] {
        let opts = Options {
            pm_gather: nimbus_photon::GatherSettings {
                ring: 2,
                beams: 1024,
                ring_refresh: refresh,
                ..Default::default()
            },
            ..options()
        };
        let mut est = prepare(&s, Method::Pm, &opts, &gpu).unwrap();
        // A render builds the whole ring; the accumulation starts from it.
        est.render(1, 3).unwrap();
        est.restart(3).unwrap();
        let mut renewals = 0;
        for _ in 0..8 {
            let step = est.accumulate(1).unwrap();
            renewals += step.stages.iter().filter(|(n, _)| *n == "renew").count();
        }
        assert_eq!(renewals, want, "ring_refresh {refresh}");
        assert_eq!(est.samples(), 8, "ring_refresh {refresh}");
    }
}

/// `--backend ort-int8` through the estimator: the shipped sky model's int8 copy is found
/// beside it and named where the render runs; a model without a copy is refused before any
/// sample, naming the missing file and the command that makes it.
#[test]
fn int8_backend_loads_the_copy_beside_the_model() {
    let s = scene();
    let gpu = GpuSlot::new();
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models");
    let mut o = options();
    o.rpnn.backend = NetBackend::OrtInt8;
    o.rpnn.model = Some(models.join("rpnn-hg-sky.onnx"));
    let mut est = prepare(&s, Method::Rpnn, &o, &gpu).unwrap();
    // One single-threaded session per rayon thread.
    let sessions = rayon::current_num_threads();
    let want = if sessions == 1 {
        "ort int8 (cpu: 1 session)".to_string()
    } else {
        format!("ort int8 (cpu: {sessions} sessions)")
    };
    assert_eq!(est.device, want);
    let r = est.render(2, 3).unwrap();
    assert!(r.image.pixels.iter().flatten().all(|v| v.is_finite()));
    o.rpnn.model = options().rpnn.model;
    let e = match prepare(&s, Method::Rpnn, &o, &gpu) {
        Ok(_) => panic!("a model without an int8 copy was accepted"),
        Err(e) => format!("{e:#}"),
    };
    assert!(
        e.contains("rpnn-tiny.int8.onnx") && e.contains("training/quantize.py"),
        "{e}"
    );
}
