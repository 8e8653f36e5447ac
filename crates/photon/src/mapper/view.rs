//! View-dependent cache words (beyond the paper): the in-scattering towards the camera.
//!
//! Elek 2012 reconstructs the radiance a cell scatters towards the camera from an HG lobe per
//! cell (§4.1.2, Appendix C). One lobe cannot hold light that flows two ways at once — into a
//! lit surface along the sun and back out of it, diffusely — and the front- and side-lit views
//! see exactly that backward part: on a τ = 4 and a τ = 20 slab, lit and seen as the held-out
//! stratus, the two flux lobes give 0.59–0.77 of the radiance scattered towards the camera in
//! the first two mean free paths (a Monte Carlo experiment over the photons' directions;
//! BENCHMARKS.md). With the view-dependent words every deposit also adds its phase-function
//! value towards the camera, p(d · ω_v | g) (`photon_trace.wgsl` words 11 and 12): the cell
//! sums are then a collision estimate of the scattered radiance itself, exact in angle, and the
//! only approximation left is the cache's spatial resolution.
//!
//! The words belong to a view point. Each ring slot remembers the one it was traced for; the
//! ray marcher uses them when every slot's view point is within the impostor tolerance of the
//! current camera (Elek §4.4: 5° seen from the cloud, 20 % in distance), and the lobes
//! otherwise — after a camera jump the ring refreshes over m frames, as after a sun change.

use super::*;

/// The impostor criteria's angle (Elek §4.4): view points closer than this, seen from the
/// cloud's centre, share their view-dependent words.
pub const VIEW_TOLERANCE_DEG: f64 = 5.0;
/// The impostor criteria's relative change in distance to the cloud.
pub const VIEW_TOLERANCE_DISTANCE: f64 = 0.2;

impl PhotonMapper<'_> {
    /// Sets the point the view-dependent words are traced for (the camera position); no effect
    /// without them. Slots traced for a point outside the tolerance are replaced over the
    /// following frames; until then the ray marcher uses the lobes.
    pub fn set_view(&mut self, origin: DVec3) {
        // A non-finite point is no view point (it would never be close to any).
        if self.settings.effective_view() && origin.is_finite() {
            self.params.view_origin = f3(origin);
        }
    }

    /// Whether every ring slot that holds beams was traced, with view-dependent words, close to
    /// the current view point (see [`Self::view_close`]), and one does. Empty slots do not
    /// count: the ring's normalisation is by the beams it holds, so a ring still filling up
    /// (the first m frames of an animation) already gives the right radiance, only noisier.
    pub fn view_ready(&self) -> bool {
        let mut any = false;
        for (v, beams) in self.slot_view.iter().zip(&self.slot_beams) {
            if beams.0 + beams.1 == 0 {
                continue;
            }
            match v {
                Some(o) if self.view_close(*o, self.params.view_origin) => any = true,
                _ => return false,
            }
        }
        self.settings.effective_view() && any
    }

    /// Whether frames must still be traced before the view-dependent words serve the current
    /// view point (never without light: nothing would ever be deposited).
    pub fn view_pending(&self) -> bool {
        // A full ring without a single beam (a budget of 0 beams) never gets ready either.
        let empty = self.ring_full() && self.slot_beams.iter().all(|b| b.0 + b.1 == 0);
        self.settings.effective_view() && self.has_light() && !empty && !self.view_ready()
    }

    /// `params.view_mode` for what J holds: 2 with the view words, else whether they are traced.
    pub(super) fn j_view_mode(&self) -> u32 {
        if self.j_view.is_some() {
            2
        } else {
            self.settings.effective_view() as u32
        }
    }

    /// Whether J, as last upsampled, holds the view-dependent in-scattering.
    pub fn j_holds_view(&self) -> bool {
        self.j_view.is_some()
    }

    /// Whether view points `a` and `b` may share view-dependent words: identical, or both
    /// outside the cloud's bounding sphere, within `VIEW_TOLERANCE_DEG` of each other seen
    /// from its centre and within `VIEW_TOLERANCE_DISTANCE` in distance to it — the impostor
    /// criteria's measure. Seen from the cloud's near side a move spans a larger angle than from
    /// its centre (≈ 15° for 5° at 1.5 bounding radii), so close to a cloud the shared words are
    /// less exact.
    pub fn view_close(&self, a: [f32; 3], b: [f32; 3]) -> bool {
        if a == b {
            return true;
        }
        let c = self.cloud_center();
        let (va, vb) = (
            DVec3::from(a.map(f64::from)) - c,
            DVec3::from(b.map(f64::from)) - c,
        );
        let (la, lb) = (va.length(), vb.length());
        let r = self.params.bound_radius as f64;
        if !(la > r && lb > r) {
            return false;
        }
        let cos = va.dot(vb) / (la * lb);
        cos >= VIEW_TOLERANCE_DEG.to_radians().cos()
            && (la / lb - 1.0).abs() <= VIEW_TOLERANCE_DISTANCE
    }
}
