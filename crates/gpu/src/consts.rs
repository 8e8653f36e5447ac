//! Constants that Rust and WGSL must agree on, defined once here. The shaders get them from
//! the generated module `constants` (`#import constants`, text from [`wgsl_module`]); the Rust
//! side uses these items (re-exported by the crates that own the meaning: the photon cache
//! layout in `nimbus-photon`, the RPNN stencil in `nimbus-rpnn`).

/// Threads per workgroup of the one-dimensional compute stages (`@workgroup_size(WG)`);
/// [`crate::Gpu::workgroups_1d`] dispatches in these units and the shaders index
/// `gid.x + gid.y * num_workgroups.x * WG`.
pub const WG: u32 = 64;

/// Photon cache (Elek 2012 §4.1, Appendix B): fixed-point scale of one unit of beam weight in
/// the u32 cache words.
pub const W_SCALE: f64 = 4096.0;
/// Photon cache: u32 words per cell (energy, flux vector, two-lobe sums, in-scattering towards
/// the camera; see `nimbus_photon::cpu`).
pub const CELL_WORDS: u32 = 13;

/// RPNN stencil (Kallweit 2017 §4.2): points per level, 5 × 5 × 9.
pub const STENCIL_POINTS: u32 = 225;
/// RPNN stencil: hierarchy levels.
pub const STENCIL_LEVELS: u32 = 10;
/// RPNN descriptor length: every level's points, then γ.
pub const DESCRIPTOR_LEN: u32 = STENCIL_LEVELS * STENCIL_POINTS + 1;

/// RPNN network layers (`shaders/rpnn_mlp.wgsl`): queries per workgroup, so a layer dispatches
/// ⌈rows / this⌉ workgroups along y (both kernels).
pub const MLP_TILE_ROWS: u32 = 64;
/// RPNN network layers: outputs per workgroup, so a layer dispatches ⌈outputs / this⌉ along x.
pub const MLP_TILE_OUTPUTS: u32 = 64;
/// RPNN network layers, the wide kernel (`dense_wide`: 16 × 8 threads, each 8 queries × 8
/// outputs): outputs per workgroup; its workgroups hold [`MLP_TILE_ROWS`] queries too.
pub const MLP_WIDE_TILE_OUTPUTS: u32 = 128;

/// One WGSL constant: name and value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Const {
    U32(&'static str, u32),
    F32(&'static str, f64),
}

/// Every constant of the `constants` module.
pub const ALL: &[Const] = &[
    Const::U32("WG", WG),
    Const::F32("W_SCALE", W_SCALE),
    Const::U32("CELL_WORDS", CELL_WORDS),
    Const::U32("STENCIL_POINTS", STENCIL_POINTS),
    Const::U32("DESCRIPTOR_LEN", DESCRIPTOR_LEN),
    Const::U32("MLP_TILE_ROWS", MLP_TILE_ROWS),
    Const::U32("MLP_TILE_OUTPUTS", MLP_TILE_OUTPUTS),
    Const::U32("MLP_WIDE_TILE_OUTPUTS", MLP_WIDE_TILE_OUTPUTS),
];

/// WGSL source of the `constants` module, one `const` per entry of [`ALL`].
pub fn wgsl_module() -> String {
    let mut s = String::from(
        "// Generated from crates/gpu/src/consts.rs (one source for Rust and WGSL).\n",
    );
    for c in ALL {
        match *c {
            Const::U32(n, v) => s.push_str(&format!("const {n}: u32 = {v}u;\n")),
            // `{:?}` keeps a decimal point (4096.0), so the literal is an f32, not an integer.
            Const::F32(n, v) => s.push_str(&format!("const {n}: f32 = {v:?};\n")),
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The generated module is valid WGSL whose constants evaluate to the Rust values.
    #[test]
    fn generated_module_carries_the_rust_values() {
        let src = wgsl_module();
        let module = naga::front::wgsl::parse_str(&src).unwrap();
        for c in ALL {
            let (name, want) = match *c {
                Const::U32(n, v) => (n, naga::Literal::U32(v)),
                Const::F32(n, v) => (n, naga::Literal::F32(v as f32)),
            };
            let (_, k) = module
                .constants
                .iter()
                .find(|(_, k)| k.name.as_deref() == Some(name))
                .unwrap_or_else(|| panic!("no constant {name} in\n{src}"));
            match module.global_expressions[k.init] {
                naga::Expression::Literal(l) => assert_eq!(l, want, "{name}"),
                ref e => panic!("{name}: {e:?}"),
            }
        }
        assert_eq!(DESCRIPTOR_LEN, 2251);
    }
}
