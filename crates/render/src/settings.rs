//! The estimators' settings by name, as the command line's flags spell them (without the dashes,
//! `_` for `-`: `sky_dirs`, `pm_variant`, `query_every`, …): one table from a name to a setter on
//! [`Options`], so a front end that takes settings by name (the Python module's
//! `render(scene, method, **settings)`) fills the same fields with the same checks as the flags.
//!
//! Every value is given as text, as on the command line (`"true"`/`"false"` for a switch,
//! `"64,32,64"` for three numbers); a bad value is an error naming the setting and what it
//! accepts, an unknown name an error listing the known ones.

#[cfg(feature = "rpnn")]
use std::path::PathBuf;

#[cfg(feature = "rpnn")]
use crate::NetBackend;
use crate::{Method, Options};

/// One setting: its name, what it does and accepts, and its setter.
pub struct Setting {
    /// The command line's flag without its dashes, `_` for `-`.
    pub name: &'static str,
    /// One line: what it sets and the values it accepts.
    pub help: &'static str,
    set: fn(&mut Options, &str) -> Result<(), String>,
}

/// The options every estimator starts from: those of the command line with no flag given,
/// `seed` the render's seed (the photon map's seed is the render's, as `nimbus render` sets
/// it).
pub fn defaults(seed: u64) -> Options {
    let mut o = Options::default();
    o.pm.seed = seed as u32;
    o.pm.density_weighted = Some(false);
    o
}

/// Sets `name` to `value` (text, as the flag's value) in `opts`.
pub fn set(opts: &mut Options, name: &str, value: &str) -> Result<(), String> {
    let Some(s) = all().find(|s| s.name == name) else {
        let names: Vec<&str> = names().collect();
        return Err(format!(
            "unknown setting `{name}` (known: {})",
            names.join(", ")
        ));
    };
    (s.set)(opts, value.trim()).map_err(|e| format!("setting `{name}`: {e}"))
}

/// The budget of one render as `nimbus render` takes it: `spp` samples per pixel, or for the
/// ray-marched photon maps ([`Method::budget_is_ring`]) the ring's frames (`ring`'s value).
pub fn budget(method: Method, opts: &Options, spp: u32) -> u32 {
    if method.budget_is_ring() {
        opts.pm.ring
    } else {
        spp
    }
}

/// The names of the settings, in the table's order.
pub fn names() -> impl Iterator<Item = &'static str> {
    all().map(|s| s.name)
}

fn int(v: &str, lo: u64, hi: u64) -> Result<u32, String> {
    match v.parse::<u64>() {
        Ok(n) if (lo..=hi).contains(&n) => Ok(n as u32),
        _ => Err(format!("must be a whole number in {lo}..={hi}, got `{v}`")),
    }
}

fn float(v: &str, ok: impl Fn(f64) -> bool, what: &str) -> Result<f64, String> {
    match v.parse::<f64>() {
        Ok(x) if x.is_finite() && ok(x) => Ok(x),
        _ => Err(format!("must be {what}, got `{v}`")),
    }
}

fn switch(v: &str) -> Result<bool, String> {
    match v.to_ascii_lowercase().as_str() {
        "true" | "1" | "yes" | "on" => Ok(true),
        "false" | "0" | "no" | "off" => Ok(false),
        _ => Err(format!("must be true or false, got `{v}`")),
    }
}

/// One of `names` (the flag's values), as its index.
fn choice(v: &str, names: &[&str]) -> Result<usize, String> {
    names
        .iter()
        .position(|n| n.eq_ignore_ascii_case(v))
        .ok_or_else(|| format!("must be one of {}, got `{v}`", names.join(", ")))
}

fn triple(v: &str) -> Result<Option<[u32; 3]>, String> {
    let parts: Vec<&str> = v
        .trim_matches(|c| c == '(' || c == ')' || c == '[' || c == ']')
        .split(',')
        .map(str::trim)
        .filter(|p| !p.is_empty())
        .collect();
    let bad = || format!("needs three whole numbers X,Y,Z ≥ 1, got `{v}`");
    if parts.len() != 3 {
        return Err(bad());
    }
    let mut out = [0u32; 3];
    for (o, p) in out.iter_mut().zip(parts) {
        *o = p.parse().ok().filter(|&n| n >= 1).ok_or_else(bad)?;
    }
    Ok(Some(out))
}

macro_rules! setting {
    ($name:literal, $help:literal, |$o:ident, $v:ident| $body:expr) => {
        Setting {
            name: $name,
            help: $help,
            set: |$o: &mut Options, $v: &str| -> Result<(), String> {
                $body;
                Ok(())
            },
        }
    };
}

/// Every setting, by the name of its flag: the photon map's, then RPNN's (with the `rpnn`
/// feature).
pub fn all() -> impl Iterator<Item = &'static Setting> {
    let rpnn: &'static [Setting] = {
        #[cfg(feature = "rpnn")]
        {
            RPNN
        }
        #[cfg(not(feature = "rpnn"))]
        {
            &[]
        }
    };
    PM.iter().chain(rpnn)
}

