//! One module per `blueshift` verb.

pub mod relativity;
pub mod spectrum;
pub mod tonemap;
pub mod tf;
