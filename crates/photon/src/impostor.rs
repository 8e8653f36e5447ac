//! Impostor caching (Elek 2012 §4.4): reuse the last ray-marched image of the cloud until one of
//! four empirical criteria says it is stale:
//! 1. angle — the direction from the cloud to the camera turned by more than 5°;
//! 2. distance — the camera's distance to the cloud changed by more than 20 %;
//! 3. illumination — the photon map was updated by more than 4 % of its ring (m) since;
//! 4. animation — the density changed by more than a tunable relative L1 amount (default 2 %).

use glam::DVec3;

/// Thresholds of the four criteria.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImpostorCriteria {
    pub angle_deg: f64,
    pub distance_rel: f64,
    pub illumination_frac: f64,
    pub density_rel: f64,
}

impl Default for ImpostorCriteria {
    fn default() -> Self {
        Self {
            angle_deg: 5.0,
            distance_rel: 0.2,
            illumination_frac: 0.04,
            density_rel: 0.02,
        }
    }
}

/// Why the impostor was (re)rendered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refresh {
    First,
    Angle,
    Distance,
    Illumination,
    Animation,
}

impl Refresh {
    pub fn name(self) -> &'static str {
        match self {
            Refresh::First => "first",
            Refresh::Angle => "angle",
            Refresh::Distance => "distance",
            Refresh::Illumination => "illumination",
            Refresh::Animation => "animation",
        }
    }
}

/// State of the impostor: what it was rendered for, and what changed since.
#[derive(Debug, Clone)]
pub struct ImpostorState {
    pub criteria: ImpostorCriteria,
    view_dir: Option<DVec3>,
    distance: f64,
    frames_traced: u32,
    density_change: f64,
    /// Counts of refreshes per reason and of reuses.
    pub refreshes: [u32; 5],
    pub reuses: u32,
}

impl ImpostorState {
    pub fn new(criteria: ImpostorCriteria) -> Self {
        Self {
            criteria,
            view_dir: None,
            distance: 0.0,
            frames_traced: 0,
            density_change: 0.0,
            refreshes: [0; 5],
            reuses: 0,
        }
    }

    /// Records a traced frame (one generation of the ring replaced).
    pub fn traced(&mut self) {
        self.frames_traced += 1;
    }

    /// Records a density change of relative L1 size `rel` (Σ|D − D_prev| / Σ D_prev).
    pub fn density_changed(&mut self, rel: f64) {
        self.density_change += rel;
    }

    /// Decides for this frame: `Some(reason)` to re-render, `None` to reuse the impostor.
    /// `ring` is m; camera and cloud centre give the view criteria.
    pub fn check(&mut self, camera: DVec3, cloud_center: DVec3, ring: u32) -> Option<Refresh> {
        let v = camera - cloud_center;
        let dist = v.length();
        let dir = v / dist.max(1e-300);
        let c = self.criteria;
        let reason = match self.view_dir {
            None => Some(Refresh::First),
            Some(d0) if d0.dot(dir).clamp(-1.0, 1.0).acos().to_degrees() > c.angle_deg => {
                Some(Refresh::Angle)
            }
            Some(_) if (dist / self.distance - 1.0).abs() > c.distance_rel => {
                Some(Refresh::Distance)
            }
            Some(_) if self.frames_traced as f64 > c.illumination_frac * ring as f64 => {
                Some(Refresh::Illumination)
            }
            Some(_) if self.density_change > c.density_rel => Some(Refresh::Animation),
            Some(_) => None,
        };
        match reason {
            Some(r) => {
                self.view_dir = Some(dir);
                self.distance = dist;
                self.frames_traced = 0;
                self.density_change = 0.0;
                self.refreshes[r as usize] += 1;
            }
            None => self.reuses += 1,
        }
        reason
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn four_criteria() {
        let mut s = ImpostorState::new(ImpostorCriteria::default());
        let c = DVec3::ZERO;
        let cam = DVec3::new(0.0, 0.0, 10.0);
        assert_eq!(s.check(cam, c, 100), Some(Refresh::First));
        assert_eq!(s.check(cam, c, 100), None);
        // 4° turn: reuse; 6°: refresh.
        let turn = |deg: f64| {
            DVec3::new(
                10.0 * deg.to_radians().sin(),
                0.0,
                10.0 * deg.to_radians().cos(),
            )
        };
        assert_eq!(s.check(turn(4.0), c, 100), None);
        assert_eq!(s.check(turn(6.0), c, 100), Some(Refresh::Angle));
        // 15 % closer: reuse; 25 %: refresh.
        let base = turn(6.0);
        assert_eq!(s.check(base * 0.85, c, 100), None);
        assert_eq!(s.check(base * 0.75, c, 100), Some(Refresh::Distance));
        // 4 of 100 generations replaced: reuse; the 5th: refresh.
        let cam = base * 0.75;
        for _ in 0..4 {
            s.traced();
        }
        assert_eq!(s.check(cam, c, 100), None);
        s.traced();
        assert_eq!(s.check(cam, c, 100), Some(Refresh::Illumination));
        s.density_changed(0.015);
        assert_eq!(s.check(cam, c, 100), None);
        s.density_changed(0.01);
        assert_eq!(s.check(cam, c, 100), Some(Refresh::Animation));
        assert_eq!(s.refreshes, [1, 1, 1, 1, 1]);
        assert_eq!(s.reuses, 5);
    }
}
