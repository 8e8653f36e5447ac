//! Settings of the photon mapper: the method variant (the paper's or exact single
//! scattering), beam budgets, ring and cache sizes, and the helpers that derive defaults.

/// Which photon-mapping method.
///
/// Measured on `scenes/refs/cumulus_side` against Mitsuba (BENCHMARKS.md "Lobe axes"): the
/// exact variant's single scattering agrees with the path tracer limited to one scattering
/// (1.7 %); with the paper's sun-aligned lobes its cache of multiply scattered light came out
/// ≈ 33 % low (mean 0.67); with two flux lobes per cell ([`LobeAxis::Flux`],
/// [`DEFAULT_LOBE_SPLIT`]) the mean is 0.997 and the 4×4 error 0.150 (the paper's variant:
/// 1.006 / 0.240, reached through compensating errors: its order-0 deposits rendered through
/// each cell's mixed lobe and its σ√(1 − g) switch). On a homogeneous sphere at three view
/// angles and three optical depths it is within 4–7 % of the path tracer (the paper's 16–33 %),
/// and on the held-out bench clouds under sun light its bias median is 0.27 against 0.35, so it
/// is the default; `Elek2012` stays selectable.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PmVariant {
    /// Exact single scattering from a sun-transmittance volume in the ray marcher; the cache
    /// holds only light scattered at least once; similarity switch to σ(1 − g) (first-order
    /// similarity theory, as diffusion theory's reduced extinction).
    #[default]
    Exact,
    /// Elek et al. 2012 as published: the unscattered sun beam is deposited into the same
    /// cache and HG lobe as scattered light (§4.1, Appendix A), similarity switch to σ√(1 − g)
    /// (§4.1.1).
    Elek2012,
}

impl PmVariant {
    pub const ALL: [PmVariant; 2] = [PmVariant::Exact, PmVariant::Elek2012];

    /// The name on the command line (`--pm-variant`) and in settings by name.
    pub fn name(self) -> &'static str {
        match self {
            PmVariant::Exact => "exact",
            PmVariant::Elek2012 => "elek2012",
        }
    }
}

impl std::str::FromStr for PmVariant {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| {
                format!("unknown photon-mapping variant `{s}` (expected exact or elek2012)")
            })
    }
}

/// Axis of the HG lobe that represents a cache cell's incident sun light (Elek §4.1.2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LobeAxis {
    /// The paper: every photon's cosine to the sun direction; every lobe points along the sun.
    Sun,
    /// Each cell's mean sun-flux direction Σ w d / Σ w, g' its length (Appendix C allows a
    /// per-cell direction); with [`PmSettings::lobe_split`] one such lobe for the low and one
    /// for the high scattering orders. Where light flows out of a cloud — its shadowed and
    /// camera-facing sides — it does not flow along the sun; measured on `cumulus_side` the
    /// sun axis loses ≈ 1/3 of the multiply scattered light at a side view (BENCHMARKS.md).
    Flux,
}

impl LobeAxis {
    pub const ALL: [LobeAxis; 2] = [LobeAxis::Sun, LobeAxis::Flux];

    /// The name on the command line (`--pm-lobe-axis`).
    pub fn name(self) -> &'static str {
        match self {
            LobeAxis::Sun => "sun",
            LobeAxis::Flux => "flux",
        }
    }
}

impl std::str::FromStr for LobeAxis {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| format!("unknown lobe axis `{s}` (expected sun or flux)"))
    }
}

