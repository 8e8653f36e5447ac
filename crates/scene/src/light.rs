//! Light sources: the sun (a delta directional light or a uniform disc of given angular radius)
//! and the sky (constant radiance or a lat-long environment map with importance sampling).

use std::f64::consts::PI;
use std::path::Path;

use glam::DVec3;

use crate::error::{FieldError, Result};
use crate::frame::direction_around;
use crate::image::Image;

/// The sun. `dir` points from the scene towards the sun; `irradiance` is the RGB irradiance on a
/// surface perpendicular to it.
#[derive(Debug, Clone, PartialEq)]
pub struct Sun {
    pub dir: DVec3,
    pub irradiance: DVec3,
    /// Angular radius in radians; 0 is a delta light.
    pub angular_radius: f64,
    cos_max: f64,
}

impl Sun {
    pub fn new(
        direction: DVec3,
        irradiance: DVec3,
        angular_radius_deg: f64,
    ) -> Result<Self, FieldError> {
        // Only the direction counts: the vector is scaled by its largest component before it is
        // normalised, so [1e308, 1e308, 0] (whose length overflows) and [1e-300, 1e-300, 0]
        // (whose length underflows) name the same direction as [1, 1, 0].
        let largest = direction.abs().max_element();
        if !direction.is_finite() || largest == 0.0 {
            return Err(FieldError::new(
                "sun.direction",
                "must be a finite non-zero vector",
            ));
        }
        let direction = direction / largest;
        if !irradiance.is_finite() || irradiance.min_element() < 0.0 {
            return Err(FieldError::new("sun.irradiance", "must be finite and ≥ 0"));
        }
        if !(angular_radius_deg.is_finite() && (0.0..=45.0).contains(&angular_radius_deg)) {
            return Err(FieldError::new(
                "sun.angular_radius_deg",
                format!("must lie in [0, 45], got {angular_radius_deg}"),
            ));
        }
        if irradiance.max_element() > MAX_RADIANCE {
            return Err(FieldError::new(
                "sun.irradiance",
                format!(
                    "must be at most {MAX_RADIANCE:e} (images are stored as f32), got [{:e}, {:e}, {:e}]",
                    irradiance.x, irradiance.y, irradiance.z
                ),
            ));
        }
        let r = angular_radius_deg.to_radians();
        let sun = Self {
            dir: direction.normalize(),
            irradiance,
            angular_radius: r,
            cos_max: r.cos(),
        };
        if !sun.is_delta() {
            let l = sun.radiance().max_element();
            if !(l.is_finite() && l <= MAX_RADIANCE) {
                return Err(FieldError::new(
                    "sun.angular_radius_deg",
                    format!(
                        "{angular_radius_deg:e} makes the disc's radiance irradiance / (π sin² r) = {l:e}, beyond {MAX_RADIANCE:e}; use 0 for a delta sun"
                    ),
                ));
            }
        }
        Ok(sun)
    }

    pub fn is_delta(&self) -> bool {
        self.angular_radius == 0.0
    }

    /// Solid angle of the disc: 2π(1 − cos r). Computed as 4π sin²(r/2) to keep precision for
    /// tiny discs.
    pub fn solid_angle(&self) -> f64 {
        let s = (0.5 * self.angular_radius).sin();
        4.0 * PI * s * s
    }

    /// Radiance of the disc (uniform): irradiance = L π sin² r.
    pub fn radiance(&self) -> DVec3 {
        let s = self.angular_radius.sin();
        self.irradiance / (PI * s * s)
    }

    /// Whether direction `d` (unit) falls in the disc.
    #[inline]
    pub fn contains(&self, d: DVec3) -> bool {
        !self.is_delta() && d.dot(self.dir) >= self.cos_max
    }

    /// Uniform sample of the disc: (direction, pdf per steradian).
    #[inline]
    pub fn sample_cone(&self, u: [f64; 2]) -> (DVec3, f64) {
        // 1 − cos θ uniform in [0, 1 − cos_max]; use the half-angle form for precision.
        let one_minus_cos_max = 2.0 * (0.5 * self.angular_radius).sin().powi(2);
        let one_minus_cos = u[0] * one_minus_cos_max;
        let d = direction_around(self.dir, 1.0 - one_minus_cos, 2.0 * PI * u[1]);
        (d, 1.0 / self.solid_angle())
    }
}

/// Sky lighting.
#[derive(Debug, Clone, PartialEq)]
pub enum Sky {
    /// The same RGB radiance from every direction.
    Constant(DVec3),
    Env(EnvMap),
}

impl Sky {
    /// Radiance arriving from direction `d` (pointing away from the scene).
    #[inline]
    pub fn radiance(&self, d: DVec3) -> DVec3 {
        match self {
            Sky::Constant(c) => *c,
            Sky::Env(e) => e.radiance(d),
        }
    }

    pub fn is_black(&self) -> bool {
        match self {
            Sky::Constant(c) => c.max_element() <= 0.0,
            // `total` is the texels' (before the scale): a scale of 0 is a black sky too.
            Sky::Env(e) => e.total <= 0.0 || e.scale == 0.0,
        }
    }
}

