//! Orthonormal frames and spherical directions.

use glam::DVec3;

/// Two unit vectors `(t, b)` completing the unit vector `n` to a right-handed orthonormal basis
/// (Duff et al. 2017, "Building an Orthonormal Basis, Revisited"): continuous except at n.z = −0
/// vs +0, branch-free and exact to round-off for every unit `n`.
#[inline]
pub fn orthonormal_basis(n: DVec3) -> (DVec3, DVec3) {
    let sign = 1.0f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        DVec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// The unit vector at angle θ (given by `cos_theta`) from `axis` and azimuth `phi` around it.
#[inline]
pub fn direction_around(axis: DVec3, cos_theta: f64, phi: f64) -> DVec3 {
    let cos_theta = cos_theta.clamp(-1.0, 1.0);
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    let (t, b) = orthonormal_basis(axis);
    (t * (sin_theta * phi.cos()) + b * (sin_theta * phi.sin()) + axis * cos_theta).normalize()
}

/// Uniformly distributed unit vector from two uniform numbers in [0, 1).
#[inline]
pub fn uniform_sphere(u: [f64; 2]) -> DVec3 {
    let z = 1.0 - 2.0 * u[0];
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f64::consts::TAU * u[1];
    DVec3::new(r * phi.cos(), r * phi.sin(), z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_is_orthonormal() {
        for n in [
            DVec3::X,
            DVec3::NEG_Z,
            DVec3::Z,
            DVec3::new(1.0, 2.0, -3.0).normalize(),
            DVec3::new(1e-9, -1e-9, -1.0).normalize(),
        ] {
            let (t, b) = orthonormal_basis(n);
            assert!((t.length() - 1.0).abs() < 1e-12);
            assert!((b.length() - 1.0).abs() < 1e-12);
            assert!(t.dot(b).abs() < 1e-12 && t.dot(n).abs() < 1e-12 && b.dot(n).abs() < 1e-12);
            assert!((t.cross(b) - n).length() < 1e-12);
        }
        let d = direction_around(DVec3::Y, 0.5, 1.0);
        assert!((d.dot(DVec3::Y) - 0.5).abs() < 1e-12);
    }
}
