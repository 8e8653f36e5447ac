//! Scene files (TOML). Every key is checked: unknown keys, wrong types and invalid values are
//! errors that name the file and the field. Relative paths are relative to the scene file.
//!
//! ```toml
//! [volume]
//! file = "cloud.vol"            # .vol, .npy, .vdb or .nvdb — or instead:
//! # grid = "density"             # .vdb/.nvdb only: the float grid to read (default `density`)
//! # generator = { kind = "cumulus", seed = 7, resolution = [128, 96, 128] }
//! aabb_min = [-1.0, -0.75, -1.0] # world box the grid fills (default: the file header's box,
//! aabb_max = [1.0, 0.75, 1.0]    #  or for generated clouds 2 units wide, centred, cubic voxels)
//! density_scale = 40.0           # σ_t = density_scale × grid value
//! albedo = 1.0
//! phase = { kind = "hg", g = 0.857 }   # or "isotropic", or
//! # phase = { kind = "mie", effective_radius_um = 8.0, effective_variance = 0.1,
//! #           wavelength_nm = 550.0, chop_deg = 5.0 }
//!
//! [sun]                          # optional
//! direction = [1.0, 0.35, -0.1]  # towards the sun
//! irradiance = [1.0, 1.0, 1.0]   # or one number
//! angular_radius_deg = 0.0       # 0 = delta light
//! atmosphere = false             # true: sun and sky colour by elevation (crate::atmosphere)
//!
//! [sky]                          # optional: constant radiance or a lat-long EXR
//! radiance = [0.1, 0.2, 0.4]
//! # envmap = "sky.exr"
//! # scale = 1.0
//!
//! [camera]
//! origin = [0.0, 0.1, 4.2]
//! target = [0.0, 0.0, 0.0]
//! up = [0.0, 1.0, 0.0]
//! vfov_deg = 26.0
//! width = 128
//! height = 96
//!
//! [render]                       # optional
//! spp = 64
//! seed = 0
//! max_depth = -1                 # scattering events per path; −1 = no limit but a 2¹⁸ safety cap
//! ```

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::DVec3;
use serde::Deserialize;

use crate::camera::Camera;
use crate::error::{Error, FieldError, Result};
use crate::generate::{self, CloudKind};
use crate::grid::DensityGrid;
use crate::io;
use crate::light::{EnvMap, Sky, Sun};
use crate::medium::Medium;
use crate::phase::{HenyeyGreenstein, MieParams, Phase, mie};
use crate::volume::{Aabb, Volume};

/// Largest accepted samples per pixel.
pub const MAX_SPP: i64 = 1 << 24;

/// Render settings of a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderSettings {
    pub spp: u32,
    pub seed: u64,
    /// Maximum number of scattering events per path; `None` = unbounded.
    pub max_depth: Option<u32>,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            spp: 64,
            seed: 0,
            max_depth: None,
        }
    }
}

/// Where the volume came from (for reports).
#[derive(Debug, Clone, PartialEq)]
pub enum VolumeSource {
    File(PathBuf),
    Generated { kind: CloudKind, seed: u64 },
    Memory,
}

/// A complete scene.
#[derive(Debug, Clone)]
pub struct Scene {
    /// The file it was read from (labels errors and reports).
    pub source: PathBuf,
    pub volume: Arc<Volume>,
    pub volume_source: VolumeSource,
    pub medium: Medium,
    /// Human-readable phase function description (`hg g=0.857`, `mie r_eff=8µm chop=5°`).
    pub phase_desc: String,
    pub sun: Option<Sun>,
    pub sky: Option<Sky>,
    pub camera: Camera,
    pub render: RenderSettings,
    /// With `[sun] atmosphere = true`: the sun irradiance and constant sky radiance above the
    /// atmosphere, so a moving sun can be recoloured ([`Scene::set_sun_dir`]).
    pub atmosphere: Option<AtmosphereTop>,
}

/// Light above the atmosphere (before the elevation-dependent attenuation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AtmosphereTop {
    pub sun_irradiance: DVec3,
    /// The constant sky's radiance × scale; `None` without a constant sky.
    pub sky_radiance: Option<DVec3>,
}

impl Scene {
    /// A scene built in memory (tests, tools): the volume, medium, lights and camera, default
    /// render settings, no atmosphere; `label` names it in errors and reports.
    pub fn in_memory(
        label: &str,
        volume: Volume,
        medium: Medium,
        sun: Option<Sun>,
        sky: Option<Sky>,
        camera: Camera,
    ) -> Self {
        Self {
            source: label.into(),
            volume: Arc::new(volume),
            volume_source: VolumeSource::Memory,
            medium,
            phase_desc: String::new(),
            sun,
            sky,
            camera,
            render: RenderSettings::default(),
            atmosphere: None,
        }
    }

