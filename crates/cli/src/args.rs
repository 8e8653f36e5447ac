//! Argument types and checks shared by several commands: the photon-mapping flags and value
//! parsers that give flags the same checks as scene keys.

use std::str::FromStr;

use anyhow::Result;
use clap::ValueEnum;
use clap::builder::{PossibleValuesParser, TypedValueParser};
use nimbus_photon::mapper::LobeAxis;
use nimbus_photon::{PmVariant, SunShadow, Terminal};

/// A library enum parsed by its own `FromStr`; `all` and `name` (its `ALL` and `name()`) give
/// the names clap lists in `--help` and in its error for any other value.
pub(crate) fn one_of<T, const N: usize>(
    all: [T; N],
    name: fn(T) -> &'static str,
) -> impl TypedValueParser<Value = T>
where
    T: FromStr<Err = String> + Clone + Send + Sync + 'static,
{
    PossibleValuesParser::new(all.map(name)).try_map(|s| s.parse::<T>())
}

/// `render --device`, `bench-suite --device`, `datagen --device`.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum Device {
    Cpu,
    Gpu,
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum UpsampleLambdaArg {
    Difference,
    Mean,
}

/// The final gathering's flags (`render`, `compare`, `bench-suite`, `view`).
#[derive(clap::Args, Clone)]
pub(crate) struct GatherArgs {
    /// Photon mapping with final gathering (`pm`): phase-sampled bounces k before the photon map
    /// is read (0: the cache at the camera ray's collision, a smooth biased preview); every sun
    /// order up to k + 1 is computed exactly.
    #[arg(long, default_value_t = nimbus_photon::mapper::DEFAULT_GATHER_BOUNCES,
          value_parser = clap::value_parser!(u32).range(0..=1_000_000))]
    pub(crate) gather_bounces: u32,
    /// Photon mapping with final gathering: the sun at each collision from the
    /// sun-transmittance volume (`volume`: its single scattering ray marched) or by a
    /// ratio-tracked shadow ray (`rays`); `auto`: the volume where the light volumes have the
    /// grid's resolution, else rays.
    #[arg(long, default_value = "auto", value_parser = one_of(SunShadow::ALL, SunShadow::name))]
    pub(crate) pm_shadow: SunShadow,
    /// Photon mapping with final gathering: what a gather path reads where it ends: `view`
    /// (view-dependent words with the phase function HG(g^(1 + k c)) towards the camera, c of
    /// `--gather-spread`) or `lobes` (each cell's two flux lobes towards the previous vertex).
    #[arg(long, default_value = "view", value_parser = one_of(Terminal::ALL, Terminal::name))]
    pub(crate) gather_terminal: Terminal,
    /// Photon mapping with final gathering, `view` terminal: the share c ∈ [0, 1] of the
    /// bounces' angular spread the view-dependent words average over (phase function
    /// HG(g^(1 + k c)); 1: end point and direction independent).
    #[arg(long, default_value_t = nimbus_photon::mapper::DEFAULT_GATHER_SPREAD, value_parser = unit_closed)]
    pub(crate) gather_spread: f64,
    /// Photon mapping with final gathering: trace a new generation into the ring after every
    /// N gathered samples, so the photon map's noise averages out as samples grow (0: the ring
    /// stays as built, its noise fixed at any sample count).
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=1_000_000))]
    pub(crate) ring_refresh: u32,
}

