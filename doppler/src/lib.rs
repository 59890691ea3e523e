//! # blueshift-doppler: Doppler volume rendering
//!
//! The Doppler paper (`shared/papers/doppler-volume-rendering.txt`):
//! the emission-absorption model of Eq. 8 over species, moved by a velocity field, integrated
//! with the banded baseline (Algorithm 1) or the piecewise-linear integrator (Algorithm 2).
//!
//! ## Where do I start?
//! - Build a [`DopplerScene`] with [`DopplerScene::from_volume`] (synthetic galaxy or shell:
//!   species tokens `bb`, `H`, `He`, `C`) or by hand with [`Species`] and
//!   [`DopplerScene::set_blackbody`] / [`DopplerScene::set_velocity`].
//! - Or load a scene file ([`SceneFile::read`] then [`SceneFile::load`]): JSON mapping volume
//!   files to species, temperature and velocity with units (format in [`SceneFile`]'s module
//!   docs; `scenes/enzo-moving7.json` is a worked example on real Enzo data).
//! - Pick [`DopplerSettings`] ([`DopplerSettings::default_for`] is the orthographic +z view
//!   framing the volume's x-y extent) and a [`SpectralIntegrator`].
//! - [`render_doppler`] gives an XYZ [`DopplerImage`]; [`pixel_spectrum`] and [`trace_ray`]
//!   give one pixel's final spectrum and its step-by-step accumulation;
//!   [`DisplayOptions::to_rgb8`] maps XYZ to a display image.
//! - Spectral cubes for astronomers: [`render_cube`] with a [`CubeSpec`] (velocity or
//!   wavelength channels around a line), [`los_camera`] for a view along any direction,
//!   [`SpectralCube::moments`], [`fits_bytes`] / [`nrrd_bytes`]; line profiles beyond the
//!   box (thermal, Gaussian) through [`DopplerSettings::broadening`] ([`Broadening`]).
//!
//! ## The model
//! Along a ray (marched back to front, in the light's direction, with step `step`), species
//! `m` with number density `rho_m` emits its lines (strength `S` x emission factor) and absorbs
//! with its lines (strength x absorption factor, as optical depth per unit density and
//! length); the black body adds `rho_bb * B(lambda, T) * BB_UNIT * blackbody factor`.
//! Everything is seen through the wavelength shift `s` of the local velocity (x velocity
//! factor) along the line of sight: observed `I(lambda) = k(s) E(lambda / s)` with
//! `k = 1 / s` (energy-conserving: a line keeps its area) or, with
//! [`DopplerSettings::invariant`], `k = s^-5` (`I_nu / nu^3` invariant: a black body at `T`
//! becomes exactly the black body at `T / s`).
//!
//! Within a segment the piecewise-linear integrator takes density and shift as linear in
//! the path length: a (delta) line then emits exactly the trapezoid between its two shifted
//! positions with heights proportional to the end densities and its AREA equal to the emitted
//! energy (Fig. 9; the paper keeps heights fixed as the band widens, which creates energy).
//! Lines are given a minimum width `line_width_nm` (the paper's `delta lambda`). Black
//! bodies are sampled on a fixed wavelength grid (`blackbody_samples` points) at both ends
//! of the segment (trapezoid rule along the ray).
//!
//! ## Absorption: two paths, one convention
//! Light emitted inside a segment crosses half of that segment's optical depth (the light
//! from behind crosses all of it): for a constant medium this is within `(k dt)^2 / 24` of
//! Beer-Lambert's `(e / k) (1 - exp(-k L))`. The banded integrator applies the same rule per
//! sample (half its depth before its emission, half after), so the integrators compare fairly.
//! - Image (XYZ) path, front to back: only the optical depth in front (plus half of the
//!   current segment's), `P(lambda)`, is kept (a flat sorted array of linear pieces, non-zero
//!   only inside the shifted absorption lines). Each segment's emission adds its closed-form
//!   XYZ minus what `P` takes from it: for the black body, one dot product of its grid
//!   coefficients with per-grid-point absorbed fractions `W_i = integral hat_i cmf (1 -
//!   exp(-P))`, kept for the depth in front and updated only inside the segment's own line
//!   windows, which each segment sweeps once; for its lines, the exact integral over their
//!   windows. Each sub-interval integral is exact (the CMFs, hats and lines linear, `exp(-P)`
//!   an exponential of the wavelength), so the cost per segment follows its lines, not the
//!   whole of `P` (module `front`). `merge_tolerance` `tol` is an error budget for the whole
//!   ray: the depth in front is merged (the k-th merge gets `tol/32 6 / (pi k)^2`), the
//!   weakest absorption lines (per line and segment) are left out of the sweeps (`25 tol/32`
//!   in total) and act to first order at their middles instead, the depth is read as chords
//!   within `ln(1 + 3 tol/32)` inside a sweep, and the faintest segments' line light is
//!   attenuated by the transmittance at each line's middle instead of exactly (`3 tol/32` of
//!   each channel's unattenuated total); so each XYZ channel is within `tol` x the
//!   unattenuated emission's (a loose bound: see module `front`). [`PieceStats`] counts `P`'s pieces.
//! - Spectrum path (picked pixels, traces), back to front: the spectrum is kept, attenuated
//!   exactly at sub-piece ends (`max_depth_step`), and merged with `tol / segments` of its
//!   maximum per merge, so merges add at most `merge_tolerance` of the maximum in total.
//!   Tests check that both paths give the same XYZ within these bounds.
//! - Absorbing spectral cubes march front to back over the channels' window alone and bin
//!   the light straight into channels (module `cube_abs`: closed-form sub-interval integrals
//!   as in the image path; `max_depth_step` is not used).
//!
//! ## Glossary (paper term -> type)
//! | Paper | Here |
//! |---|---|
//! | Eq. 8 species, E_m, A_m | [`Species`] |
//! | Table 1 factors | [`Factors`] |
//! | Algorithm 1 (fixed bands) | [`SpectralIntegrator::Banded`], [`BandShift::Nearest`] |
//! | Algorithm 2 (piecewise linear) | [`SpectralIntegrator::PiecewiseLinear`] |
//! | Eq. 4/5, 6/7 | `blueshift_spectrum::DopplerModel` |
//! | merge tolerance (Fig. 18) | [`DopplerSettings::merge_tolerance`] |
//! | preview strategy | [`DopplerSettings::piece_budget`] |
//! | picked pixel spectra, step-by-step accumulation | [`pixel_spectrum`], [`trace_ray`] |
//! | line profile (paper: box of width delta lambda) | [`Broadening`], `blueshift_spectrum::PwlGaussian` |
//! | position-position-velocity cube (yt's `PPVCube`) | [`SpectralCube`], [`render_cube`] |
//! | moment maps 0/1/2 | [`Moments`] |

