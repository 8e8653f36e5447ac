//! The photon cache's memory layout shared by Rust and WGSL: the fixed-point scale of beam
//! weights, the words per cell, and the workgroup-shared capacity of the trace shader (Elek 2012
//! §4.1 and Appendix B: caches accumulate in workgroup memory when they fit).

use nimbus_gpu::{consts, shaders};

/// Fixed-point scale of one unit of beam weight in the caches (`W_SCALE` in the shaders; one
/// definition for both in `nimbus_gpu::consts`).
pub const W_SCALE: f64 = consts::W_SCALE;
/// Default of the trace shader's `override SHARED_CELLS` (cells in workgroup memory): 256 cells
/// × 52 bytes fit the 16 KiB every WebGPU adapter offers; [`trace_constants`] sets what the
/// cache needs and the adapter allows.
pub const SHARED_CELLS: u32 = 256;
/// The most cells ever accumulated in workgroup memory (the paper's 2 400-cell budget).
pub const SHARED_CELLS_MAX: u32 = 2400;
/// u32 words per cache cell (`CELL_WORDS` in the shaders, from `nimbus_gpu::consts`).
pub const CELL_WORDS: usize = consts::CELL_WORDS as usize;
/// Most cache cells: the ring update runs one thread per cache word, in one dimension of at
/// most 65 535 workgroups of 64 (WebGPU's dispatch limit).
pub const MAX_CACHE_CELLS: u64 = 65_535 * 64 / consts::CELL_WORDS as u64;
/// Bytes per cache cell (13 u32).
pub const CELL_BYTES: u32 = consts::CELL_WORDS * 4;

/// Cells that fit the adapter's workgroup storage (at most 2 400); caches with more cells use
/// global atomics.
pub fn shared_cells(max_workgroup_storage: u32) -> u32 {
    (max_workgroup_storage / CELL_BYTES).min(SHARED_CELLS_MAX)
}

/// Pipeline constants of `shaders/photon_trace.wgsl`: its workgroup-shared cell count (WGSL
/// `override SHARED_CELLS`, which sizes the workgroup array). The mapper passes the cache's own
/// cell count when it fits the adapter's workgroup storage, and one cell when the cache uses
/// global atomics (no workgroup memory reserved for nothing). Every count the mapper can pass
/// (1 ..= [`SHARED_CELLS_MAX`]) is the same module with another array length; the tests
/// validate the extremes with naga's override processing.
pub fn trace_constants(shared_cap: u32) -> [(&'static str, f64); 1] {
    [(
        "SHARED_CELLS",
        f64::from(shared_cap.clamp(1, SHARED_CELLS_MAX)),
    )]
}

/// The trace shader (composed WGSL, specialised only through [`trace_constants`]).
pub fn trace_source() -> String {
    shaders::source("photon_trace.wgsl")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The override exists, and every shared capacity the mapper can set gives a valid
    /// module once naga substitutes it (what wgpu does when the pipeline is created).
    #[test]
    fn every_trace_specialisation_is_valid() {
        let composed = shaders::composed("photon_trace.wgsl").unwrap().unwrap();
        let module = composed.validate().unwrap();
        let decl = module
            .overrides
            .iter()
            .find(|(_, o)| o.name.as_deref() == Some("SHARED_CELLS"));
        assert!(
            decl.is_some(),
            "photon_trace.wgsl must declare override SHARED_CELLS"
        );
        for cap in [0, 1, SHARED_CELLS, SHARED_CELLS_MAX, u32::MAX] {
            let mut consts = naga::back::PipelineConstants::default();
            for (k, v) in trace_constants(cap) {
                consts.insert(k.to_string(), v);
            }
            let mut v = naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            );
            let info = v.validate(&module).unwrap();
            let (m, _) =
                naga::back::pipeline_constants::process_overrides(&module, &info, None, &consts)
                    .unwrap_or_else(|e| panic!("cap {cap}: {e:?}"));
            // The workgroup array really has SHARED_CELLS × CELL_WORDS entries.
            let want = cap.clamp(1, SHARED_CELLS_MAX) * consts::CELL_WORDS;
            let sh = m
                .global_variables
                .iter()
                .find(|(_, g)| g.name.as_deref() == Some("sh"))
                .unwrap()
                .1;
            let naga::TypeInner::Array { size, .. } = m.types[sh.ty].inner else {
                panic!("cap {cap}: sh is not an array")
            };
            let len = size
                .resolve(m.to_ctx())
                .unwrap_or_else(|e| panic!("cap {cap}: {e:?}"));
            assert!(
                matches!(len, naga::proc::IndexableLength::Known(n) if n == want),
                "cap {cap}: {len:?}, want {want}"
            );
        }
    }

    /// Shared-memory capacity: 16 KiB (WebGPU's minimum) holds 315 cells of 52 bytes, 32 KiB
    /// 630, 48 KiB 945; never more than the paper's 2 400.
    #[test]
    fn shared_capacity_follows_the_adapter() {
        assert_eq!(shared_cells(16384), 315);
        assert_eq!(shared_cells(32768), 630);
        assert_eq!(shared_cells(49152), 945);
        assert_eq!(shared_cells(1 << 20), 2400);
        assert!(SHARED_CELLS <= shared_cells(16384));
    }
}
