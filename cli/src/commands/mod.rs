//! One module per `blueshift` verb.

pub mod relativity;
pub mod spectrum;
pub mod tonemap;
pub mod tf;
pub mod convert;
pub mod info;
pub mod spectrum;
pub mod synth;
mod volume_common;
