//! The volumetric path tracer (the reference estimator).
//!
//! Paths start at the camera and scatter inside the cloud until they leave it:
//! - free flights by delta tracking ([`Tracker::sample_collision`]); σ_s = α σ_t, so a real
//!   collision scatters with weight α (no absorption events: the throughput carries α);
//! - next-event estimation at every scattering vertex: to the sun (delta: one direction; disc:
//!   a uniformly sampled cone direction, MIS with phase sampling) and, for an environment map,
//!   to an importance-sampled sky direction (MIS with phase sampling); the transmittance of each
//!   shadow ray by ratio tracking;
//! - phase-function importance sampling for the next direction (throughput unchanged: p/pdf = 1);
//!   a path that leaves the medium picks up the sky (constant sky: full weight, it has no NEE) and
//!   a finite sun disc with its MIS weight (power heuristic);
//! - Russian roulette on the throughput after [`RR_DEPTH`] scatterings, only where the
//!   throughput has fallen below 1 (α < 1): unbiased, and albedo-1 paths are never cut; they end
//!   by leaving the medium, or at `max_depth` scatterings when one is set, else at the safety cap
//!   [`MAX_SCATTERINGS`]. In an albedo-1 medium of optical depth τ a random walk may take up to
//!   ~τ² scatterings (10¹² for τ = 10⁶, `nimbus stress`); the cap keeps such renders finite. For
//!   clouds (τ ≲ 10³ with g ≈ 0.86, transport depth ≲ 150) paths surviving 2¹⁸ scatterings
//!   have negligible probability (diffusion decay ~e^(−n π² / 3τ_tr²): e^(−38) at n = 2¹⁸), so the
//!   cap does not change the image.
//! - A path whose next vertex is its current one (x + t·d == x in f64: σ_t so large — 10²⁰ per
//!   unit, `nimbus stress` — that free flights fall below the resolution of the coordinates)
//!   cannot move: it ends there, dark (the light an optically infinite albedo-1 medium would
//!   diffuse back out is dropped), and is counted in [`PathStats::stuck`]. Without this such a
//!   walk takes [`MAX_SCATTERINGS`] steps on the spot for every path.
//!
//! With a chopped Mie phase function the first vertex uses the full function and the later
//! segments the reduced density (Kallweit 2017 §3.1), see [`nimbus_scene::Medium`].

use glam::DVec3;
use nimbus_scene::{MajorantGrid, Scene, Sky};

use crate::rng::Pcg32;
use crate::tracking::Tracker;

/// Scatterings after which Russian roulette may end low-throughput paths.
pub const RR_DEPTH: u32 = 8;

/// Scatterings after which a path ends when the scene sets no `max_depth`.
pub const MAX_SCATTERINGS: u32 = 1 << 18;

/// Block size (voxels per majorant cell and axis) of the majorant grid.
pub const MAJORANT_BLOCK: usize = 8;

/// How a path left the medium ([`PathTracer::radiance_after_escape`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Escape {
    /// Path throughput at the escape (albedos and Russian roulette).
    pub beta: f64,
    /// The direction it left along (the sky seen along it).
    pub dir: DVec3,
    /// Scattering events on the path, the starting vertex's count included.
    pub scatterings: u32,
}

/// Counters of one path.
#[derive(Debug, Default, Clone, Copy)]
pub struct PathStats {
    pub scatterings: u64,
    /// Paths that ended because their next vertex was their current one (see the module docs).
    pub stuck: u64,
}

/// The path tracer for one scene.
pub struct PathTracer<'a> {
    pub scene: &'a Scene,
    majorants: std::borrow::Cow<'a, MajorantGrid>,
}

#[inline]
fn power_heuristic(a: f64, b: f64) -> f64 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 { a2 / (a2 + b2) } else { 0.0 }
}

impl<'a> PathTracer<'a> {
    /// A tracer with the default majorant grid ([`MAJORANT_BLOCK`]³-voxel cells).
    pub fn new(scene: &'a Scene) -> Self {
        Self::with_majorants(
            scene,
            MajorantGrid::with_block(&scene.volume, MAJORANT_BLOCK),
        )
    }

    /// A tracer with a given majorant grid (a 1×1×1 grid disables empty-space skipping).
    pub fn with_majorants(scene: &'a Scene, majorants: MajorantGrid) -> Self {
        Self {
            scene,
            majorants: std::borrow::Cow::Owned(majorants),
        }
    }

    /// A tracer over a majorant grid kept elsewhere (a progressive render that outlives its
    /// scene borrows: the grid is built once per density, not per call).
    pub fn borrowing(scene: &'a Scene, majorants: &'a MajorantGrid) -> Self {
        Self {
            scene,
            majorants: std::borrow::Cow::Borrowed(majorants),
        }
    }

    pub fn majorants(&self) -> &MajorantGrid {
        &self.majorants
    }

    /// Radiance arriving at `o` from direction `-d` (the ray `o + t d`).
    pub fn radiance(&self, o: DVec3, d: DVec3, rng: &mut Pcg32, stats: &mut PathStats) -> DVec3 {
        self.radiance_after(o, d, 0, None, rng, stats)
    }

