//! # nimbus-scene
//!
//! Everything a Nimbus estimator reads: density volumes, the medium (albedo, phase function),
//! lights, camera, render settings, scene files, procedural clouds, and image I/O.
//!
//! ## Conventions (shared by every estimator; identical to the Mitsuba 3 references)
//! - **World**: right-handed, y up; σ_t is per world unit.
//! - **Grid**: values at cell centres, x fastest, then y, then z (`data[(z*ny + y)*nx + x]`).
//!   A world point p maps to the continuous index u = (p − aabb_min)/(aabb_max − aabb_min) × res
//!   − 0.5; trilinear interpolation with indices clamped to the edge. The medium exists only
//!   inside the AABB (σ_t = 0 outside); σ_t(p) = density_scale × lookup(p). See [`volume`].
//!   Storage is dense or sparse (8³ bricks, [`brick`]: `.vdb`/`.nvdb` files are never
//!   densified); both read the same values through [`DensityGrid::get`].
//! - **Medium**: σ_s = albedo × σ_t, no emission; phase functions use the propagation convention
//!   (cos θ between travel directions before and after scattering; g > 0 forward). See [`phase`].
//! - **Sun**: `direction` points towards the sun; `irradiance` is measured perpendicular to it.
//!   **Sky**: radiance arriving from each direction. See [`light`].
//! - **Camera**: pinhole look-at, full vertical FOV, pixel (0,0) top-left, box pixel filter. See
//!   [`camera`].
//! - **Images**: linear radiance RGB, row 0 at the top. See [`image`].

pub mod atmosphere;
pub mod brick;
pub mod build;
pub mod camera;
pub mod cancel;
pub mod clock;
pub mod compare;
pub mod contain;
pub mod downsample;
pub mod error;
pub mod frame;
pub mod fsio;
pub mod generate;
pub mod grid;
pub mod image;
pub mod io;
pub mod light;
pub mod medium;
pub mod memory;
pub mod phase;
pub mod scene;
pub mod scene_paths;
pub mod tau;
pub mod volume;

pub use camera::Camera;
pub use cancel::{Cancel, Cancelled};
pub use error::{Error, FieldError, Result};
pub use generate::CloudKind;
pub use grid::DensityGrid;
pub use image::Image;
pub use light::{EnvMap, Sky, Sun};
pub use medium::Medium;
pub use phase::Phase;
pub use scene::{AtmosphereTop, RenderSettings, Scene, VolumeSource};
pub use volume::{Aabb, MajorantGrid, Volume};
