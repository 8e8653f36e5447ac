//! Cellular (Worley) noise and its Perlin–Worley blend, the building blocks of
//! [`super::CloudKind::Congestus`].
//!
//! Worley noise F1 (Worley 1996): the distance from `p` to the nearest of one random feature
//! point per unit cell, found among the 27 cells around `p` — exact, unlike an approximate
//! search over fewer cells, so the field has no seams. `1 − F1²` is a field of round caps
//! ("billows"); at a few scales it gives the cauliflower detail of cumulus tops, and F1
//! itself the wispy detail of eroded cloud bases (Schneider & Vos, "The real-time volumetric
//! cloudscapes of Horizon Zero Dawn", SIGGRAPH 2015 course; GPU Pro 7 §II.4).

/// Worley F1 noise with its own seed.
pub(crate) struct Cellular {
    seed: u64,
}

fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58476d1ce4e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d049bb133111eb);
    z ^ (z >> 31)
}

fn unit(h: u64) -> f64 {
    (h >> 11) as f64 / (1u64 << 53) as f64
}

impl Cellular {
    pub(crate) fn new(seed: u64) -> Self {
        Self {
            seed: mix(seed ^ 0x5851_f42d_4c95_7f2d),
        }
    }

    /// The feature point of cell `c` (inside it).
    fn feature(&self, c: [i64; 3]) -> [f64; 3] {
        let mut h = self.seed;
        for v in c {
            h = mix(h ^ (v as u64).wrapping_mul(0x9e3779b97f4a7c15));
        }
        let (a, b) = (mix(h ^ 1), mix(h ^ 2));
        [
            c[0] as f64 + unit(h),
            c[1] as f64 + unit(a),
            c[2] as f64 + unit(b),
        ]
    }

    /// The smallest squared distance from `p` to the feature points of the cells within
    /// `r` cells of `c` (a (2r+1)³ block).
    fn nearest2(&self, p: [f64; 3], c: [i64; 3], r: i64) -> f64 {
        let mut best = f64::INFINITY;
        for dz in -r..=r {
            for dy in -r..=r {
                for dx in -r..=r {
                    let f = self.feature([c[0] + dx, c[1] + dy, c[2] + dz]);
                    let d2 = (p[0] - f[0]).powi(2) + (p[1] - f[1]).powi(2) + (p[2] - f[2]).powi(2);
                    best = best.min(d2);
                }
            }
        }
        best
    }

    /// F1: the distance to the nearest feature point, in [0, √3]. The 27 cells around `p`
    /// decide it unless the nearest of them is farther than the block's boundary (at least one
    /// cell away), then the 125 cells around `p` do: every cell beyond those is farther than
    /// the own cell's feature could be (√3 < 2).
    pub(crate) fn f1(&self, p: [f64; 3]) -> f64 {
        let c = p.map(|v| v.floor() as i64);
        let best = self.nearest2(p, c, 1);
        let wall = (0..3)
            .map(|i| {
                let f = p[i] - c[i] as f64;
                f.min(1.0 - f)
            })
            .fold(f64::INFINITY, f64::min);
        if best > (1.0 + wall).powi(2) {
            return self.nearest2(p, c, 2).sqrt();
        }
        best.sqrt()
    }

    /// Billows: `1 − F1²` clamped to [0, 1], round caps centred on the feature points.
    pub(crate) fn billow(&self, p: [f64; 3]) -> f64 {
        (1.0 - self.f1(p).powi(2)).clamp(0.0, 1.0)
    }
}

/// The Perlin–Worley blend: `perlin01` (Perlin noise mapped to [0, 1]) remapped from [0, 1]
/// onto [`billows`, 1] (Schneider 2015): billowy where the Worley term is high, connected by
/// Perlin noise's smooth structure elsewhere. In [0, 1] when both inputs are.
pub(crate) fn perlin_worley(perlin01: f64, billows: f64) -> f64 {
    billows + perlin01 * (1.0 - billows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f1_is_the_distance_to_the_nearest_feature() {
        // Brute force over a 7³ block of cells agrees with the 27-cell search.
        let c = Cellular::new(9);
        let mut s = 1u64;
        for _ in 0..500 {
            s = mix(s);
            let p = [
                unit(s) * 9.0 - 4.5,
                unit(mix(s ^ 1)) * 9.0,
                unit(mix(s ^ 2)) * 3.0,
            ];
            let cell = p.map(|v| v.floor() as i64);
            let mut best = f64::INFINITY;
            for dz in -3..=3 {
                for dy in -3..=3 {
                    for dx in -3..=3 {
                        let f = c.feature([cell[0] + dx, cell[1] + dy, cell[2] + dz]);
                        let d =
                            ((p[0] - f[0]).powi(2) + (p[1] - f[1]).powi(2) + (p[2] - f[2]).powi(2))
                                .sqrt();
                        best = best.min(d);
                    }
                }
            }
            assert_eq!(c.f1(p), best, "{p:?}");
            assert!((0.0..=3f64.sqrt()).contains(&best));
        }
    }

    #[test]
    fn billows_and_blend_stay_in_range() {
        let c = Cellular::new(3);
        for i in 0..1000 {
            let p = [
                i as f64 * 0.037,
                i as f64 * 0.011 - 3.0,
                (i % 17) as f64 * 0.29,
            ];
            let b = c.billow(p);
            assert!((0.0..=1.0).contains(&b), "{b}");
            for q in [0.0, 0.3, 1.0] {
                let pw = perlin_worley(q, b);
                assert!((b..=1.0).contains(&pw));
            }
        }
        // Different seeds, different fields; the same seed, the same field.
        let (a, b) = (Cellular::new(1), Cellular::new(2));
        assert_ne!(a.f1([0.3, 0.4, 0.5]), b.f1([0.3, 0.4, 0.5]));
        assert_eq!(a.f1([0.3, 0.4, 0.5]), Cellular::new(1).f1([0.3, 0.4, 0.5]));
    }
}