/// The photon map's settings (`PmArgs`, `GatherArgs`).
static PM: &[Setting] = &[
    // Photon mapping (`PmArgs`, `GatherArgs`).
    setting!(
        "beams",
        "photon mapping: beams per frame n_g, 1..=2^26 (default 8192; with final gathering 65536)",
        |o, v| {
            let b = int(v, 1, 1 << 26)?;
            o.pm.beams_per_frame = b;
            o.pm_gather.beams = b;
        }
    ),
    setting!(
        "ring",
        "photon mapping: partial caches in the ring m, 1..=4096 (default 100; with final gathering 8); the budget of pm-march and pm-elek2012",
        |o, v| {
            let r = int(v, 1, 4096)?;
            o.pm.ring = r;
            o.pm_gather.ring = r;
        }
    ),
    setting!("pm_variant", "photon mapping: exact or elek2012", |o, v| {
        o.pm.variant = [
            nimbus_photon::PmVariant::Exact,
            nimbus_photon::PmVariant::Elek2012,
        ][choice(v, &["exact", "elek2012"])?]
    }),
    setting!(
        "pm_density_weighted",
        "photon mapping: density-weighted deposits, true or false",
        |o, v| o.pm.density_weighted = Some(switch(v)?)
    ),
    setting!(
        "pm_lobe_axis",
        "photon mapping: the cells' lobe axis, sun or flux (default: the variant's)",
        |o, v| {
            o.pm.lobe_axis = Some(
                [
                    nimbus_photon::mapper::LobeAxis::Sun,
                    nimbus_photon::mapper::LobeAxis::Flux,
                ][choice(v, &["sun", "flux"])?],
            )
        }
    ),
    setting!(
        "pm_lobe_split",
        "photon mapping with flux axes: the order from which light gets a lobe of its own, 0..=1024",
        |o, v| o.pm.lobe_split = Some(int(v, 0, 1024)?)
    ),
    setting!(
        "pm_upsample_lambda",
        "photon mapping: the upsampling's attenuation, difference or mean",
        |o, v| o.pm.upsample_mean = choice(v, &["difference", "mean"])? == 1
    ),
    setting!(
        "pm_upsample_g_extrapolate",
        "photon mapping with sun-axis lobes: extrapolate g', true or false",
        |o, v| o.pm.upsample_g_extrapolate = switch(v)?
    ),
    setting!(
        "pm_in_scatter",
        "photon mapping: in-scattering towards the camera, view or lobes (default: the variant's)",
        |o, v| o.pm.view_dependent = Some(choice(v, &["view", "lobes"])? == 0)
    ),
    setting!(
        "cache_res",
        "photon mapping: cache resolution X,Y,Z",
        |o, v| o.pm.cache_res = triple(v)?
    ),
    setting!(
        "light_res",
        "photon mapping: light-volume resolution X,Y,Z",
        |o, v| o.pm.light_res = triple(v)?
    ),
    setting!(
        "half_res",
        "photon mapping: ray march at half resolution, true or false",
        |o, v| o.pm_half_res = switch(v)?
    ),
    setting!(
        "detail_noise",
        "photon mapping: detail noise amplitude in density voxels, ≥ 0",
        |o, v| o.pm.detail_noise = float(v, |x| x >= 0.0, "a number ≥ 0")? as f32
    ),
    setting!(
        "similarity",
        "photon mapping: similarity threshold t in [0, 1)",
        |o, v| o.pm.similarity_t = float(v, |x| (0.0..1.0).contains(&x), "in [0, 1)")?
    ),
    setting!(
        "max_order",
        "photon mapping: scatterings after which a beam stops, 0..=2^32-1",
        |o, v| o.pm.max_order = int(v, 0, u32::MAX as u64)?
    ),
    setting!(
        "gather_bounces",
        "final gathering (pm): phase-sampled bounces k, 0..=1000000",
        |o, v| o.pm_gather.bounces = int(v, 0, 1_000_000)?
    ),
    setting!(
        "pm_shadow",
        "final gathering (pm): the sun at each collision, auto, volume or rays",
        |o, v| {
            o.pm_gather.shadow = [
                nimbus_photon::SunShadow::Auto,
                nimbus_photon::SunShadow::Volume,
                nimbus_photon::SunShadow::Rays,
            ][choice(v, &["auto", "volume", "rays"])?]
        }
    ),
    setting!(
        "gather_terminal",
        "final gathering (pm): what a path reads where it ends, view or lobes",
        |o, v| {
            o.pm_gather.terminal = [
                nimbus_photon::Terminal::View,
                nimbus_photon::Terminal::Lobes,
            ][choice(v, &["view", "lobes"])?]
        }
    ),
    setting!(
        "gather_spread",
        "final gathering (pm): the share c of the bounces' spread, in [0, 1]",
        |o, v| o.pm_gather.spread = float(v, |x| (0.0..=1.0).contains(&x), "in [0, 1]")?
    ),
    setting!(
        "ring_refresh",
        "final gathering (pm): gathered samples per new generation, 0..=1000000 (0: never)",
        |o, v| o.pm_gather.ring_refresh = int(v, 0, 1_000_000)?
    ),
];