/// Settings of the photon mapper (defaults follow Elek 2012 §5).
#[derive(Debug, Clone)]
pub struct PmSettings {
    /// The method (default: `Exact`; `Elek2012` is the paper's).
    pub variant: PmVariant,
    /// Beams traced per frame, n_g (the paper: 819 k / 100 = 8 192).
    pub beams_per_frame: u32,
    /// Number of partial caches in the ring, m.
    pub ring: u32,
    /// Resolution of the caches H and I; default: the largest grid with the density grid's
    /// proportions and at most [`PmSettings::default_max_cells`] cells (the paper's 2 400 with
    /// lobes; half the density resolution per axis with the view-dependent words).
    pub cache_res: Option<[u32; 3]>,
    /// Resolution of the light volumes (J, its flux directions, T_sun) and of the density the
    /// photon stages trace (block means of the grid); the ray marcher reads the grid itself.
    /// Default: the density's, or coarser by the smallest integer factor at which J fits one
    /// storage binding — for every 8³ brick of the box, or else for the bricks near density
    /// (`crate::light_map`, `mapper::light::light_map`).
    pub light_res: Option<[u32; 3]>,
    /// Beams cross the cache cells no stage reads (no density within a cell and three light
    /// voxels) in one step instead of by Woodcock tracking (`photon_trace.wgsl`); `None`: on
    /// when the light volumes are coarser than the grid or stored sparse (a large box, often
    /// mostly empty).
    pub skip_empty: Option<bool>,
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
    /// Axis of the cells' HG lobes; `None`: the variant's (exact: [`LobeAxis::Flux`],
    /// elek2012: [`LobeAxis::Sun`]).
    pub lobe_axis: Option<LobeAxis>,
    /// With flux axes: sun light of scattering order ≥ K gets a lobe of its own (`Some(0)`:
    /// one lobe for all orders); `None`: [`DEFAULT_LOBE_SPLIT`].
    pub lobe_split: Option<u32>,
    /// The upsampling's attenuation between a voxel and a coarse cell (Elek §4.3): `false`
    /// (default) λ = σ_s (D(p) − D(q)) / 2 as printed, `true` the mean extinction
    /// σ_s (D(p) + D(q)) / 2.
    pub upsample_mean: bool,
    /// Sun-axis lobes: g' extrapolated as Σ g'(q) g^δ w_L / Σ w_L instead of the formula's
    /// weighted mean Σ g'(q) g^δ w_L / Σ g^δ w_L (Elek §4.3; default false = the formula).
    pub upsample_g_extrapolate: bool,
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
    /// View-dependent cache words (beyond the paper): every deposit also adds the phase
    /// function towards the camera, p(d · ω_v | g), so a converged ring holds the scattered
    /// radiance towards that camera with no lobe approximation; the ray marcher uses it once
    /// every ring slot was traced for the current camera position and the lobes before (and
    /// while the camera moves). `None`: the variant's (see [`PmSettings::effective_view`]).
    pub view_dependent: Option<bool>,
    /// Anisotropy of the view-dependent words' phase function (`None`: the medium's g); the
    /// final gathering sets g^(k+1) (`mapper/gather.rs`).
    pub view_g: Option<f64>,
    /// The default cache as fine as the light volumes where memory and beams allow
    /// ([`PmSettings::default_max_cells`]): the final gathering's, whose only error left is the
    /// cache's spatial resolution.
    pub fine_cache: bool,
    /// Frames over which a sun-transmittance rebuild is spread (1 = at once, the default;
    /// the viewer amortises large volumes: `mapper/sun.rs`).
    pub sun_chunks: u32,
}

impl Default for PmSettings {
    fn default() -> Self {
        Self {
            variant: PmVariant::default(),
            beams_per_frame: 8192,
            ring: 100,
            cache_res: None,
            light_res: None,
            skip_empty: None,
            beam_threshold: 0.01,
            max_order: 1024,
            similarity_t: 0.05,
            similarity_linear: None,
            density_weighted: None,
            lobe_axis: None,
            lobe_split: None,
            upsample_mean: false,
            upsample_g_extrapolate: false,
            step_fraction: 1.0 / 300.0,
            early_exit: 0.02,
            seed: 0,
            detail_noise: 0.0,
            force_global_atomics: false,
            sun_chunks: 1,
            view_dependent: None,
            view_g: None,
            fine_cache: false,
        }
    }
}

/// Largest default ring (all partial caches) with view-dependent words: 128 MiB, WebGPU's
/// default `max_storage_buffer_binding_size` (lavapipe's limit).
pub const VIEW_RING_BYTES: u64 = 128 << 20;

/// Fewest beams in the ring per cache cell for the view-dependent default cache: the bench's
/// ring of 100 × 8 192 beams then allows ≈ 25 600 cells (half the resolution of the held-out
/// clouds), the CLI's smallest (2 × 2 048) the paper's 2 400.
pub const VIEW_BEAMS_PER_CELL: u64 = 32;

/// Fewest beams in the ring per cache cell for the final gathering's default cache
/// ([`PmSettings::fine_cache`]): its paths average each pixel's cache reads over many cells,
/// so cells may hold fewer beams than the ray marcher needs.
pub const GATHER_BEAMS_PER_CELL: u64 = 4;

