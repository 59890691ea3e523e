//! One module per `blueshift` verb.

pub mod clean;
pub mod convert;
pub mod doppler;
pub mod doppler_cube;
pub mod gpu_info;
pub mod info;
pub mod observer_args;
pub mod relativity;
pub mod render;
pub mod render_heat;
pub mod spectrum;
pub mod synth;
pub mod tf;
pub mod tonemap;
pub mod view;
pub mod view_args;
mod volume_common;
