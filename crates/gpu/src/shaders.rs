//! Registry of every WGSL file in `shaders/`. Shaders are plain WGSL; the ones that share code
//! are prefixed with `common.wgsl` (random numbers, grid lookups, phase functions) by
//! [`source`]. A unit test parses and validates each with naga.

/// Shared helpers, prepended to the other shaders.
pub const COMMON: &str = include_str!("../../../shaders/common.wgsl");

/// (file name, source, whether `common.wgsl` is prepended) of every shader except
/// `common.wgsl` itself.
pub const SHADERS: &[(&str, &str, bool)] = &[
    (
        "photon_trace.wgsl",
        include_str!("../../../shaders/photon_trace.wgsl"),
        true,
    ),
    (
        "photon_update.wgsl",
        include_str!("../../../shaders/photon_update.wgsl"),
        true,
    ),
    (
        "photon_upsample.wgsl",
        include_str!("../../../shaders/photon_upsample.wgsl"),
        true,
    ),
    (
        "photon_raymarch.wgsl",
        include_str!("../../../shaders/photon_raymarch.wgsl"),
        true,
    ),
    (
        "photon_sun.wgsl",
        include_str!("../../../shaders/photon_sun.wgsl"),
        true,
    ),
    ("pt.wgsl", include_str!("../../../shaders/pt.wgsl"), true),
    (
        "rpnn_descriptor.wgsl",
        include_str!("../../../shaders/rpnn_descriptor.wgsl"),
        false,
    ),
    (
        "blit.wgsl",
        include_str!("../../../shaders/blit.wgsl"),
        false,
    ),
    (
        "rpnn_mlp.wgsl",
        include_str!("../../../shaders/rpnn_mlp.wgsl"),
        false,
    ),
];

/// Full source of a shader: `common.wgsl` (for the photon-mapping shaders) followed by the
/// file.
pub fn source(name: &str) -> String {
    let (_, body, common) = SHADERS
        .iter()
        .find(|(n, _, _)| *n == name)
        .unwrap_or_else(|| panic!("unknown shader {name}"));
    if *common {
        format!("{COMMON}\n{body}")
    } else {
        body.to_string()
    }
}

/// Layout of a WGSL struct as naga computes it: (member name, byte offset) in declaration
/// order, and the struct's size. Layout tests compare it with the `#[repr(C)]` Rust twin.
pub fn struct_layout(shader: &str, name: &str) -> (Vec<(String, u32)>, u32) {
    let src = source(shader);
    let module = naga::front::wgsl::parse_str(&src)
        .unwrap_or_else(|e| panic!("{shader}: {}", e.emit_to_string(&src)));
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

    #[test]
    fn every_shader_file_is_registered_and_valid() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shaders");
        let mut files: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".wgsl") && n != "common.wgsl")
            .collect();
        files.sort();
        let mut registered: Vec<String> = SHADERS.iter().map(|(n, _, _)| n.to_string()).collect();
        registered.sort();
        assert_eq!(files, registered, "every shaders/*.wgsl must be in SHADERS");
        for (name, _, _) in SHADERS {
            let src = source(name);
            let module = naga::front::wgsl::parse_str(&src)
                .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&src)));
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            )
            .validate(&module)
            .unwrap_or_else(|e| panic!("{name}: {e:?}"));
        }
    }
}
