//! One module per `blueshift` verb.

pub mod convert;
pub mod info;
pub mod render;
pub mod spectrum;
pub mod synth;
mod volume_common;
pub mod tf;
