//! Registry of every WGSL file in `shaders/`: the stages (`shaders/*.wgsl`, one per pipeline
//! entry point family) and the modules they import (`shaders/lib/*.wgsl`, plus `constants`,
//! generated from [`crate::consts`]). A stage names what it needs with `#import` lines
//! ([`crate::compose`]); [`source`] returns the composed WGSL. A unit test composes, parses and
//! validates every stage with naga.

use crate::compose::{self, Composed};
use std::borrow::Cow;

/// (name, source) of a stage: `stage!("pt.wgsl")`.
macro_rules! stage {
    ($file:literal) => {
        ($file, include_str!(concat!("../../../shaders/", $file)))
    };
}

/// (name, source) of a module: `module!("rng")` is `shaders/lib/rng.wgsl`.
macro_rules! module {
    ($name:literal) => {
        (
            $name,
            include_str!(concat!("../../../shaders/lib/", $name, ".wgsl")),
        )
    };
}

/// (module name, source) of every module in `shaders/lib/` (file `<name>.wgsl`).
pub const MODULES: &[(&str, &str)] = &[
    module!("params"),
    module!("math"),
    module!("rng"),
    module!("hg"),
    module!("grid"),
    module!("density_dense"),
    module!("density_bricks"),
    module!("light_bricks"),
    module!("density_light"),
    module!("tracking"),
    module!("pt_core"),
    module!("photon_lookup"),
    module!("photon_raymarch_core"),
    module!("photon_gather_core"),
    module!("env_map"),
    module!("rpnn_frame"),
    module!("rpnn_sample_core"),
];

/// (file name, source) of every stage in `shaders/`.
pub const SHADERS: &[(&str, &str)] = &[
    stage!("photon_trace.wgsl"),
    stage!("photon_update.wgsl"),
    stage!("photon_upsample.wgsl"),
    stage!("photon_raymarch.wgsl"),
    stage!("photon_raymarch_bricks.wgsl"),
    stage!("photon_raymarch_light.wgsl"),
    stage!("photon_sun.wgsl"),
    stage!("photon_gather.wgsl"),
    stage!("photon_gather_bricks.wgsl"),
    stage!("photon_gather_light.wgsl"),
    stage!("pt.wgsl"),
    stage!("pt_bricks.wgsl"),
    stage!("rpnn_descriptor.wgsl"),
    stage!("rpnn_mlp.wgsl"),
    stage!("rpnn_sample.wgsl"),
    stage!("rpnn_sample_bricks.wgsl"),
    stage!("blit.wgsl"),
];

/// Source of an importable module: a file of `shaders/lib/` or the generated `constants`.
pub fn module(name: &str) -> Option<Cow<'static, str>> {
    if name == "constants" {
        return Some(crate::consts::wgsl_module().into());
    }
    MODULES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, s)| Cow::Borrowed(*s))
}

/// A stage (`pt.wgsl`) or a module (`grid`) with its imports resolved; `None` if no such file
/// is registered.
pub fn composed(name: &str) -> Option<Result<Composed, compose::ComposeError>> {
    let body = SHADERS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, s)| Cow::Borrowed(*s))
        .or_else(|| module(name))?;
    Some(compose::compose(name, &body, &module))
}

/// The composed WGSL of a registered stage.
///
/// # Panics
/// On a name that is not registered or a source whose imports do not resolve: both are
/// mistakes in this crate, which `every_shader_file_is_registered_and_valid` rules out.
pub fn source(name: &str) -> String {
    match composed(name) {
        Some(Ok(c)) => c.source,
        Some(Err(e)) => panic!("{e}"),
        None => panic!("unknown shader {name}"),
    }
}

/// Layout of a WGSL struct as naga computes it: (member name, byte offset) in declaration
/// order, and the struct's size. `shader` is a stage or a module name. Layout tests compare it
/// with the `#[repr(C)]` Rust twin.
pub fn struct_layout(shader: &str, name: &str) -> (Vec<(String, u32)>, u32) {
    let module = match composed(shader) {
        Some(Ok(c)) => c.parse().unwrap_or_else(|e| panic!("{e}")),
        Some(Err(e)) => panic!("{e}"),
        None => panic!("unknown shader {shader}"),
    };
    let ty = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("{shader}: no struct {name}"))
        .1;
    let naga::TypeInner::Struct { members, span } = &ty.inner else {
        panic!("{shader}: {name} is not a struct")
    };
    let m = members
        .iter()
        .map(|m| (m.name.clone().unwrap_or_default(), m.offset))
        .collect();
    (m, *span)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wgsl_files(dir: &std::path::Path) -> Vec<String> {
        let mut files: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".wgsl"))
            .collect();
        files.sort();
        files
    }

    /// Every file is registered, every stage composes, parses and validates; every module is
    /// imported by some stage.
    #[test]
    fn every_shader_file_is_registered_and_valid() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shaders");
        let mut stages: Vec<String> = SHADERS.iter().map(|(n, _)| n.to_string()).collect();
        stages.sort();
        assert_eq!(
            wgsl_files(&dir),
            stages,
            "every shaders/*.wgsl must be in SHADERS"
        );
        let mut modules: Vec<String> = MODULES.iter().map(|(n, _)| format!("{n}.wgsl")).collect();
        modules.sort();
        assert_eq!(
            wgsl_files(&dir.join("lib")),
            modules,
            "every shaders/lib/*.wgsl must be in MODULES"
        );
        let mut used = std::collections::BTreeSet::new();
        for (name, _) in SHADERS {
            let c = composed(name).unwrap().unwrap_or_else(|e| panic!("{e}"));
            c.validate().unwrap_or_else(|e| panic!("{e}"));
            used.extend(c.segments.iter().map(|s| s.file.clone()));
        }
        for (m, _) in MODULES {
            assert!(used.contains(*m), "module {m} is imported by no stage");
        }
    }

    /// One HG, one RNG, one frame construction in WGSL: each defined only in its module.
    #[test]
    fn one_hg_and_one_rng_implementation() {
        for (name, src) in SHADERS.iter().chain(MODULES) {
            let owner = |f: &str| src.contains(&format!("fn {f}("));
            for (f, home) in [
                ("hg_eval", "hg"),
                ("hg_sample_cos", "hg"),
                ("rand", "rng"),
                ("pcg_hash", "rng"),
                ("around", "math"),
            ] {
                assert!(
                    !owner(f) || *name == home,
                    "{name} defines {f}; it belongs in lib/{home}.wgsl"
                );
            }
        }
    }
}
