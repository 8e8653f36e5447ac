//! Exact shortcuts for the heap-shaped clouds (cumulus, congestus): per tile of voxels, the
//! blobs that can decide the shape there and whether the whole tile lies deep inside; and an
//! fBm evaluated octave by octave that stops once the remaining octaves cannot change the
//! decision its caller takes. Both give the values of the plain formula bit for bit (the max
//! over a subset holding the maximiser is the max; the octaves are summed in the same order),
//! so the generated clouds do not depend on them (`generate_with`'s tests compare both paths).

use noise::{NoiseFn, Perlin};

/// A sphere of the heap: centre and radius (normalised coordinates).
pub(crate) type Blob = ([f64; 3], f64);

fn distance(c: [f64; 3], p: [f64; 3]) -> f64 {
    ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt()
}

/// What the shape alone says about a tile of voxels (every voxel within `h` of a centre).
#[derive(Debug, Clone, Default)]
pub(crate) struct Tile {
    /// Evaluate every blob (no plan was made for this tile).
    pub all: bool,
    /// The blobs whose value can be the maximum somewhere in the tile (when not `all`).
    pub blobs: Vec<usize>,
    /// The whole tile lies so deep inside that no noise can change its density.
    pub inside: bool,
}

impl Tile {
    /// No plan: every blob, no shortcut.
    pub(crate) fn everything() -> Self {
        Self {
            all: true,
            blobs: Vec::new(),
            inside: false,
        }
    }
}

/// How a blob's value falls with the distance from its centre: the cumulus shape 1 − d/r or
/// the congestus depth r − d. Both decrease in d, so over a ball of radius h around c the value
/// lies between `f(d_c + h, r)` and `f(d_c − h, r)`.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Measure {
    Shape,
    Depth,
}

impl Measure {
    fn of(self, d: f64, r: f64) -> f64 {
        match self {
            Measure::Shape => 1.0 - d / r,
            Measure::Depth => r - d,
        }
    }
}

/// A heap of spheres and how deep a point lies in it.
pub(crate) struct Heap {
    pub blobs: Vec<Blob>,
    pub measure: Measure,
}

impl Heap {
    /// The max over the tile's blobs of the measure at `p` (the max over all blobs: the tile
    /// holds every blob that can attain it).
    pub(crate) fn at(&self, p: [f64; 3], tile: &Tile) -> f64 {
        let one = |&(c, r): &Blob| self.measure.of(distance(c, p), r);
        if tile.all {
            self.blobs.iter().map(one).fold(f64::NEG_INFINITY, f64::max)
        } else {
            tile.blobs
                .iter()
                .map(|&i| one(&self.blobs[i]))
                .fold(f64::NEG_INFINITY, f64::max)
        }
    }

    /// Bounds of [`Heap::at`] over the ball of radius `h` around `c`, and the tile's blobs:
    /// those whose upper bound reaches the largest lower bound (10⁻⁹ of slack covers the
    /// rounding of both sides). Returns (lower, upper).
    pub(crate) fn plan(&self, c: [f64; 3], h: f64, tile: &mut Tile) -> (f64, f64) {
        let mut lower = f64::NEG_INFINITY;
        let mut upper = f64::NEG_INFINITY;
        for &(centre, r) in &self.blobs {
            let d = distance(centre, c);
            lower = lower.max(self.measure.of(d + h, r));
            upper = upper.max(self.measure.of(d - h, r));
        }
        tile.all = false;
        tile.blobs.clear();
        for (i, &(centre, r)) in self.blobs.iter().enumerate() {
            if self.measure.of(distance(centre, c) - h, r) >= lower - 1e-9 {
                tile.blobs.push(i);
            }
        }
        (lower, upper)
    }
}

/// The decision an fBm-driven threshold comes to.
pub(crate) enum Early {
    /// `offset + weight · n` is certainly below the lower threshold.
    Below,
    /// … certainly above the upper one.
    Above,
    /// Every octave was needed: n itself.
    Value(f64),
}

/// `noise::Fbm<Perlin>` (same sources, order of operations and scale: the same values bit for
/// bit), evaluated octave by octave.
pub(crate) struct Octaves {
    sources: Vec<Perlin>,
    frequency: f64,
    lacunarity: f64,
    persistence: f64,
    scale: f64,
    /// `rest[k]`: the largest |contribution| of the octaves after the first k + 1 (Perlin is
    /// clamped to [−1, 1]), before the scale.
    rest: Vec<f64>,
}

impl Octaves {
    /// As `Fbm::<Perlin>::new(seed).set_octaves(octaves).set_frequency(frequency)`.
    pub(crate) fn new(seed: u32, octaves: usize, frequency: f64) -> Self {
        let lacunarity = noise::Fbm::<Perlin>::DEFAULT_LACUNARITY;
        let persistence = noise::Fbm::<Perlin>::DEFAULT_PERSISTENCE;
        let denom = (1..=octaves).fold(0.0, |acc, x| acc + persistence.powi(x as i32));
        let rest = (0..octaves)
            .map(|k| {
                (k + 2..=octaves)
                    .map(|x| persistence.powi(x as i32))
                    .sum::<f64>()
            })
            .collect();
        Self {
            sources: (0..octaves)
                .map(|x| Perlin::new(seed.wrapping_add(x as u32)))
                .collect(),
            frequency,
            lacunarity,
            persistence,
            scale: 1.0 / denom,
            rest,
        }
    }