    /// Like [`PathTracer::radiance`] for a path that has already scattered `scatterings` times:
    /// its next segment uses the density and its next vertex the phase function of that depth,
    /// and `first_pdf` (the density of the phase sample that produced `d`, if any) weights MIS
    /// when it escapes. Used to estimate indirect in-scattered radiance inside the medium.
    pub fn radiance_after(
        &self,
        o: DVec3,
        d: DVec3,
        scatterings: u32,
        first_pdf: Option<f64>,
        rng: &mut Pcg32,
        stats: &mut PathStats,
    ) -> DVec3 {
        self.radiance_after_escape(o, d, scatterings, first_pdf, rng, stats, &mut None)
    }

    /// [`PathTracer::radiance_after`], also telling how the path left the medium: `escape`
    /// becomes its throughput, direction and scattering count when it escaped (the same path,
    /// the same random numbers). The RPNN training records read it to estimate the sky's
    /// transfer from the very paths that estimate the sun's (`nimbus_rpnn::data::datagen`).
    #[allow(clippy::too_many_arguments)]
    pub fn radiance_after_escape(
        &self,
        mut o: DVec3,
        mut d: DVec3,
        scatterings: u32,
        first_pdf: Option<f64>,
        rng: &mut Pcg32,
        stats: &mut PathStats,
        escape: &mut Option<Escape>,
    ) -> DVec3 {
        let scene = self.scene;
        let tracker = Tracker::new(&scene.volume, &self.majorants);
        let aabb = scene.volume.aabb();
        let medium = &scene.medium;
        let mut l = DVec3::ZERO;
        let mut beta = 1.0f64;
        let mut scatterings = scatterings;
        // Density (per sr) of the phase sample that produced `d`; None for the camera ray.
        let mut prev_pdf: Option<f64> = first_pdf;
        loop {
            let factor = medium.density_factor(scatterings);
            let collision = aabb
                .intersect(o, d)
                .and_then(|(t0, t1)| tracker.sample_collision(o, d, t0, t1, factor, rng));
            let Some(t) = collision else {
                l += beta * self.escaped(d, prev_pdf);
                *escape = Some(Escape {
                    beta,
                    dir: d,
                    scatterings,
                });
                break;
            };
            if scatterings >= scene.render.max_depth.unwrap_or(MAX_SCATTERINGS) {
                break;
            }
            let x = o + d * t;
            if x == o {
                stats.stuck += 1;
                break;
            }
            scatterings += 1;
            stats.scatterings += 1;
            let (albedo, phase) = medium.vertex(scatterings);
            beta *= albedo;
            if beta <= 0.0 {
                break;
            }
            let shadow_factor = medium.density_factor(scatterings);
            let shadow = |wi: DVec3, rng: &mut Pcg32| -> f64 {
                match aabb.intersect(x, wi) {
                    Some((t0, t1)) => tracker.transmittance(x, wi, t0, t1, shadow_factor, rng),
                    None => 1.0,
                }
            };
            // Next-event estimation: sun.
            if let Some(sun) = &scene.sun {
                if sun.is_delta() {
                    let ph = phase.eval(d.dot(sun.dir));
                    if ph > 0.0 {
                        l += beta * ph * shadow(sun.dir, rng) * sun.irradiance;
                    }
                } else {
                    let (wi, pdf_l) = sun.sample_cone(rng.next2());
                    let ph = phase.eval(d.dot(wi));
                    if ph > 0.0 {
                        let w = power_heuristic(pdf_l, ph);
                        l += beta * ph * w / pdf_l * shadow(wi, rng) * sun.radiance();
                    }
                }
            }
            // Next-event estimation: environment map.
            if let Some(Sky::Env(env)) = &scene.sky
                && let Some((wi, pdf_l)) = env.sample(rng.next2())
            {
                let ph = phase.eval(d.dot(wi));
                if ph > 0.0 && pdf_l > 0.0 {
                    let w = power_heuristic(pdf_l, ph);
                    l += beta * ph * w / pdf_l * shadow(wi, rng) * env.radiance(wi);
                }
            }
            // Phase sampling: p / pdf = 1.
            let s = phase.sample(d, rng.next2());
            o = x;
            d = s.dir;
            prev_pdf = Some(s.pdf);
            if scatterings > RR_DEPTH && beta < 1.0 {
                if rng.next_f64() >= beta {
                    break;
                }
                beta = 1.0;
            }
        }
        l
    }

    /// Radiance of the lights seen along an escaping direction, with MIS weights for the
    /// strategies that also have next-event estimation.
    fn escaped(&self, d: DVec3, prev_pdf: Option<f64>) -> DVec3 {
        let mut le = DVec3::ZERO;
        match &self.scene.sky {
            Some(Sky::Constant(c)) => le += *c,
            Some(Sky::Env(env)) => {
                let w = prev_pdf.map_or(1.0, |p| power_heuristic(p, env.pdf(d)));
                le += env.radiance(d) * w;
            }
            None => {}
        }
        if let Some(sun) = &self.scene.sun
            && sun.contains(d)
        {
            let w = prev_pdf.map_or(1.0, |p| power_heuristic(p, 1.0 / sun.solid_angle()));
            le += sun.radiance() * w;
        }
        le
    }
}