/// RPNN's settings (`RpnnArgs`).
#[cfg(feature = "rpnn")]
static RPNN: &[Setting] = &[
    setting!(
        "model",
        "rpnn: the ONNX model file (default: the shipped model for the scene)",
        |o, v| {
            if v.is_empty() {
                return Err("must name a file".into());
            }
            o.rpnn.model = Some(PathBuf::from(v))
        }
    ),
    setting!(
        "backend",
        "rpnn: where the network runs, auto, wgpu, ort or ort-int8",
        |o, v| {
            o.rpnn.backend = [
                NetBackend::Auto,
                NetBackend::Wgpu,
                NetBackend::Ort,
                NetBackend::OrtInt8,
            ][choice(v, &["auto", "wgpu", "ort", "ort-int8"])?]
        }
    ),
    setting!(
        "sky_dirs",
        "rpnn: sky directions per shading point and sample, 1..=1024 (default 4)",
        |o, v| o.rpnn.sky_dirs = int(v, 1, 1024)?
    ),
    setting!(
        "sky_degree",
        "rpnn with a sky head: spherical-harmonic degree, 0..=4",
        |o, v| o.rpnn.sky_degree = int(v, 0, 4)? as usize
    ),
    setting!(
        "strict",
        "rpnn: refuse a model trained for another medium, true or false",
        |o, v| o.rpnn.strict = switch(v)?
    ),
    setting!(
        "cpu_shading",
        "rpnn with the network on the GPU: shade on the CPU anyway, true or false",
        |o, v| o.rpnn.cpu_shading = switch(v)?
    ),
    setting!(
        "net_precision",
        "rpnn with the network on the GPU: f32 or f16",
        |o, v| {
            o.rpnn.precision = [
                nimbus_rpnn::gpu_mlp::Precision::F32,
                nimbus_rpnn::gpu_mlp::Precision::F16,
            ][choice(v, &["f32", "f16"])?]
        }
    ),
    setting!(
        "net_tiles",
        "rpnn with the network on the GPU: kernel tiles, 64x64 or 64x128",
        |o, v| {
            o.rpnn.tiles = [
                nimbus_rpnn::gpu_mlp::Tiles::Square,
                nimbus_rpnn::gpu_mlp::Tiles::Wide,
            ][choice(v, &["64x64", "64x128"])?]
        }
    ),
    setting!(
        "traced_bounces",
        "rpnn: bounces traced before the network is asked, 0..=16",
        |o, v| {
            o.rpnn.traced_bounces = int(v, 0, nimbus_rpnn::render::MAX_TRACED_BOUNCES as u64)?
        }
    ),
    setting!(
        "query_every",
        "rpnn: one sample in every M asks the network, 1..=64",
        |o, v| o.rpnn.query_every = int(v, 1, nimbus_rpnn::render::MAX_QUERY_EVERY as u64)?
    ),
];

#[cfg(test)]
mod tests {
    use super::*;

    /// Names set their fields with the flags' checks; bad values and unknown names are refused
    /// with the name and what is accepted.
    #[test]
    #[cfg(feature = "rpnn")]
    fn by_name() {
        let mut o = defaults(7);
        assert_eq!(o.pm.seed, 7);
        set(&mut o, "sky_dirs", "16").unwrap();
        set(&mut o, "pm_variant", "elek2012").unwrap();
        set(&mut o, "ring", "12").unwrap();
        set(&mut o, "backend", "ort").unwrap();
        set(&mut o, "cache_res", "8,6,8").unwrap();
        set(&mut o, "half_res", "true").unwrap();
        assert_eq!(o.rpnn.sky_dirs, 16);
        assert_eq!(o.pm.variant, nimbus_photon::PmVariant::Elek2012);
        assert_eq!((o.pm.ring, o.pm_gather.ring), (12, 12));
        assert_eq!(o.rpnn.backend, NetBackend::Ort);
        assert_eq!(o.pm.cache_res, Some([8, 6, 8]));
        assert!(o.pm_half_res);
        assert_eq!(budget(Method::PmMarch, &o, 64), 12);
        assert_eq!(budget(Method::Pt, &o, 64), 64);
        let e = set(&mut o, "sky_dirs", "0").unwrap_err();
        assert!(e.contains("sky_dirs") && e.contains("1..=1024"), "{e}");
        let e = set(&mut o, "backend", "cuda").unwrap_err();
        assert!(e.contains("backend") && e.contains("ort-int8"), "{e}");
        let e = set(&mut o, "sky_dir", "4").unwrap_err();
        assert!(
            e.contains("unknown setting `sky_dir`") && e.contains("sky_dirs"),
            "{e}"
        );
        let e = set(&mut o, "cache_res", "8,6").unwrap_err();
        assert!(e.contains("X,Y,Z"), "{e}");
        // Every name is unique.
        let mut n: Vec<&str> = names().collect();
        n.sort();
        n.dedup();
        assert_eq!(n.len(), all().count());
    }
}