/// A piecewise-constant 1D distribution.
#[derive(Debug, Clone, PartialEq)]
struct Distribution1D {
    cdf: Vec<f64>,
    func: Vec<f64>,
    integral: f64,
}

impl Distribution1D {
    fn new(func: Vec<f64>) -> Self {
        let n = func.len() as f64;
        let mut cdf = Vec::with_capacity(func.len() + 1);
        cdf.push(0.0);
        for f in &func {
            cdf.push(cdf.last().unwrap() + f / n);
        }
        let integral = *cdf.last().unwrap();
        if integral > 0.0 {
            cdf.iter_mut().for_each(|c| *c /= integral);
        } else {
            let len = cdf.len() - 1;
            cdf.iter_mut()
                .enumerate()
                .for_each(|(i, c)| *c = i as f64 / len as f64);
        }
        Self {
            cdf,
            func,
            integral,
        }
    }

    /// Returns (continuous sample in [0, 1), bin index, pdf over [0, 1)).
    fn sample(&self, u: f64) -> (f64, usize, f64) {
        let n = self.func.len();
        let i = (self.cdf.partition_point(|&c| c <= u) - 1).min(n - 1);
        let w = self.cdf[i + 1] - self.cdf[i];
        let du = if w > 0.0 { (u - self.cdf[i]) / w } else { 0.5 };
        let pdf = if self.integral > 0.0 {
            self.func[i] / self.integral
        } else {
            1.0
        };
        ((i as f64 + du.clamp(0.0, 1.0)) / n as f64, i, pdf)
    }
}

/// A lat-long environment map. Direction ↔ texel: φ = atan2(d.x, −d.z), u = φ/2π + ½;
/// θ = acos(d.y), v = θ/π (row 0 is the zenith, +y up). Radiance is constant over each texel,
/// and importance sampling follows luminance × sin θ exactly, so eval and pdf agree.
#[derive(Debug, Clone, PartialEq)]
pub struct EnvMap {
    image: Image,
    scale: f64,
    rows: Distribution1D,
    cols: Vec<Distribution1D>,
    total: f64,
}

/// The largest radiance or irradiance a scene may hold: images are f32 (max ≈ 3.4e38), and
/// estimates multiply radiance by σ_t, phase values and sample weights, so 1e30 leaves room.
pub const MAX_RADIANCE: f64 = 1e30;

impl EnvMap {
    pub fn new(image: Image, scale: f64) -> Result<Self, FieldError> {
        if !(scale.is_finite() && scale >= 0.0) {
            return Err(FieldError::new("sky.scale", "must be finite and ≥ 0"));
        }
        if image.width == 0 || image.height == 0 || image.pixels.len() != image.width * image.height
        {
            return Err(FieldError::new(
                "sky.envmap",
                format!(
                    "a {}×{} image of {} pixels is no map",
                    image.width,
                    image.height,
                    image.pixels.len()
                ),
            ));
        }
        // Texels first (a NaN or +inf is named as the map's, not as the scale's overflow).
        if let Some(i) = image
            .pixels
            .iter()
            .position(|p| p.iter().any(|v| !v.is_finite() || *v < 0.0))
        {
            return Err(FieldError::new(
                "sky.envmap",
                format!(
                    "pixel[{},{}] is {:?}: pixels must be finite and ≥ 0",
                    i % image.width,
                    i / image.width,
                    image.pixels[i]
                ),
            ));
        }
        // The image (12 bytes a texel) and the sampling tables below (a weight and a CDF entry,
        // f64 each), held together.
        crate::memory::check(
            image.pixels.len() as u128 * 28,
            "sky.envmap",
            &format!(
                "a {}×{} environment map and its sampling tables",
                image.width, image.height
            ),
        )?;
        let max = image
            .pixels
            .iter()
            .flatten()
            .fold(0.0f64, |m, v| m.max(*v as f64));
        if max * scale > MAX_RADIANCE {
            return Err(FieldError::new(
                "sky.scale",
                format!(
                    "scale × brightest pixel = {:e} exceeds {MAX_RADIANCE:e}",
                    max * scale
                ),
            ));
        }
        let (w, h) = (image.width, image.height);
        let mut cols = Vec::with_capacity(h);
        let mut row_w = Vec::with_capacity(h);
        for y in 0..h {
            let sin_t = (PI * (y as f64 + 0.5) / h as f64).sin();
            let f: Vec<f64> = (0..w).map(|x| image.lum(x, y) * sin_t).collect();
            let d = Distribution1D::new(f);
            row_w.push(d.integral);
            cols.push(d);
        }
        let rows = Distribution1D::new(row_w);
        let total = rows.integral;
        Ok(Self {
            image,
            scale,
            rows,
            cols,
            total,
        })
    }

    pub fn load(path: &Path, scale: f64) -> Result<Self> {
        let img = Image::read_exr(path)?;
        Self::new(img, scale).map_err(|e| e.at(path))
    }

