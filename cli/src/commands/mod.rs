//! One module per `blueshift` verb.

pub mod spectrum;
pub mod info;
pub mod convert;
pub mod synth;
mod volume_common;