impl GatherArgs {
    /// The gathering's settings; `ring` and `beams` are the photon map's flags when given.
    pub(crate) fn settings(
        &self,
        ring: Option<u32>,
        beams: Option<u32>,
    ) -> nimbus_photon::GatherSettings {
        use nimbus_photon::mapper::{DEFAULT_GATHER_BEAMS, DEFAULT_GATHER_RING};
        nimbus_photon::GatherSettings {
            ring: ring.unwrap_or(DEFAULT_GATHER_RING),
            beams: beams.unwrap_or(DEFAULT_GATHER_BEAMS),
            bounces: self.gather_bounces,
            spread: self.gather_spread,
            ring_refresh: self.ring_refresh,
            shadow: self.pm_shadow,
            terminal: self.gather_terminal,
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum InScatterArg {
    View,
    Lobes,
}

/// Photon-mapping settings shared by `render --method pm` and `animate`.
#[derive(clap::Args)]
pub(crate) struct PmArgs {
    /// Photon mapping: beams traced per frame (n_g), 1..=2²⁶ (default: 8 192, the paper's; with
    /// final gathering 65 536).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=1 << 26))]
    pub(crate) beams: Option<u32>,
    /// Photon mapping: `exact` (default: exact single scattering from a sun-transmittance
    /// volume, the cache for scattered light only, similarity σ(1−g), per-cell flux axes) or
    /// `elek2012` (the paper: one cache for all scattering orders, similarity σ√(1−g), lobes
    /// along the sun); see BENCHMARKS.md.
    #[arg(long, default_value = "exact", value_parser = one_of(PmVariant::ALL, PmVariant::name))]
    pm_variant: PmVariant,
    /// Photon mapping: density-weighted deposits (cells hold the fluence where the medium is,
    /// ⟨σφ⟩/⟨σ⟩, instead of the cell-volume average; experimental, see BENCHMARKS.md).
    #[arg(long)]
    pm_density_weighted: bool,
    /// Photon mapping: axis of each cache cell's HG lobe: `sun` (the paper: cosines to the sun
    /// direction) or `flux` (the cell's mean sun-flux direction, Elek Appendix C). Default:
    /// the variant's (exact: flux, elek2012: sun).
    #[arg(long, value_parser = one_of(LobeAxis::ALL, LobeAxis::name))]
    pm_lobe_axis: Option<LobeAxis>,
    /// Photon mapping with flux axes: sun light scattered K or more times gets a lobe of its
    /// own, so forward-peaked low orders and diffuse high orders are not forced into one HG
    /// lobe (0 = one lobe per cell; default 4).
    #[arg(long, value_parser = clap::value_parser!(u32).range(0..=1024))]
    pm_lobe_split: Option<u32>,
    /// Photon mapping: attenuation λ of the upsampling filter between a voxel p and a cache
    /// cell q: `difference` σ_s (D(p) − D(q))/2 (Elek §4.3 as printed, default) or `mean`
    /// σ_s (D(p) + D(q))/2.
    #[arg(long, value_enum, default_value = "difference")]
    pm_upsample_lambda: UpsampleLambdaArg,
    /// Photon mapping with sun-axis lobes: extrapolate g' as g'(q)·g^δ (Elek §4.3's prose)
    /// instead of using g^δ as a weight (its formula, default).
    #[arg(long)]
    pm_upsample_g_extrapolate: bool,
    /// Photon mapping: in-scattering towards the camera: `view` (deposits weighted by the phase
    /// function towards the camera, exact in angle; used once the ring was traced for the
    /// camera's position) or `lobes` (each cell's HG lobes, view-independent). Default: the
    /// variant's (exact: view, elek2012: lobes); see BENCHMARKS.md.
    #[arg(long, value_enum)]
    pm_in_scatter: Option<InScatterArg>,
    /// Photon mapping: partial caches in the ring (m; default 100, the paper's; with final
    /// gathering 8), 1..=4096.
    #[arg(long, value_parser = crate::flags::int_in(1u32, 4096))]
    pub(crate) ring: Option<u32>,
    /// Photon mapping: cache resolution X,Y,Z (default: ≤ 2400 cells, the grid's proportions).
    #[arg(long, value_parser = crate::flags::u32_triple(1, 1 << 16))]
    cache_res: Option<[u32; 3]>,
    /// Photon mapping: resolution X,Y,Z of the light volumes (J, T_sun) and of the block-averaged
    /// density the photons trace (default: the grid's, stored only in the 8³ bricks near
    /// density where the whole box's J would not fit one GPU storage binding, or coarser by an
    /// integer factor when even those would not); the ray marcher reads the grid itself.
    #[arg(long, value_parser = crate::flags::u32_triple(1, 1 << 16))]
    light_res: Option<[u32; 3]>,
    /// Photon mapping: ray march at half resolution and upscale.
    #[arg(long)]
    pub(crate) half_res: bool,
    /// Photon mapping: detail noise amplitude in density voxels, in [0, 16] (0 = off).
    #[arg(long, default_value_t = 0.0, value_parser = crate::flags::f32_in(0.0, 16.0))]
    detail_noise: f32,
    /// Photon mapping: similarity threshold t (switch to σ√(1−g), isotropic, after
    /// log t / log|g| bounces; 0 = never switch); in [0, 1).
    #[arg(long, default_value_t = 0.05, value_parser = unit_interval)]
    similarity: f64,
    /// Photon mapping: a beam stops after this many scatterings (0..=65536).
    #[arg(long, default_value_t = 1024, value_parser = crate::flags::int_in(0u32, 1 << 16))]
    max_order: u32,
}

impl PmArgs {
    pub(crate) fn settings(&self, seed: u32) -> Result<nimbus_photon::PmSettings> {
        Ok(nimbus_photon::PmSettings {
            variant: self.pm_variant,
            density_weighted: Some(self.pm_density_weighted),
            lobe_axis: self.pm_lobe_axis,
            lobe_split: self.pm_lobe_split,
            view_dependent: self.pm_in_scatter.map(|a| a == InScatterArg::View),
            upsample_mean: self.pm_upsample_lambda == UpsampleLambdaArg::Mean,
            upsample_g_extrapolate: self.pm_upsample_g_extrapolate,
            beams_per_frame: self.beams.unwrap_or(8192),
            ring: self.ring.unwrap_or(100),
            cache_res: self.cache_res,
            light_res: self.light_res,
            seed,
            detail_noise: self.detail_noise,
            similarity_t: self.similarity,
            max_order: self.max_order,
            ..Default::default()
        })
    }
}

/// An exposure: a finite number in (0, 1e30] (one of 0, NaN or ∞, or one that overflows every
/// pixel, writes an all-black or all-white image).
pub(crate) fn positive_finite(s: &str) -> std::result::Result<f64, String> {
    crate::flags::f64_above(0.0, crate::flags::MAX_EXPOSURE)(s)
}

/// A thread count in 1..=1024 (more threads than that only exhaust the system's limits).
pub(crate) fn thread_count(s: &str) -> std::result::Result<usize, String> {
    let v: usize = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a whole number in 1..=1024"))?;
    if (1..=1024).contains(&v) {
        Ok(v)
    } else {
        Err(format!("must lie in 1..=1024, got {v}"))
    }
}

/// A value in [0, 1].
pub(crate) fn unit_closed(s: &str) -> std::result::Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number"))?;
    if v.is_finite() && (0.0..=1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("must lie in [0, 1], got {s}"))
    }
}

/// A value in [0, 1).
pub(crate) fn unit_interval(s: &str) -> std::result::Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number"))?;
    if v.is_finite() && (0.0..1.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("must lie in [0, 1), got {s}"))
    }
}

