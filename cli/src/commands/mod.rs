//! One module per `blueshift` verb.

pub mod spectrum;
pub mod relativity;