    /// Points the sun towards `dir` (normalised); with an atmosphere the sun and constant-sky
    /// colours follow the new elevation (crate::atmosphere).
    pub fn set_sun_dir(&mut self, dir: DVec3) {
        let Some(sun) = self.sun.as_mut() else {
            return;
        };
        sun.dir = dir.normalize();
        if let Some(top) = self.atmosphere {
            let h = crate::atmosphere::elevation_deg(sun.dir);
            sun.irradiance = top.sun_irradiance * crate::atmosphere::sun_transmittance(h);
            if let (Some(c), Some(Sky::Constant(sky))) = (top.sky_radiance, self.sky.as_mut()) {
                *sky = c * crate::atmosphere::sky_factor(h);
            }
        }
    }
}

/// What a scene built in code holds in memory instead of in files
/// ([`Scene::from_toml_in_memory`]).
#[derive(Debug, Clone, Default)]
pub struct InMemory {
    /// The density grid, with the box its source gives (`None`: `aabb_min` and `aabb_max`
    /// are required).
    pub grid: Option<(DensityGrid, Option<(DVec3, DVec3)>)>,
    /// A latitude–longitude environment map (linear RGB, row 0 the zenith).
    pub envmap: Option<crate::Image>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    volume: RawVolume,
    sun: Option<RawSun>,
    sky: Option<RawSky>,
    camera: RawCamera,
    render: Option<RawRender>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawVolume {
    file: Option<PathBuf>,
    grid: Option<String>,
    generator: Option<RawGenerator>,
    aabb_min: Option<[f64; 3]>,
    aabb_max: Option<[f64; 3]>,
    #[serde(default = "one")]
    density_scale: f64,
    #[serde(default = "one")]
    albedo: f64,
    phase: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawGenerator {
    kind: String,
    #[serde(default)]
    seed: u64,
    resolution: [i64; 3],
}

#[derive(Deserialize)]
#[serde(untagged)]
enum Rgb {
    Grey(f64),
    Rgb([f64; 3]),
}

impl Rgb {
    fn vec(&self) -> DVec3 {
        match self {
            Rgb::Grey(v) => DVec3::splat(*v),
            Rgb::Rgb(v) => DVec3::from_array(*v),
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSun {
    direction: [f64; 3],
    irradiance: Rgb,
    #[serde(default)]
    angular_radius_deg: f64,
    /// Attenuate sun (and sky) colour by a clear atmosphere for the sun's elevation
    /// (see [`crate::atmosphere`]); `irradiance` is then taken above the atmosphere.
    #[serde(default)]
    atmosphere: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSky {
    radiance: Option<Rgb>,
    envmap: Option<PathBuf>,
    #[serde(default = "one")]
    scale: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    origin: [f64; 3],
    target: [f64; 3],
    #[serde(default = "y_up")]
    up: [f64; 3],
    vfov_deg: f64,
    width: i64,
    height: i64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRender {
    #[serde(default = "default_spp")]
    spp: i64,
    #[serde(default)]
    seed: u64,
    #[serde(default = "minus_one")]
    max_depth: i64,
}

fn one() -> f64 {
    1.0
}
fn y_up() -> [f64; 3] {
    [0.0, 1.0, 0.0]
}
fn default_spp() -> i64 {
    64
}
fn minus_one() -> i64 {
    -1
}

/// Prefixes a field error's name with a section.
fn within(section: &str) -> impl Fn(FieldError) -> FieldError + '_ {
    move |e| {
        if e.field.starts_with(section) {
            e
        } else {
            FieldError::new(format!("{section}.{}", e.field), e.msg)
        }
    }
}

/// Parses a `phase` value: `"isotropic"` or a table with `kind`.
pub fn parse_phase(
    v: Option<&toml::Value>,
) -> Result<(Phase, Option<MieParams>, String), FieldError> {
    let Some(v) = v else {
        return Ok((Phase::Isotropic, None, "isotropic".into()));
    };
    let (kind, table) = match v {
        toml::Value::String(s) => (s.clone(), toml::Table::new()),
        toml::Value::Table(t) => {
            let kind = t
                .get("kind")
                .and_then(|k| k.as_str())
                .ok_or_else(|| FieldError::new("phase.kind", "missing (isotropic, hg or mie)"))?;
            (kind.to_string(), t.clone())
        }
        _ => {
            return Err(FieldError::new(
                "phase",
                "must be \"isotropic\" or a table such as { kind = \"hg\", g = 0.857 }",
            ));
        }
    };
    let num = |key: &str| -> Result<Option<f64>, FieldError> {
        match table.get(key) {
            None => Ok(None),
            Some(toml::Value::Float(f)) => Ok(Some(*f)),
            Some(toml::Value::Integer(i)) => Ok(Some(*i as f64)),
            Some(_) => Err(FieldError::new(format!("phase.{key}"), "must be a number")),
        }
    };
    let allow = |keys: &[&str]| -> Result<(), FieldError> {
        for k in table.keys() {
            if k != "kind" && !keys.contains(&k.as_str()) {
                return Err(FieldError::new(
                    format!("phase.{k}"),
                    format!("unknown key for phase kind `{kind}` (allowed: {keys:?})"),
                ));
            }
        }
        Ok(())
    };
    match kind.as_str() {
        "isotropic" => {
            allow(&[])?;
            Ok((Phase::Isotropic, None, "isotropic".into()))
        }
        "hg" => {
            allow(&["g"])?;
            let g = num("g")?.ok_or_else(|| FieldError::new("phase.g", "missing"))?;
            let hg = HenyeyGreenstein::new(g).map_err(within("phase"))?;
            Ok((Phase::HenyeyGreenstein(hg), None, format!("hg g={g}")))
        }
        "mie" => {
            allow(&[
                "effective_radius_um",
                "effective_variance",
                "wavelength_nm",
                "refractive_index",
                "chop_deg",
            ])?;
            let d = MieParams::default();
            let p = MieParams {
                effective_radius_um: num("effective_radius_um")?.unwrap_or(d.effective_radius_um),
                effective_variance: num("effective_variance")?.unwrap_or(d.effective_variance),
                wavelength_nm: num("wavelength_nm")?.unwrap_or(d.wavelength_nm),
                refractive_index: num("refractive_index")?.unwrap_or(d.refractive_index),
                chop_deg: num("chop_deg")?.unwrap_or(d.chop_deg),
            };
            p.validate().map_err(within("phase"))?;
            let desc = format!(
                "mie r_eff={}µm v_eff={} λ={}nm chop={}°",
                p.effective_radius_um, p.effective_variance, p.wavelength_nm, p.chop_deg
            );
            // The phase itself is built by the caller with the albedo (chopping needs it).
            Ok((Phase::Isotropic, Some(p), desc))
        }
        other => Err(FieldError::new(
            "phase.kind",
            format!("unknown phase function `{other}` (expected isotropic, hg or mie)"),
        )),
    }
}

/// The largest scene file read: scene files are a few KiB of TOML, and a file far larger is
/// something else (read whole, it would take its size in memory and its parse error would quote
/// its longest line).
pub const MAX_SCENE_BYTES: u64 = 1 << 20;

/// A parse error's text with each quoted line cut to 200 characters: the error quotes the
/// offending line, which in a file that is not a scene can be megabytes long.
fn clip_lines(msg: &str) -> String {
    const MAX: usize = 200;
    msg.lines()
        .map(|l| match l.char_indices().nth(MAX) {
            Some((at, _)) => format!("{}… ({} more bytes)", &l[..at], l.len() - at),
            None => l.to_string(),
        })
        .collect::<Vec<_>>()
        .join("\n")
}

impl Scene {
    /// Reads a scene file (at most [`MAX_SCENE_BYTES`]).
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let (_, len) = crate::fsio::open(path, crate::fsio::Hold::Streamed)?;
        if len > MAX_SCENE_BYTES {
            return Err(Error::parse(
                path,
                format!(
                    "a scene file of {}: scene files are text of a few KiB (at most {}); \
                     volumes belong in their own files (volume.file)",
                    crate::memory::human(len as u128),
                    crate::memory::human(MAX_SCENE_BYTES as u128)
                ),
            ));
        }
        // Read at most the size it has now (a file that grew since is cut there).
        let text = crate::fsio::read_to_string(path)?;
        let base = path.parent().unwrap_or(Path::new("."));
        Self::from_toml_str(&text, base, path)
    }

    /// Parses scene text; relative paths resolve against `base_dir`; `label` names the source in
    /// errors.
    pub fn from_toml_str(text: &str, base_dir: &Path, label: &Path) -> Result<Self> {
        Self::from_toml_in_memory(text, base_dir, label, InMemory::default())
    }

    /// [`Scene::from_toml_str`] with data held in memory instead of files (the Python module's
    /// numpy arrays): `memory.grid` is the volume of a `[volume]` that names neither `file`
    /// nor `generator`, `memory.envmap` the map of a `[sky]` that gives neither `radiance` nor
    /// `envmap`. Every other field is read and checked as a scene file's.
    pub fn from_toml_in_memory(
        text: &str,
        base_dir: &Path,
        label: &Path,
        memory: InMemory,
    ) -> Result<Self> {
        let raw: RawScene = toml::from_str(text).map_err(|e| {
            Error::parse(
                label,
                format!("invalid scene: {}", clip_lines(&e.to_string())),
            )
        })?;
        let at = |e: FieldError| e.at(label);
        let v = &raw.volume;
        // Volume grid.
        let (grid, header_bounds, source) = match (&v.file, &v.generator) {
            (Some(_), Some(_)) => {
                return Err(Error::invalid(
                    label,
                    "volume",
                    "give either `file` or `generator`, not both",
                ));
            }
            (None, None) => match memory.grid {
                Some((grid, bounds)) => (grid, bounds, VolumeSource::Memory),
                None => {
                    return Err(Error::invalid(
                        label,
                        "volume",
                        "needs `file = \"...\"` or `generator = { kind, seed, resolution }`",
                    ));
                }
            },
            (Some(f), None) => {
                if f.as_os_str().is_empty() {
                    return Err(Error::invalid(
                        label,
                        "volume.file",
                        "is empty: name a .vol, .npy, .vdb or .nvdb file",
                    ));
                }
                let p = base_dir.join(f);
                let gf = io::read_grid_named(&p, v.grid.as_deref())?;
                (gf.grid, gf.bounds, VolumeSource::File(p))
            }
            (None, Some(g)) => {
                if v.grid.is_some() {
                    return Err(Error::invalid(
                        label,
                        "volume.grid",
                        "names a grid of a .vdb or .nvdb `file`; a generator makes its own",
                    ));
                }
                let kind: CloudKind = g
                    .kind
                    .parse()
                    .map_err(|e| at(within("volume.generator")(e)))?;
                let res =
                    crate::grid::check_resolution(g.resolution, "volume.generator.resolution")
                        .map_err(at)?;
                let grid = generate::generate(kind, g.seed, res)
                    .map_err(|e| at(within("volume.generator")(e)))?;
                let b = generate::default_aabb(res);
                (
                    grid,
                    Some(b),
                    VolumeSource::Generated { kind, seed: g.seed },
                )
            }
        };
        let (bmin, bmax) = match (v.aabb_min, v.aabb_max, header_bounds) {
            (Some(a), Some(b), _) => (DVec3::from_array(a), DVec3::from_array(b)),
            (None, None, Some(h)) => h,
            (None, None, None) => {
                return Err(Error::invalid(
                    label,
                    "volume.aabb_min",
                    "required: this volume file stores no bounding box (give aabb_min and aabb_max)",
                ));
            }
            _ => {
                return Err(Error::invalid(
                    label,
                    "volume.aabb_max",
                    "give both aabb_min and aabb_max, or neither",
                ));
            }
        };
        let aabb = Aabb::new(bmin, bmax).map_err(|e| at(within("volume")(e)))?;
        let volume =
            Volume::new(grid, aabb, v.density_scale).map_err(|e| at(within("volume")(e)))?;
        // Medium.
        let (phase, mie_params, phase_desc) =
            parse_phase(v.phase.as_ref()).map_err(|e| at(within("volume")(e)))?;
        let medium = match mie_params {
            Some(p) => {
                let m = mie::cached(&p).map_err(|e| at(within("volume.phase")(e)))?;
                Medium::mie(v.albedo, &m).map_err(at)?
            }
            None => Medium::new(v.albedo, phase).map_err(at)?,
        };
        // Lights.
        // Atmospheric attenuation by sun elevation (applies to the sun and a constant sky).
        let atmosphere = raw.sun.as_ref().filter(|s| s.atmosphere).map(|s| {
            let h = crate::atmosphere::elevation_deg(DVec3::from_array(s.direction));
            (
                crate::atmosphere::sun_transmittance(h),
                crate::atmosphere::sky_factor(h),
            )
        });
        let sun = match &raw.sun {
            Some(s) => Some(
                Sun::new(
                    DVec3::from_array(s.direction),
                    s.irradiance.vec() * atmosphere.map_or(DVec3::ONE, |a| a.0),
                    s.angular_radius_deg,
                )
                .map_err(at)?,
            ),
            None => None,
        };
        let sky = match &raw.sky {
            None => None,
            Some(s) => match (&s.radiance, &s.envmap) {
                (Some(_), Some(_)) => {
                    return Err(Error::invalid(
                        label,
                        "sky",
                        "give either `radiance` or `envmap`, not both",
                    ));
                }
                (None, None) if memory.envmap.is_none() => {
                    return Err(Error::invalid(label, "sky", "needs `radiance` or `envmap`"));
                }
                // The scale is the scene's, for either kind of sky: checked here (an env map's
                // errors otherwise name the EXR). Each factor on its own: -1 × -1 is no sky
                // radiance of 1.
                _ if !(s.scale.is_finite() && s.scale >= 0.0) => {
                    return Err(Error::invalid(
                        label,
                        "sky.scale",
                        format!("must be finite and ≥ 0, got {}", s.scale),
                    ));
                }
                (Some(r), None) => {
                    let c = r.vec() * s.scale * atmosphere.map_or(DVec3::ONE, |a| a.1);
                    if !r.vec().is_finite() || r.vec().min_element() < 0.0 {
                        return Err(Error::invalid(
                            label,
                            "sky.radiance",
                            "must be finite and ≥ 0",
                        ));
                    }
                    // (also an overflow of the product to ∞)
                    if !c.is_finite() || c.max_element() > crate::light::MAX_RADIANCE {
                        return Err(Error::invalid(
                            label,
                            "sky.radiance",
                            format!(
                                "radiance × scale = {:e} exceeds {:e} (images are stored as f32)",
                                c.max_element(),
                                crate::light::MAX_RADIANCE
                            ),
                        ));
                    }
                    Some(Sky::Constant(c))
                }
                (None, None) => Some(Sky::Env(
                    EnvMap::new(memory.envmap.expect("checked above"), s.scale)
                        .map_err(|e| e.at(label))?,
                )),
                (None, Some(e)) => Some(Sky::Env(
                    EnvMap::load(&base_dir.join(e), s.scale).map_err(|err| match err {
                        // A file that cannot be read or parsed: name the scene's field too.
                        Error::Io { .. } | Error::Parse { .. } => {
                            Error::invalid(label, "sky.envmap", err.to_string())
                        }
                        // The scale is the scene's field (scale × brightest texel too large).
                        Error::Invalid { path, field, msg } if field == "sky.scale" => {
                            Error::invalid(label, field, format!("{msg} ({})", path.display()))
                        }
                        invalid => invalid,
                    })?,
                )),
            },
        };
        // A black sky costs work and adds nothing: leave it out.
        let sky = sky.filter(|s| !s.is_black());
        let c = &raw.camera;
        let dim = |v: i64, name: &str| -> Result<usize> {
            if v < 1 || v > crate::camera::MAX_IMAGE_SIDE as i64 {
                Err(Error::invalid(
                    label,
                    name,
                    format!("must lie in 1..={}, got {v}", crate::camera::MAX_IMAGE_SIDE),
                ))
            } else {
                Ok(v as usize)
            }
        };
        let camera = Camera::new(
            DVec3::from_array(c.origin),
            DVec3::from_array(c.target),
            DVec3::from_array(c.up),
            c.vfov_deg,
            dim(c.width, "camera.width")?,
            dim(c.height, "camera.height")?,
        )
        .map_err(at)?;
        let render = match &raw.render {
            None => RenderSettings::default(),
            Some(r) => {
                if r.spp < 1 || r.spp > MAX_SPP {
                    return Err(Error::invalid(
                        label,
                        "render.spp",
                        format!("must lie in 1..={MAX_SPP}, got {}", r.spp),
                    ));
                }
                if r.max_depth < -1 || r.max_depth > u32::MAX as i64 {
                    return Err(Error::invalid(
                        label,
                        "render.max_depth",
                        format!("must be −1 (unbounded) or ≥ 0, got {}", r.max_depth),
                    ));
                }
                RenderSettings {
                    spp: r.spp as u32,
                    seed: r.seed,
                    max_depth: (r.max_depth >= 0).then_some(r.max_depth as u32),
                }
            }
        };
        Ok(Scene {
            source: label.to_path_buf(),
            volume: Arc::new(volume),
            volume_source: source,
            medium,
            phase_desc,
            sun,
            sky,
            camera,
            render,
            atmosphere: raw
                .sun
                .as_ref()
                .filter(|s| s.atmosphere)
                .map(|s| AtmosphereTop {
                    sun_irradiance: s.irradiance.vec(),
                    sky_radiance: raw
                        .sky
                        .as_ref()
                        .and_then(|k| k.radiance.as_ref().map(|r| r.vec() * k.scale)),
                }),
        })
    }
}
