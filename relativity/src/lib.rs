//! # blueshift-relativity
//!
//! What a fast observer sees: special-relativistic aberration, Doppler shift and the
//! searchlight effect, rendered from HDR environment maps. It implements the method of the
//! relativistic-visualization paper (`shared/papers/relativistic-visualization.txt`) and goes
//! beyond it in the three places its authors leave open: motion in any direction (not only
//! along z), a spectral colour shift (not a simplified RGB model) and the searchlight effect.
//!
//! ## Where do I start?
//! - [`Velocity`]: `beta`, `gamma`, rapidity, velocity addition, the Lorentz boost
//!   ([`LorentzMatrix`]), aberration ([`Velocity::observer_to_scene`],
//!   [`Velocity::scene_to_observer`]) and the Doppler factor
//!   ([`Velocity::doppler_factor_observer`]).
//! - [`Environment`]: an equirectangular map, a cube map or the procedural [`Checker`];
//!   [`Environment::load`] reads EXR, Radiance `.hdr` and PNG.
//! - [`DopplerColourTable`]: RGB colour shift by a Doppler factor through spectra (Mallett &
//!   Yuksel 2019 spectral primary decomposition), precomputed as 3x3 matrices over `D`.
//! - [`render`] with a [`Camera`] and [`Effects`]; [`ramp`] for a velocity ramp.
//!
//! ```
//! use blueshift_relativity::*;
//! use glam::DVec3;
//! let v = Velocity::along(DVec3::Z, 0.9)?;
//! let cam = Camera { look: DVec3::Z, width: 64, height: 48, ..Camera::default() };
//! let img = render(&Environment::Checker(Checker::default()), &cam, v, Effects::ALL, None)?;
//! assert_eq!(img.dimensions(), (64, 48));
//! # Ok::<(), blueshift_relativity::Error>(())
//! ```
//!
//! ## Glossary: paper terms to types
//! | relativistic-visualization paper | blueshift |
//! |---|---|
//! | Eq. 1 Lorentz transformation (gamma typo corrected) | [`LorentzMatrix::boost`], [`Velocity::gamma`] |
//! | Eq. 2 aberration of light, along z | [`Velocity::observer_to_scene`] (any direction), [`Velocity::scene_to_observer`] |
//! | Eq. 3 Doppler shift `nu' = nu gamma (1 - R_d . beta)` | [`Velocity::doppler_factor_scene`], [`Velocity::doppler_factor_observer`] |
//! | "radiance fluctuation" / searchlight (future work) | [`searchlight_integrated`], [`searchlight_per_wavelength`], [`searchlight_per_frequency`] |
//! | Backlight RGB colour model | replaced by [`DopplerColourTable`] (spectral) |
//! | cube map on the observer's sphere | [`CubeMap`], [`EquirectMap`], [`Environment`] |
//! | the rendering algorithm | [`render`], [`ramp`] |
//!
//! ## Conventions
//! `c = 1`. The scene frame is the environment's rest frame; the observer moves with
//! `beta` in it. Directions are unit **viewing directions** (towards what is seen).
//! `D = nu_obs / nu_emit` (> 1 blue shift), the spectrum crate's [`DopplerFactor`].
//! Environment maps are linear RGB (Rec. 709 / sRGB primaries); PNG input is sRGB-decoded.
//!
//! [`DopplerFactor`]: blueshift_spectrum::DopplerFactor

mod colour;
mod envmap;
mod error;
mod fast;
mod lorentz;
mod observer;
mod render;
mod session;

pub use colour::{
    DopplerColourTable, LINEAR_D_ENTRIES, LINEAR_D_MAX_ERROR, Mat3, SpectralPrimaries, TABLE_D_MAX,
    TABLE_D_MIN,
};
pub use envmap::{
    Checker, CubeMap, Environment, EquirectMap, FACE_NAMES, MAX_MAP_BYTES, MAX_MAP_SIDE, MapLayout,
    Rgb, check_size, cube_dir, cube_face_st, from_lon_polar, lon_polar, read_linear,
};
pub use error::{Error, Result};
pub use fast::{ATAN2_MAX_ERROR_RAD, atan2 as fast_atan2};
pub use lorentz::{
    Event, LorentzMatrix, Velocity, searchlight_integrated, searchlight_per_frequency,
    searchlight_per_wavelength, unit,
};
pub use observer::MovingObserver;
pub use render::{
    Camera, CameraFrame, Effects, out_of_map_fraction, parse_ramp, ramp, render, scene_direction,
    to_srgb8,
};
pub use session::RelativitySession;
