//! # blueshift-tfedit: high-resolution transfer functions
//!
//! Transfer functions for high-dynamic-range volume rendering (HDR VolVis, Yuan et al.,
//! sections 3, 5 and 6.2): colour knots interpolated in RGB, HSV, Lab or Moreland's
//! diverging space, opacity knots, a global opacity alpha_g, a data domain with an optional
//! logarithmic axis; lookup tables of 256 to 2^24 entries and their 2D encoding; exact
//! max-opacity queries for majorants (MDWT section 4.3); the focus+context editor axes
//! (fisheye data axis, logarithmic opacity axis) and a picture of the editor view;
//! ParaView preset exchange and built-in maps.
//!
//! ## Where do I start?
//! - [`load`] reads a transfer function from blueshift's JSON or a ParaView preset.
//! - [`TransferFunction`]: [`TransferFunction::eval`] gives RGBA at a data value,
//!   [`TransferFunction::max_opacity`] bounds the opacity over a value range,
//!   [`TransferFunction::lut`] builds a [`Lut`], which [`Lut2d`] encodes for textures.
//! - [`Fisheye`] and [`ValueAxis`] are the editor's axes; `picture::render_editor_view`
//!   (feature `picture`) draws them.
//!
//! ## What opacity means
//! Opacities are numbers in [0, 1] without unit; `eval` returns the knot opacity times
//! alpha_g. Renderers multiply it by a density scale to get the extinction coefficient per
//! unit length (see [`TransferFunction`]).
//!
//! ## Glossary (paper term → type)
//! | Paper | Here |
//! |---|---|
//! | transfer function (HDR VolVis §5) | [`TransferFunction`] |
//! | HSV colour interpolation (§5) | [`ColorSpace::Hsv`] |
//! | global opacity α_g (§3) | [`TransferFunction::alpha_g`], [`TransferFunction::with_alpha_g`] |
//! | 2^16-entry lookup table (§5) | [`Lut`], [`TransferFunction::lut`] |
//! | 2D texture encoding, m × (n+2) (§6.2, Fig. 8) | [`Lut2d`] |
//! | focus region R_c, M_c, transition R_tr (Fig. 6) | [`FocusRegion`] |
//! | nonlinear magnification, M_min from Eq. 2 | [`Fisheye`], [`Fisheye::m_min`] |
//! | logarithmic alpha/colour axis (Fig. 7) | [`ValueAxis::Log`] |
//! | editor snapshot (Fig. 7) | `picture::render_editor_view` |
//! | macrocell majorant = max opacity over [min, max] (MDWT §4.3) | [`TransferFunction::max_opacity`] |
//!
//! ## Features
//! - `rayon` (default): build long tables on all cores; results are identical without it.
//! - `picture` (default): the editor-view picture (`plotters`, `image`).

mod axis;
pub mod color;
mod error;
mod io;
mod lut;
pub mod paraview;
#[cfg(feature = "picture")]
pub mod picture;
pub mod presets;
mod tf;

pub use axis::{Fisheye, FocusRegion, ValueAxis};
pub use color::ColorSpace;
pub use error::{Error, Result};
pub use io::{
    FORMAT_TAG, FORMAT_VERSION, Format, MAX_FILE_BYTES, TransferFunctionFile, detect, load,
    parse_any,
};
pub use lut::{Lut, Lut2d, MAX_LUT_ENTRIES, MIN_LUT_ENTRIES};
pub use presets::{BUILTIN_NAMES, builtin, builtin_over};
pub use tf::{ColorKnot, DataAxis, OpacityKnot, TransferFunction};
