//! Settings of the photon mapper: the method variant (the paper's or exact single
//! scattering), beam budgets, ring and cache sizes, and the helpers that derive defaults.

/// Which photon-mapping method.
///
/// Measured on `scenes/refs/cumulus_side` (mean cloud luminance against the path tracer, see
/// BENCHMARKS.md): the exact variant's single scattering agrees with the path tracer limited to
/// one scattering (1.7 %), but its cache of multiply scattered light comes out ≈ 33 % low — the
/// paper's variant reaches 1.00 only because its order-0 deposits, rendered through each cell's
/// mixed lobe, add ≈ 0.0098 where the true single scattering is 0.0018, and its σ√(1 − g)
/// switch adds ≈ 22 % more. Density-weighted deposits ([`PmSettings::density_weighted`]) lift the exact
/// variant's mean to 0.96 but over-brighten thin boundary cells. Until the cache's multiple
/// scattering is right, the paper's variant stays the default.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PmVariant {
    /// Exact single scattering from a sun-transmittance volume in the ray marcher; the cache
    /// holds only light scattered at least once; similarity switch to σ(1 − g) (first-order
    /// similarity theory, as diffusion theory's reduced extinction).
    Exact,
    /// Elek et al. 2012 as published: the unscattered sun beam is deposited into the same
    /// cache and HG lobe as scattered light (§4.1, Appendix A), similarity switch to σ√(1 − g)
    /// (§4.1.1).
    #[default]
    Elek2012,
}

impl PmVariant {
    pub fn name(self) -> &'static str {
        match self {
            PmVariant::Exact => "exact",
            PmVariant::Elek2012 => "elek2012",
        }
    }
}

/// Settings of the photon mapper (defaults follow Elek 2012 §5).
#[derive(Debug, Clone)]
pub struct PmSettings {
    /// The method (default: the paper's; `Exact` adds exact single scattering).
    pub variant: PmVariant,
    /// Beams traced per frame, n_g (the paper: 819 k / 100 = 8 192).
    pub beams_per_frame: u32,
    /// Number of partial caches in the ring, m.
    pub ring: u32,
    /// Resolution of the caches H and I; default: the largest grid of ≤ 2 400 cells with the
    /// density grid's proportions (the paper's shared-memory budget).
    pub cache_res: Option<[u32; 3]>,
    /// A beam stops when its weight (albedo^scatterings) falls below this.
    pub beam_threshold: f32,
    /// A beam stops after this many scatterings.
    pub max_order: u32,
    /// Similarity threshold t: switch to the reduced extinction σ' and isotropic scattering
    /// after log(t)/log|g| bounces.
    pub similarity_t: f64,
    /// Reduced extinction after the switch: σ(1 − g) when true, the paper's σ√(1 − g) when
    /// false; `None`: the variant's (exact: σ(1 − g), elek2012: σ√(1 − g)).
    pub similarity_linear: Option<bool>,
    /// Density-weighted deposits (cells store ⟨σφ⟩/⟨σ⟩ instead of the cell-volume average of
    /// φ); `None` = off. Measured on `cumulus_side` with the exact variant: the mean rises from
    /// 0.67 to 0.96 of the reference, but thin boundary cells (small ⟨σ⟩) come out far too
    /// bright while the interior stays dark (4×4 error 0.51 against 0.46): not yet a default.
    pub density_weighted: Option<bool>,
    /// Ray-marching step as a fraction of the box diagonal (the paper: 1/300).
    pub step_fraction: f64,
    /// Early exit below this transmittance (the paper: 2 %).
    pub early_exit: f32,
    pub seed: u32,
    /// Detail noise amplitude in density voxels (0 = off, the default for comparisons; the
    /// paper uses it to break the smoothness of coarse grids). Frequency: one period per 4
    /// voxels at the lowest octave.
    pub detail_noise: f32,
    /// Accumulate beams with global atomics even when the cache fits workgroup memory (the
    /// result is identical; for testing and measuring both paths).
    pub force_global_atomics: bool,
}

impl Default for PmSettings {
    fn default() -> Self {
        Self {
            variant: PmVariant::Elek2012,
            beams_per_frame: 8192,
            ring: 100,
            cache_res: None,
            beam_threshold: 0.01,
            max_order: 1024,
            similarity_t: 0.05,
            similarity_linear: None,
            density_weighted: None,
            step_fraction: 1.0 / 300.0,
            early_exit: 0.02,
            seed: 0,
            detail_noise: 0.0,
            force_global_atomics: false,
        }
    }
}

/// Default cache resolution: ≤ `max_cells` cells with the proportions of `d_res`, never finer
/// than `d_res`.
pub fn default_cache_res(d_res: [usize; 3], max_cells: u32) -> [u32; 3] {
    let n = (d_res[0] * d_res[1] * d_res[2]) as f64;
    let s = (max_cells as f64 / n).cbrt().min(1.0);
    let mut r = d_res.map(|v| ((v as f64 * s).floor() as u32).clamp(1, v as u32));
    while r.iter().map(|&v| v as u64).product::<u64>() > max_cells as u64 {
        let i = (0..3).max_by_key(|&i| r[i]).unwrap();
        r[i] -= 1;
    }
    r
}

/// Similarity switch order i = log t / log|g| (Elek §4.1.1); `u32::MAX` when it never applies.
pub fn similarity_order(g: f64, t: f64) -> u32 {
    let a = g.abs();
    if a < 1e-6 {
        return u32::MAX; // isotropic already: σ' = σ, nothing to switch
    }
    let i = t.ln() / a.ln();
    if !i.is_finite() || i > 1e9 {
        u32::MAX
    } else {
        i.floor().max(0.0) as u32
    }
}
