//! # nimbus-photon
//!
//! GPU temporally-coherent photon mapping for clouds (Elek et al. 2012): photon beams traced with
//! Woodcock tracking deposit into a coarse grid (§4.1), a ring of m partial caches amortises the
//! illumination over frames (§3.2, §4.2), a Henyey–Greenstein lobe per cell stores the angular
//! distribution (§4.1.2, Appendix C), a physically based filter upsamples the cache to the density
//! resolution (§4.3), and ray marching makes the image (§4.4).
//!
//! Every GPU stage has a CPU twin of the same name in [`cpu`] that the tests compare against.

pub mod animate;
pub mod cache_layout;
pub mod impostor;
pub mod light_map;
pub mod mapper;

pub mod cpu;
pub mod settings;

pub use mapper::{
    GatherSettings, LobeAxis, PhotonMapper, PmError, PmSettings, PmVariant, SunShadow, Terminal,
};
pub use nimbus_gpu::params::VolumeParams;
