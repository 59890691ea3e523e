//! One module per `blueshift` verb.

pub mod convert;
pub mod info;
pub mod render;
pub mod spectrum;
pub mod synth;
pub mod tf;
mod volume_common;