    /// fBm at `p`.
    pub(crate) fn get(&self, p: [f64; 3]) -> f64 {
        match self.get_unless(p, 0.0, 0.0, f64::NEG_INFINITY, f64::INFINITY) {
            Early::Value(n) => n,
            _ => unreachable!("infinite thresholds never stop early"),
        }
    }

    /// fBm n at `p`, unless after some octave `offset + weight · n` (weight > 0) is certain to
    /// lie below `below` or above `above` whatever the remaining octaves add (with 10⁻⁹ of
    /// slack for rounding, so the caller's own test on the full value agrees).
    pub(crate) fn get_unless(
        &self,
        p: [f64; 3],
        offset: f64,
        weight: f64,
        below: f64,
        above: f64,
    ) -> Early {
        let mut point = p.map(|v| v * self.frequency);
        let mut result = 0.0;
        let mut attenuation = self.persistence;
        let last = self.sources.len() - 1;
        for (k, source) in self.sources.iter().enumerate() {
            let signal = source.get(point) * attenuation;
            attenuation *= self.persistence;
            result += signal;
            if k < last {
                let spread = weight * self.rest[k] * self.scale + 1e-9;
                let mid = offset + weight * result * self.scale;
                if mid + spread < below {
                    return Early::Below;
                }
                if mid - spread > above {
                    return Early::Above;
                }
                point = point.map(|v| v * self.lacunarity);
            }
        }
        Early::Value(result * self.scale)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use noise::{Fbm, MultiFractal};

    fn points() -> impl Iterator<Item = [f64; 3]> {
        (0..4000).map(|i| {
            let t = i as f64;
            [
                (t * 0.1373).sin() * 1.3,
                (t * 0.0311).cos() + 1.0,
                (t * 0.0731).sin() * 0.9,
            ]
        })
    }

    #[test]
    fn octaves_are_noise_fbm_bit_for_bit() {
        for (seed, octaves, freq) in [(0u32, 5, 2.5), (77, 3, 2.0), (u32::MAX - 1, 4, 1.5)] {
            // noise's own seeds per octave are `seed + i`, which wraps in release builds and
            // overflows (a panic) where overflow is checked: built here with the wrap, so the
            // case near u32::MAX runs in every build.
            let fbm = Fbm::<Perlin>::new(0)
                .set_octaves(octaves)
                .set_frequency(freq)
                .set_sources(
                    (0..octaves as u32)
                        .map(|i| Perlin::new(seed.wrapping_add(i)))
                        .collect(),
                );
            let ours = Octaves::new(seed, octaves, freq);
            for p in points() {
                assert_eq!(fbm.get(p).to_bits(), ours.get(p).to_bits(), "{p:?}");
            }
        }
    }

    #[test]
    fn stopping_early_agrees_with_the_full_value() {
        // Every early answer is the one the full value gives; and the shortcut is taken often
        // (otherwise it would be useless).
        let ours = Octaves::new(9, 5, 2.5);
        let (below, above) = (-0.06, 0.39);
        let mut early = 0;
        for (i, p) in points().enumerate() {
            let offset = (i % 41) as f64 / 20.0 - 1.0;
            let n = ours.get(p);
            let u = offset + 0.35 * n;
            match ours.get_unless(p, offset, 0.35, below, above) {
                Early::Below => {
                    assert!(u < below, "{u}");
                    early += 1;
                }
                Early::Above => {
                    assert!(u > above, "{u}");
                    early += 1;
                }
                Early::Value(v) => assert_eq!(v.to_bits(), n.to_bits()),
            }
        }
        assert!(early > 1000, "{early}");
    }

    #[test]
    fn a_tile_plan_keeps_the_maximiser() {
        let blobs = vec![
            ([0.0, 0.3, 0.0], 0.4),
            ([0.35, 0.4, 0.1], 0.3),
            ([-0.5, 0.35, -0.2], 0.35),
            ([0.1, 0.8, 0.0], 0.2),
        ];
        for measure in [Measure::Shape, Measure::Depth] {
            let heap = Heap {
                blobs: blobs.clone(),
                measure,
            };
            let mut tile = Tile::default();
            let mut pruned = 0;
            for c in points() {
                let c = c.map(|v| v * 0.6);
                let h = 0.05;
                let (lo, hi) = heap.plan(c, h, &mut tile);
                pruned += blobs.len() - tile.blobs.len();
                for k in 0..20 {
                    let a = k as f64 * 0.7;
                    let s = h * (k as f64 / 20.0);
                    let p = [c[0] + s * a.cos(), c[1] + s * a.sin(), c[2]];
                    let full = heap.at(p, &Tile::everything());
                    assert_eq!(heap.at(p, &tile).to_bits(), full.to_bits());
                    assert!(lo - 1e-12 <= full && full <= hi + 1e-12);
                }
            }
            assert!(pruned > 4000, "{measure:?}: {pruned}");
        }
    }
}
