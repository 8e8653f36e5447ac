//! The photon cache's memory layout shared by Rust and WGSL: the fixed-point scale of beam
//! weights, the words per cell, and the workgroup-shared capacity of the trace shader (Elek 2012
//! §4.1 and Appendix B: caches accumulate in workgroup memory when they fit).

use nimbus_gpu::shaders;

/// Fixed-point scale of one unit of beam weight in the caches (`W_SCALE` in the shader).
pub const W_SCALE: f64 = 4096.0;
/// Workgroup-shared cache capacity (cells) declared by the shader: 256 cells × 44 bytes fit the
/// 16 KiB every WebGPU adapter offers; [`shared_cells`] patches in what the adapter allows.
pub const SHARED_CELLS: u32 = 256;
/// The most cells ever accumulated in workgroup memory (the paper's 2 400-cell budget).
const SHARED_CELLS_MAX: u32 = 2400;
pub use crate::reference::CELL_WORDS;
/// Bytes per cache cell (11 u32).
pub const CELL_BYTES: u32 = CELL_WORDS as u32 * 4;

/// Cells that fit the adapter's workgroup storage (at most 2 400); caches with more cells use
/// global atomics.
pub fn shared_cells(max_workgroup_storage: u32) -> u32 {
    (max_workgroup_storage / CELL_BYTES).min(SHARED_CELLS_MAX)
}

/// `shaders/photon_trace.wgsl` with its workgroup-shared cell count set to `shared_cap`: the
/// shader declares `const SHARED_CELLS: u32 = 256u;` ([`SHARED_CELLS`]), and the mapper patches
/// in the cache's own cell count when it fits the adapter's workgroup storage (one cell when
/// the cache uses global atomics, so no workgroup memory is reserved for nothing). A source that no longer carries
/// that exact declaration is an error, not a silently unpatched shader (both variants are
/// validated by naga in the tests).
pub fn trace_source(shared_cap: u32) -> Result<String, String> {
    let src = shaders::source("photon_trace.wgsl");
    let decl = format!("const SHARED_CELLS: u32 = {SHARED_CELLS}u;");
    if src.matches(&decl).count() != 1 {
        return Err(format!(
            "shaders/photon_trace.wgsl must declare `{decl}` exactly once (it is patched for large workgroup storage)"
        ));
    }
    Ok(src.replace(&decl, &format!("const SHARED_CELLS: u32 = {shared_cap}u;")))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both workgroup-shared variants of the trace shader parse and validate, and the patch
    /// really changes the constant.
    #[test]
    fn patched_trace_shader_is_valid() {
        for cap in [1, SHARED_CELLS, SHARED_CELLS_MAX] {
            let src = trace_source(cap).unwrap();
            assert!(src.contains(&format!("const SHARED_CELLS: u32 = {cap}u;")));
            let module = naga::front::wgsl::parse_str(&src)
                .unwrap_or_else(|e| panic!("cap {cap}: {}", e.emit_to_string(&src)));
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            )
            .validate(&module)
            .unwrap_or_else(|e| panic!("cap {cap}: {e:?}"));
        }
    }

    /// The cell layout constant is the same in Rust and in both shaders that read the cache.
    #[test]
    fn cell_words_match_the_shaders() {
        for file in ["photon_trace.wgsl", "photon_upsample.wgsl"] {
            let src = shaders::source(file);
            assert!(
                src.contains(&format!("const CELL_WORDS: u32 = {CELL_WORDS}u;")),
                "{file} must declare CELL_WORDS = {CELL_WORDS}"
            );
        }
    }

    /// Shared-memory capacity: 16 KiB (WebGPU's minimum) holds 372 cells of 44 bytes, 32 KiB
    /// 744, 48 KiB 1 117; never more than the paper's 2 400.
    #[test]
    fn shared_capacity_follows_the_adapter() {
        assert_eq!(shared_cells(16384), 372);
        assert_eq!(shared_cells(32768), 744);
        assert_eq!(shared_cells(49152), 1117);
        assert_eq!(shared_cells(1 << 20), 2400);
        assert!(SHARED_CELLS <= shared_cells(16384));
    }
}
