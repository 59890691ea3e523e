//! One module per `blueshift` verb.

pub mod spectrum;
pub mod tonemap;
pub mod tf;
