//! Sun and sky colour through a clear atmosphere, as a function of sun elevation — a simple
//! physically based transmittance model, used when a scene sets `[sun] atmosphere = true`.
//!
//! - Wavelengths standing for R, G, B: 680, 550, 440 nm.
//! - Rayleigh optical depth of the whole atmosphere at sea level (Hansen & Travis 1974):
//!   τ_R(λ) = 0.008569 λ⁻⁴ (1 + 0.0113 λ⁻² + 0.00013 λ⁻⁴), λ in µm (0.097 at 550 nm).
//! - Aerosol optical depth by Ångström's law, τ_A(λ) = β (λ / 0.55 µm)^−α with β = 0.1,
//!   α = 1.3 (clear continental air).
//! - Relative air mass of Kasten & Young (1989): m = 1 / (sin h + 0.50572 (h + 6.07995°)^−1.6364),
//!   h the elevation in degrees (m = 1 at the zenith, 37.9 at the horizon).
//! - Sun: the given irradiance is taken above the atmosphere and multiplied by
//!   T(λ) = exp(−(τ_R + τ_A) m). Below the horizon (h < 0) the sun is blocked: T = 0.
//! - Sky: the given radiance is the sky of a sun at the zenith; its colour follows the light the
//!   sun loses to single Rayleigh scattering along the slant path, (1 − e^{−τ_R m}) / m, times
//!   the transmittance of the scattered light back out, e^{−(τ_R + τ_A)}, normalised to 1 at the
//!   zenith. The sky reddens and dims as the sun sets.

use glam::DVec3;

pub const WAVELENGTHS_UM: [f64; 3] = [0.680, 0.550, 0.440];

pub fn rayleigh_tau(l_um: f64) -> f64 {
    let l2 = l_um * l_um;
    0.008569 / (l2 * l2) * (1.0 + 0.0113 / l2 + 0.00013 / (l2 * l2))
}

pub fn aerosol_tau(l_um: f64) -> f64 {
    0.1 * (l_um / 0.55).powf(-1.3)
}

/// Relative optical air mass for a sun at `elevation_deg` (clamped to ≥ 0).
pub fn air_mass(elevation_deg: f64) -> f64 {
    let h = elevation_deg.clamp(0.0, 90.0);
    1.0 / (h.to_radians().sin() + 0.50572 * (h + 6.07995).powf(-1.6364))
}

/// Elevation (degrees) of a direction towards the sun (+y up).
pub fn elevation_deg(dir_to_sun: DVec3) -> f64 {
    dir_to_sun
        .normalize()
        .y
        .clamp(-1.0, 1.0)
        .asin()
        .to_degrees()
}

fn per_channel(f: impl Fn(f64) -> f64) -> DVec3 {
    DVec3::new(
        f(WAVELENGTHS_UM[0]),
        f(WAVELENGTHS_UM[1]),
        f(WAVELENGTHS_UM[2]),
    )
}

/// Direct-sun transmittance (RGB) for a sun at `elevation_deg`.
pub fn sun_transmittance(elevation_deg: f64) -> DVec3 {
    if elevation_deg < 0.0 {
        return DVec3::ZERO;
    }
    let m = air_mass(elevation_deg);
    per_channel(|l| (-(rayleigh_tau(l) + aerosol_tau(l)) * m).exp())
}

/// Sky radiance factor (RGB) relative to a sun at the zenith.
pub fn sky_factor(elevation_deg: f64) -> DVec3 {
    let f = |h: f64| {
        let m = air_mass(h);
        per_channel(|l| {
            let tr = rayleigh_tau(l);
            (1.0 - (-tr * m).exp()) / m * (-(tr + aerosol_tau(l))).exp()
        })
    };
    if elevation_deg < 0.0 {
        return DVec3::ZERO;
    }
    f(elevation_deg) / f(90.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_values_and_trends() {
        assert!((rayleigh_tau(0.55) - 0.0973).abs() < 2e-3);
        assert!((air_mass(90.0) - 1.0).abs() < 1e-3);
        assert!((air_mass(0.0) - 37.92).abs() < 0.05);
        let z = sun_transmittance(90.0);
        // Zenith at 550 nm: exp(−(0.097 + 0.1)) ≈ 0.82.
        assert!((z.y - (-(rayleigh_tau(0.55) + 0.1f64)).exp()).abs() < 1e-3);
        // Lower sun: dimmer and redder.
        let low = sun_transmittance(5.0);
        assert!(low.max_element() < z.min_element());
        assert!(low.x / low.z > z.x / z.z);
        assert_eq!(sun_transmittance(-1.0), DVec3::ZERO);
        assert!((sky_factor(90.0) - DVec3::ONE).length() < 1e-12);
        assert!(sky_factor(3.0).z < 1.0);
        assert!((elevation_deg(DVec3::new(1.0, 1.0, 0.0)) - 45.0).abs() < 1e-9);
    }
}