/// Fewest beams in the ring for the view-dependent words by default. Each deposit carries its
/// phase value towards the camera — up to HG(1) · 4π ≈ 90 × its mean at g = 0.857 — so the
/// words' noise is heavy-tailed, and a typical image from few beams is dark where the mean is
/// right: on the demo cumulus the centre's luminance is 0.21 from 2 × 2 048 beams, 0.39 from
/// 4 × 8 192, 0.356 from 100 × 8 192 (path tracer 0.360; the lobes 0.375 / 0.400 / 0.428).
/// Below this budget the lobes are the default.
pub const VIEW_MIN_RING_BEAMS: u64 = 32 * 1024;

/// Whether the exact variant traces view-dependent words by default.
pub const DEFAULT_VIEW_DEPENDENT: bool = true;

/// Default split order of the two flux lobes (see [`PmSettings::lobe_split`]): orders 1–3
/// (g^k ≥ 0.63 for g = 0.857) keep their forward peak in the low lobe. Measured on
/// `cumulus_side` against Mitsuba, 4×4 error for K = 0 (one lobe) / 2 / 4 / 8 / 19: 0.171 /
/// 0.158 / 0.150 / 0.174 / 0.163.
pub const DEFAULT_LOBE_SPLIT: u32 = 4;

impl PmSettings {
    /// The split order in effect with flux axes (0: one lobe).
    pub fn effective_lobe_split(&self) -> u32 {
        self.lobe_split.unwrap_or(DEFAULT_LOBE_SPLIT)
    }

    /// Whether the view-dependent words are traced (the setting, else the variant's: off for
    /// the paper's method, and for a ring of fewer than [`VIEW_MIN_RING_BEAMS`] beams).
    pub fn effective_view(&self) -> bool {
        self.view_dependent.unwrap_or(
            self.variant == PmVariant::Exact
                && DEFAULT_VIEW_DEPENDENT
                && self.ring as u64 * self.beams_per_frame as u64 >= VIEW_MIN_RING_BEAMS,
        )
    }

    /// Most cells of the default cache (see [`default_cache_res`]): the paper's 2 400 with
    /// lobes; with view-dependent words half the density resolution per axis, as long as the
    /// ring holds at least [`VIEW_BEAMS_PER_CELL`] beams per cell (a finer cache with few beams
    /// is mostly empty) — never below the paper's 2 400 cells — and fits one storage binding of
    /// at most [`VIEW_RING_BYTES`]. Measured on the held-out bench clouds (BENCHMARKS.md): with
    /// the words, the error left is the cache's spatial resolution (`stratus_009` front-lit,
    /// mean ratio 0.88 / 0.96 / 1.01 with 2 205 cells, half and full resolution); with lobes a
    /// finer cache does not help.
    pub fn default_max_cells(&self, d_res: [usize; 3], max_binding: u64) -> u32 {
        if !self.effective_view() {
            return 2400;
        }
        let voxels = d_res.iter().map(|&v| v as u64).product::<u64>();
        let ring = self.ring.max(1) as u64;
        let (cells, per_cell) = if self.fine_cache {
            (voxels, GATHER_BEAMS_PER_CELL)
        } else {
            (voxels / 8, VIEW_BEAMS_PER_CELL)
        };
        let beams = ring * self.beams_per_frame as u64 / per_cell;
        let ring_bytes = ring * crate::cache_layout::CELL_BYTES as u64;
        let budget = max_binding.min(VIEW_RING_BYTES) / ring_bytes;
        cells
            .min(beams)
            .max(2400)
            .min(budget)
            .min(crate::cache_layout::MAX_CACHE_CELLS)
            .clamp(1, u32::MAX as u64) as u32
    }

    /// The lobe axis in effect (the setting, else the variant's).
    pub fn effective_lobe_axis(&self) -> LobeAxis {
        self.lobe_axis.unwrap_or(match self.variant {
            PmVariant::Exact => LobeAxis::Flux,
            PmVariant::Elek2012 => LobeAxis::Sun,
        })
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

/// Slices of an amortised sun-transmittance rebuild in a live view ([`PmSettings::sun_chunks`]
/// 0): at most 2^16 voxel marches per frame, at most 64 frames of lag (less than the default
/// ring of 100 frames). A rebuild of the demo's 128×96×128 cloud at once takes ≈ 8.5 s on
/// lavapipe (2 cores), so ≈ 0.35 s per frame in 24 slices; on a discrete GPU the whole lag is a
/// fraction of a second.
pub fn sun_chunks(res: [usize; 3]) -> u32 {
    (res.iter().product::<usize>().div_ceil(1 << 16)).clamp(1, 64) as u32
}
