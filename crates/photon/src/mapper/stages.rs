//! The photon map's compute stages as data (Elek 2012 §4): each entry names its shader, entry
//! point, the buffer behind every binding and its CPU twin. `PhotonMapper::new` builds each
//! pipeline and bind group from its entry, so wiring a stage is one table row, and a unit test
//! checks every row's bindings against what naga finds the entry point uses (a binding the
//! shader reads but the row forgets, or one it no longer has, fails without a GPU).
//!
//! The image stages (the ray march, the final gathering) are bound when the image size is known
//! (`raymarch.rs`, `gather.rs`).

use super::plan::Buf;

/// What a binding holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Binding {
    /// The uniform block (`VolumeParams`).
    Params,
    /// The ring slot being replaced (the update's uniform).
    Slot,
    /// A planned buffer.
    Buf(Buf),
}

/// One compute stage.
#[derive(Debug, Clone, Copy)]
pub struct StageSpec {
    pub label: &'static str,
    /// The WGSL file in `shaders/`.
    pub shader: &'static str,
    pub entry: &'static str,
    /// Specialised by the light volumes' layout (`override LIGHT_SPARSE`).
    pub sparse: bool,
    pub bindings: &'static [(u32, Binding)],
    /// The CPU reference of the stage (`crate::cpu`), tested against it.
    pub cpu_twin: &'static str,
}

/// Which stage of [`STAGES`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StageId {
    Sun,
    Trace,
    Update,
    Cells,
    Upsample,
}

use Binding::{Buf as B, Params, Slot};

/// The per-frame and per-image stages, in the order a frame runs them.
pub const STAGES: [(StageId, StageSpec); 5] = [
    (
        StageId::Sun,
        StageSpec {
            label: "sun transmittance",
            shader: "photon_sun.wgsl",
            entry: "sun_transmittance",
            sparse: true,
            bindings: &[
                (0, Params),
                (1, B(Buf::Density)),
                (2, B(Buf::SunT)),
                (3, B(Buf::LightIndex)),
            ],
            cpu_twin: "cpu::sun_transmittance",
        },
    ),
    (
        StageId::Trace,
        StageSpec {
            label: "photon trace",
            shader: "photon_trace.wgsl",
            entry: "trace",
            sparse: true,
            bindings: &[
                (0, Params),
                (1, B(Buf::Density)),
                (2, B(Buf::HNew)),
                (3, B(Buf::Overflow)),
                (4, B(Buf::CellSkip)),
                (5, B(Buf::LightIndex)),
            ],
            cpu_twin: "cpu::trace",
        },
    ),
    (
        StageId::Update,
        StageSpec {
            label: "photon update",
            shader: "photon_update.wgsl",
            entry: "update",
            sparse: false,
            bindings: &[
                (2, B(Buf::HNew)),
                (3, B(Buf::Ring)),
                (4, B(Buf::Total)),
                (5, Slot),
                (6, B(Buf::Overflow)),
            ],
            cpu_twin: "cpu::update",
        },
    ),
    (
        StageId::Cells,
        StageSpec {
            label: "photon cache cells",
            shader: "photon_upsample.wgsl",
            entry: "cells",
            sparse: true,
            bindings: &[
                (0, Params),
                (1, B(Buf::Density)),
                (2, B(Buf::Total)),
                (4, B(Buf::CellVals)),
                (5, B(Buf::CellAux)),
                (6, B(Buf::CellDir)),
                (9, B(Buf::LightIndex)),
            ],
            cpu_twin: "cpu::cells",
        },
    ),
    (
        StageId::Upsample,
        StageSpec {
            label: "photon upsample",
            shader: "photon_upsample.wgsl",
            entry: "upsample",
            sparse: true,
            bindings: &[
                (0, Params),
                (1, B(Buf::Density)),
                (3, B(Buf::J)),
                (4, B(Buf::CellVals)),
                (5, B(Buf::CellAux)),
                (6, B(Buf::CellDir)),
                (7, B(Buf::JDir)),
                (8, B(Buf::JHigh)),
                (9, B(Buf::LightIndex)),
            ],
            cpu_twin: "cpu::upsample",
        },
    ),
];

/// The table's entry for `id`.
pub fn spec(id: StageId) -> &'static StageSpec {
    &STAGES
        .iter()
        .find(|(s, _)| *s == id)
        .expect("every StageId has a row")
        .1
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each row binds exactly the bindings its entry point uses (naga's analysis of the
    /// composed shader), each once; every stage has a row; its CPU twin exists by that name in
    /// `crate::cpu` (checked by a reference in code below, so a rename fails to compile).
    #[test]
    fn every_row_binds_what_its_entry_point_uses() {
        for (id, s) in &STAGES {
            let composed = nimbus_gpu::shaders::composed(s.shader)
                .unwrap_or_else(|| panic!("{}: no such shader", s.shader))
                .unwrap();
            let module = composed.validate().unwrap();
            let mut v = naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            );
            let info = v.validate(&module).unwrap();
            let (ep_index, _) = module
                .entry_points
                .iter()
                .enumerate()
                .find(|(_, e)| e.name == s.entry)
                .unwrap_or_else(|| panic!("{}: no entry point {}", s.shader, s.entry));
            let ep = info.get_entry_point(ep_index);
            let mut used: Vec<u32> = module
                .global_variables
                .iter()
                .filter(|(h, g)| g.binding.is_some() && !ep[*h].is_empty())
                .map(|(_, g)| g.binding.as_ref().unwrap().binding)
                .collect();
            used.sort_unstable();
            let mut bound: Vec<u32> = s.bindings.iter().map(|(b, _)| *b).collect();
            bound.sort_unstable();
            assert_eq!(bound, used, "{id:?} ({} {})", s.shader, s.entry);
            let has_sparse = module
                .overrides
                .iter()
                .any(|(_, o)| o.name.as_deref() == Some("LIGHT_SPARSE"));
            assert!(!s.sparse || has_sparse, "{id:?}: no LIGHT_SPARSE override");
            // `PhotonMapper::new` resolves every other buffer.
            for (_, b) in s.bindings {
                assert!(
                    ![B(Buf::March), B(Buf::SunTBack), B(Buf::Image)].contains(b),
                    "{id:?} binds {b:?}"
                );
            }
        }
        for id in [
            StageId::Sun,
            StageId::Trace,
            StageId::Update,
            StageId::Cells,
            StageId::Upsample,
        ] {
            assert_eq!(STAGES.iter().filter(|(s, _)| *s == id).count(), 1);
        }
        // The twins named in the table.
        let _ = (
            crate::cpu::sun_transmittance,
            crate::cpu::trace,
            crate::cpu::update,
            crate::cpu::cells,
            crate::cpu::upsample,
        );
        let names: Vec<_> = STAGES.iter().map(|(_, s)| s.cpu_twin).collect();
        assert_eq!(
            names,
            [
                "cpu::sun_transmittance",
                "cpu::trace",
                "cpu::update",
                "cpu::cells",
                "cpu::upsample"
            ]
        );
    }
}
