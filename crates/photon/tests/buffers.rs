//! The photon map's buffers: a cache sum that would wrap is an error, not a wrong image, and
//! every buffer has the size of the plan the memory checks sum (`mapper/plan.rs`).

use glam::DVec3;
use nimbus_photon::{PhotonMapper, PmSettings, PmVariant};
use nimbus_scene::{Aabb, Camera, DensityGrid, Sun, Volume};

use crate::common::small_cloud;
use crate::gpu::scene;

/// A cache cell whose u32 sum would wrap is an error naming the remedies, not a silently wrong
/// image: a one-cell cache over a homogeneous box of σ = 10⁷ where every beam that enters
/// scatters until the cap of 1 024 scatterings, each a deposit of 4 096 fixed-point units
/// (≈ 4.2 × 10⁶ per beam): the ≈ 1 000th beam of a 4 096-beam frame overflows 2³² (caught in
/// the trace), and four frames of 1 024 beams overflow only in the ring's total (caught in the
/// update). The same box at σ = 1 (≈ 2 deposits per beam) stays far inside 32 bits.
#[test]
fn cache_overflow_is_an_error() {
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::cache_overflow_is_an_error") else {
        return;
    };
    let mapper = |scale: f64, beams: u32, ring: u32| {
        let grid = DensityGrid::constant([8, 8, 8], 1.0).unwrap();
        let aabb = Aabb::new(DVec3::splat(-0.5), DVec3::splat(0.5)).unwrap();
        let s = scene(
            Volume::new(grid, aabb, scale).unwrap(),
            1.0,
            0.857,
            Some(Sun::new(DVec3::new(0.3, 1.0, 0.2), DVec3::ONE, 0.0).unwrap()),
            None,
            Camera::new(DVec3::new(0.0, 0.0, 3.0), DVec3::ZERO, DVec3::Y, 30.0, 8, 8).unwrap(),
        );
        let pm = PhotonMapper::new(
            &gpu,
            &s,
            PmSettings {
                beams_per_frame: beams,
                ring,
                cache_res: Some([1, 1, 1]),
                ..Default::default()
            },
        )
        .unwrap();
        (pm, s.camera)
    };
    let render = |scale: f64, beams: u32, ring: u32| {
        let (mut pm, camera) = mapper(scale, beams, ring);
        pm.render(&camera).map(|_| ())
    };
    for (beams, ring) in [(4096, 1), (1024, 4)] {
        let e = render(1e7, beams, ring)
            .expect_err("must overflow")
            .to_string();
        assert!(
            e.contains("overflowed") && e.contains("--beams") && e.contains("1×1×1"),
            "{e}"
        );
    }
    render(1.0, 4096, 1).unwrap();
    // A generation that overflows on its own stops the fill at once: one frame traced of a
    // ring of four, not four.
    let (mut pm, _) = mapper(1e7, 4096, 4);
    assert!(pm.converge().is_err());
    assert_eq!(pm.frames(), 1);
}

/// The buffer plan is what is allocated (`mapper/plan.rs`): for the default variant, the
/// paper's, flux lobes split by order, an amortised sun rebuild, skipped empty cells, and light
/// volumes coarser than the grid (the ray marcher's own dense density), every buffer the mapper
/// holds after a render (the image, or the gathering's sums) has the size the memory checks sum.
#[test]
fn the_buffer_plan_is_what_is_allocated() {
    use nimbus_photon::mapper::Buf;
    let Some(gpu) = nimbus_gpu::testing::gpu("gpu::the_buffer_plan_is_what_is_allocated") else {
        return;
    };
    let s = small_cloud();
    let base = PmSettings {
        beams_per_frame: 256,
        ring: 2,
        ..Default::default()
    };
    let configs = [
        base.clone(),
        PmSettings {
            variant: PmVariant::Elek2012,
            ..base.clone()
        },
        PmSettings {
            lobe_axis: Some(nimbus_photon::LobeAxis::Flux),
            lobe_split: Some(2),
            view_dependent: Some(false),
            sun_chunks: 3,
            ..base.clone()
        },
        PmSettings {
            skip_empty: Some(true),
            light_res: Some([12, 9, 12]),
            ..base.clone()
        },
    ];
    let gather = nimbus_photon::GatherSettings {
        ring: 2,
        beams: 256,
        ..Default::default()
    };
    for (k, settings) in configs.into_iter().enumerate() {
        let mut pm = PhotonMapper::new(&gpu, &s, settings).unwrap();
        if k % 2 == 0 {
            pm.render(&s.camera).unwrap();
        } else {
            pm.converge().unwrap();
            pm.upsample();
            let mut g = gather;
            g.bounces = 0;
            pm.gather(&s.camera, &g, 1).unwrap();
        }
        let plan = *pm.plan();
        let mut seen = 0;
        for (b, bytes) in plan.entries() {
            let Some(buf) = pm.buffer(b) else {
                // Only the ray marcher's bricks and an unamortised sun rebuild have none.
                assert!(
                    b == Buf::March || (b == Buf::SunTBack && bytes == 0),
                    "config {k}: {b:?} planned {bytes} bytes but not allocated"
                );
                continue;
            };
            assert_eq!(
                buf.size(),
                bytes.max(4).next_multiple_of(4),
                "config {k}: {b:?}"
            );
            seen += 1;
        }
        // Every buffer but the bricks' and the unamortised back buffer is there.
        assert!(seen >= 16, "config {k}: only {seen} buffers");
        if k == 2 {
            assert!(plan.bytes(Buf::SunTBack) > 0 && plan.bytes(Buf::JHigh) > 16);
        }
        if k == 3 {
            assert!(pm.buffer(Buf::March).is_some() && plan.bytes(Buf::CellSkip) > 4);
        }
    }
}