    fn texel(&self, d: DVec3) -> (usize, usize) {
        let u = d.x.atan2(-d.z) / (2.0 * PI) + 0.5;
        let v = d.y.clamp(-1.0, 1.0).acos() / PI;
        let x = ((u * self.image.width as f64) as usize).min(self.image.width - 1);
        let y = ((v * self.image.height as f64) as usize).min(self.image.height - 1);
        (x, y)
    }

    /// The map's texels (before [`EnvMap::scale`]): what a GPU copy uploads.
    pub fn image(&self) -> &Image {
        &self.image
    }

    /// The factor every texel is multiplied by.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    pub fn radiance(&self, d: DVec3) -> DVec3 {
        let (x, y) = self.texel(d);
        let p = self.image.get(x, y);
        DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64) * self.scale
    }

    /// The direction of texel coordinates (u, v) ∈ [0, 1]² (the inverse of the texel lookup).
    pub fn dir_of(u: f64, v: f64) -> DVec3 {
        let phi = (u - 0.5) * 2.0 * PI;
        let theta = v * PI;
        DVec3::new(
            theta.sin() * phi.sin(),
            theta.cos(),
            -theta.sin() * phi.cos(),
        )
    }

    /// Importance-samples a direction: (direction, pdf per steradian). `None` for a black map.
    pub fn sample(&self, u: [f64; 2]) -> Option<(DVec3, f64)> {
        if self.total <= 0.0 {
            return None;
        }
        let (v, row, pdf_v) = self.rows.sample(u[0]);
        let (uu, _, pdf_u) = self.cols[row].sample(u[1]);
        let d = Self::dir_of(uu, v);
        let sin_t = (v * PI).sin();
        if sin_t <= 0.0 {
            return None;
        }
        Some((d, pdf_u * pdf_v / (2.0 * PI * PI * sin_t)))
    }

    /// Density (per steradian) with which [`EnvMap::sample`] produces `d`.
    pub fn pdf(&self, d: DVec3) -> f64 {
        if self.total <= 0.0 {
            return 0.0;
        }
        let (x, y) = self.texel(d);
        let row = &self.cols[y];
        let pdf_v = self.rows.func[y] / self.rows.integral;
        let pdf_u = if row.integral > 0.0 {
            row.func[x] / row.integral
        } else {
            0.0
        };
        // Uniform (u, v) within a texel maps to directions with density 1/(2π² sin θ).
        let sin_t = (1.0 - d.y * d.y).max(0.0).sqrt();
        if sin_t <= 0.0 {
            return 0.0;
        }
        pdf_u * pdf_v / (2.0 * PI * PI * sin_t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sun_disc_radiance_and_sampling() {
        let s = Sun::new(DVec3::new(0.0, 2.0, 0.0), DVec3::ONE, 0.27).unwrap();
        assert!((s.dir - DVec3::Y).length() < 1e-15);
        // Irradiance of the disc = L × ∫ cos θ dω = L π sin² r.
        let l = s.radiance().x;
        assert!((l * PI * s.angular_radius.sin().powi(2) - 1.0).abs() < 1e-12);
        let (d, pdf) = s.sample_cone([0.99, 0.3]);
        assert!(s.contains(d));
        assert!((pdf * s.solid_angle() - 1.0).abs() < 1e-12);
        assert!(Sun::new(DVec3::ZERO, DVec3::ONE, 0.0).is_err());
        // A direction is a direction at any length: one whose length overflows or underflows
        // (once silently dropped: the normalised vector was NaN) names [1, 1, 0]/√2.
        for scale in [1e308, 1e-300, 1e-320] {
            let s = Sun::new(DVec3::new(scale, scale, 0.0), DVec3::ONE, 0.0).unwrap();
            let want = DVec3::new(1.0, 1.0, 0.0).normalize();
            assert!((s.dir - want).length() < 1e-15, "{scale}: {:?}", s.dir);
        }
        assert!(Sun::new(DVec3::new(f64::INFINITY, 0.0, 0.0), DVec3::ONE, 0.0).is_err());
        assert!(Sun::new(DVec3::Y, DVec3::splat(-1.0), 0.0).is_err());
    }

    #[test]
    fn envmap_pdf_matches_sampling() {
        let mut img = Image::new(16, 8);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            let v = 0.1 + (i % 7) as f32;
            *p = [v, v, v];
        }
        let e = EnvMap::new(img, 2.0).unwrap();
        // ∫ pdf dω = 1 (Monte Carlo over uniform directions, 1e5 samples: ±1 %).
        let n = 100_000;
        let mut s = 1u64;
        let mut acc = 0.0;
        for _ in 0..n {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let a = (s >> 11) as f64 / (1u64 << 53) as f64;
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let b = (s >> 11) as f64 / (1u64 << 53) as f64;
            let d = crate::frame::uniform_sphere([a, b]);
            acc += e.pdf(d) * 4.0 * PI;
            let (sd, spdf) = e.sample([a, b]).unwrap();
            assert!((spdf / e.pdf(sd) - 1.0).abs() < 1e-6 || spdf < 1e-9);
        }
        assert!((acc / n as f64 - 1.0).abs() < 0.01, "{}", acc / n as f64);
    }
}