/// Flags of `render`, `compare` and `bench-suite` that belong to estimators the command does not
/// run (the photon map's to pm, RPNN's to rpnn), as warnings: given, they would otherwise be
/// ignored without a word.
pub(crate) fn flags_for_other_methods(cmd: &clap::Command, m: &clap::ArgMatches) -> Vec<String> {
    use nimbus_render::Method;
    let Some((name, sub)) = m.subcommand() else {
        return Vec::new();
    };
    let Some(command) = cmd.find_subcommand(name) else {
        return Vec::new();
    };
    let methods: Vec<Method> = match name {
        "render" => sub
            .get_one::<Method>("method")
            .copied()
            .into_iter()
            .collect(),
        "compare" | "bench-suite" => sub
            .get_one::<String>("methods")
            .and_then(|s| nimbus_eval::method::parse_methods(s).ok())
            .unwrap_or_default(),
        _ => return Vec::new(),
    };
    if methods.is_empty() {
        return Vec::new();
    }
    let names: Vec<String> = methods.iter().map(|m| m.to_string()).collect();
    let pm = methods.iter().any(|m| m.is_photon_mapping());
    let rpnn = methods.iter().any(|m| m.is_rpnn());
    // The photon map's flags: render's groups, compare's --beams and --ring and the
    // gathering's group.
    let group = |id: &str| -> Vec<String> {
        command
            .get_groups()
            .find(|g| g.get_id() == id)
            .map(|g| g.get_args().map(|a| a.to_string()).collect())
            .unwrap_or_default()
    };
    let mut pm_ids = group("PmArgs");
    if name != "render" {
        pm_ids.extend(["beams".to_string(), "ring".to_string()]);
    }
    let gather_ids = group("GatherArgs");
    let gather = methods.contains(&Method::Pm);
    let rpnn_ids: Vec<String> = command
        .get_groups()
        .find(|g| g.get_id() == "RpnnArgs")
        .map(|g| g.get_args().map(|id| id.to_string()).collect())
        .unwrap_or_default();
    let mut out = Vec::new();
    for (ids, applies, to) in [
        (pm_ids, pm, "pm, pm-march and pm-elek2012"),
        (gather_ids, gather, "pm"),
        (rpnn_ids, rpnn, "rpnn"),
    ] {
        if applies {
            continue;
        }
        for id in ids {
            if sub.value_source(&id) == Some(clap::parser::ValueSource::CommandLine) {
                let flag = command
                    .get_arguments()
                    .find(|a| a.get_id() == id.as_str())
                    .and_then(|a| a.get_long())
                    .unwrap_or(id.as_str());
                out.push(format!(
                    "warning: --{flag} applies to --method {to}; ignored with {}",
                    if name == "render" {
                        format!("--method {}", names[0])
                    } else {
                        format!("--methods {}", names.join(","))
                    }
                ));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every name a library enum's flag lists parses back to its variant (the names clap shows
    /// and the library's `FromStr` agree).
    #[test]
    fn library_enum_names_parse() {
        fn check<T: FromStr<Err = String> + PartialEq + std::fmt::Debug + Copy, const N: usize>(
            all: [T; N],
            name: fn(T) -> &'static str,
        ) {
            for v in all {
                assert_eq!(name(v).parse::<T>(), Ok(v));
            }
            assert!("bogus".parse::<T>().unwrap_err().contains(name(all[0])));
        }
        check(PmVariant::ALL, PmVariant::name);
        check(LobeAxis::ALL, LobeAxis::name);
        check(SunShadow::ALL, SunShadow::name);
        check(Terminal::ALL, Terminal::name);
        check(
            nimbus_render::NetBackend::ALL,
            nimbus_render::NetBackend::name,
        );
        check(
            nimbus_rpnn::gpu_mlp::Precision::ALL,
            nimbus_rpnn::gpu_mlp::Precision::name,
        );
        check(
            nimbus_rpnn::gpu_mlp::Tiles::ALL,
            nimbus_rpnn::gpu_mlp::Tiles::name,
        );
        check(nimbus_eval::RefDevice::ALL, nimbus_eval::RefDevice::name);
    }
}