mod banded;
mod cube;
mod cube_abs;
mod display;
mod error;
mod fits;
mod front;
#[cfg(test)]
mod front_tests;
mod key;
mod model;
#[cfg(test)]
mod names;
pub mod part;
mod prepared;
mod profile;
mod pwl;
mod render;
pub mod scene_file;
mod session;
#[cfg(test)]
mod tests;

pub use banded::BandTables;
pub use blueshift_camera::{Camera, Projection, Ray};
pub use cube::{
    CubeLineWidth, CubeSpec, MAX_CHANNELS, Moments, SpectralAxis, SpectralCube, los_camera,
    render_cube,
};
pub use display::{ColourMatrix, DisplayOptions, Exposure, GamutMapper, SHOULDER_KNEE, shoulder};
pub use error::{Error, Result};
pub use fits::{CubeMeta, FitsHeader, FitsValue, WcsAxis, fits_bytes, nrrd_bytes, read_fits};
pub use key::doppler_colour_key;
pub use model::{
    BB_REF_NM, BB_UNIT, DopplerScene, Factors, Species, brightness_temperature, planck_factor,
};
pub use prepared::{LineEntry, LineKind, Prepared, RaySpan};
pub use profile::{Broadening, Profiles};
pub use pwl::PwlTables;
pub use render::{
    BandShift, DopplerImage, DopplerSettings, PieceStats, SpectralIntegrator, TraceStep,
    pixel_spectrum, render_doppler, render_doppler_bricks, render_doppler_bricks_with,
    render_doppler_lod, render_doppler_lod_with, trace_ray,
};
pub use scene_file::{
    BlackbodySpec, CubeUnitsSpec, FactorSpec, FieldSpec, MemoryVolumes, SceneFile, SpeciesSpec,
    VelocitySpec, catalogue_mass_amu,
};
pub use session::{DopplerSession, SAMPLE_CACHE_BYTES};
