//! Shared numerical checks for every phase function: normalisation, mean cosine, and a
//! chi-square goodness-of-fit test of the direction sampler.

use super::*;
use crate::frame::orthonormal_basis;

/// Simpson integral of f(μ) over [−1, 1] with 2n panels per half, dense near both ends so that
/// forward and backward peaks are resolved: μ = 1 − t⁴ on [0, 1] and μ = −1 + t⁴ on [−1, 0].
fn integrate_mu(f: impl Fn(f64) -> f64, n: usize) -> f64 {
    let h = 1.0 / n as f64;
    let half = |sign: f64| {
        let g = |t: f64| f(sign * (1.0 - t.powi(4))) * 4.0 * t.powi(3);
        let mut s = g(0.0) + g(1.0);
        for i in 1..n {
            s += if i % 2 == 1 { 4.0 } else { 2.0 } * g(i as f64 * h);
        }
        s * h / 3.0
    };
    half(1.0) + half(-1.0)
}

fn all_phases() -> Vec<(String, Phase)> {
    let mut v = vec![("isotropic".to_string(), Phase::Isotropic)];
    for g in [-0.999, -0.5, 0.0, 1e-6, 0.5, 0.857, 0.95, 0.999] {
        v.push((
            format!("hg g={g}"),
            Phase::HenyeyGreenstein(HenyeyGreenstein::new(g).unwrap()),
        ));
    }
    let mie = mie::cached(&MieParams {
        chop_deg: 5.0,
        ..Default::default()
    })
    .unwrap();
    v.push((
        "mie full".into(),
        Phase::Tabulated(Arc::new(mie.full.clone())),
    ));
    v.push((
        "mie chopped".into(),
        Phase::Tabulated(Arc::new(mie.chopped.as_ref().unwrap().phase.clone())),
    ));
    v
}

#[test]
fn normalised_with_mean_cosine_g() {
    for (name, p) in all_phases() {
        // HG with g = 0.999 has a peak of width ~1e-3 in θ; the t⁴ substitution with 2·10⁵
        // panels resolves it to < 1e-6 relative.
        let norm = TAU * integrate_mu(|mu| p.eval(mu), 200_000);
        let g = TAU * integrate_mu(|mu| p.eval(mu) * mu, 200_000);
        // Tabulated functions are piecewise constant: Simpson's rule across bin edges is exact
        // only to the bin width (~1e-4 in μ near the peak), hence 1e-3.
        let tol = if matches!(p, Phase::Tabulated(_)) {
            1e-3
        } else {
            1e-6
        };
        assert!((norm - 1.0).abs() < tol, "{name}: ∫p = {norm}");
        assert!(
            (g - p.mean_cosine()).abs() < tol,
            "{name}: g = {g} vs {}",
            p.mean_cosine()
        );
    }
}

/// Upper quantile of the chi-square distribution (Wilson–Hilferty approximation) at the
/// standard-normal quantile z.
fn chi2_quantile(dof: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * dof);
    dof * (1.0 - a + z * a.sqrt()).powi(3)
}

#[test]
fn chi_square_sampling() {
    // 2D histogram over (cos θ, φ) of 200 000 sampled directions around a tilted axis; expected
    // counts from the CDF. Bins whose expectation is < 5 are merged into one. Threshold: the
    // 1 − 1e-4 quantile (z = 3.72), so a correct sampler fails with probability 1e-4 per case.
    let axis = DVec3::new(0.3, -0.5, 0.8).normalize();
    let (t, b) = orthonormal_basis(axis);
    let (nmu, nphi) = (40usize, 8usize);
    for (name, p) in all_phases() {
        let mut counts = vec![0.0f64; nmu * nphi];
        let n = 200_000usize;
        let mut s = 0x853c49e6748fea9bu64;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64) / (1u64 << 53) as f64
        };
        // Bin edges in μ: equal-probability bins from the CDF, so every bin is well populated.
        let edges: Vec<f64> = (0..=nmu)
            .map(|i| {
                let target = i as f64 / nmu as f64;
                let (mut lo, mut hi) = (-1.0f64, 1.0f64);
                for _ in 0..100 {
                    let mid = 0.5 * (lo + hi);
                    if p.cdf(mid) < target {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                0.5 * (lo + hi)
            })
            .collect();
        for _ in 0..n {
            let smp = p.sample(axis, [next(), next()]);
            let mu = smp.dir.dot(axis).clamp(-1.0, 1.0);
            let phi = smp.dir.dot(b).atan2(smp.dir.dot(t)).rem_euclid(TAU);
            let i = edges.partition_point(|&e| e <= mu).clamp(1, nmu) - 1;
            let j = ((phi / TAU * nphi as f64) as usize).min(nphi - 1);
            counts[i * nphi + j] += 1.0;
            // The reported pdf is the phase value: perfect importance sampling.
            assert!(
                (smp.pdf - p.eval(mu)).abs() <= 1e-6 * smp.pdf.max(1.0)
                    || matches!(p, Phase::Tabulated(_))
            );
        }
        let mut chi2 = 0.0;
        let mut dof = 0usize;
        let (mut pool_o, mut pool_e) = (0.0, 0.0);
        for i in 0..nmu {
            let pm = p.cdf(edges[i + 1]) - p.cdf(edges[i]);
            for j in 0..nphi {
                let e = pm / nphi as f64 * n as f64;
                let o = counts[i * nphi + j];
                if e < 5.0 {
                    pool_o += o;
                    pool_e += e;
                } else {
                    chi2 += (o - e) * (o - e) / e;
                    dof += 1;
                }
            }
        }
        if pool_e > 5.0 {
            chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
            dof += 1;
        }
        let limit = chi2_quantile((dof - 1) as f64, 3.72);
        assert!(
            chi2 < limit,
            "{name}: chi2 = {chi2:.1} > {limit:.1} (dof {dof})"
        );
    }
}
