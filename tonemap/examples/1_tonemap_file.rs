//! Tone-maps one HDR file with one operator at its paper defaults and writes the
//! display-linear result as PFM (what `benches/scripts/tonemap_vs_pfstmo.py` reads).
//!
//! Run: `cargo run --release -p blueshift-tonemap --example 1_tonemap_file -- IN.{exr,hdr,pfm}
//! OUT.pfm durand|fattal|reinhard-local|drago|reinhard|clean` (`clean`: the input after the
//! dirty-input rule, unmapped, for feeding the same pixels to a peer tool).

use blueshift_tonemap::io::{read_hdr_image, write_pfm};
use blueshift_tonemap::{
    DragoParams, DurandParams, FattalParams, Operator, ReinhardLocalParams, ReinhardParams,
    sanitize,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [input, output, op] = args.as_slice() else {
        return Err("usage: 1_tonemap_file IN OUT.pfm OPERATOR".into());
    };
    let hdr = read_hdr_image(input)?;
    if op == "clean" {
        write_pfm(output, &sanitize(&hdr).0)?;
        return Ok(());
    }
    let op = match op.as_str() {
        "durand" => Operator::Durand(DurandParams::default()),
        "fattal" => Operator::Fattal(FattalParams::default()),
        "reinhard-local" => Operator::ReinhardLocal(ReinhardLocalParams::default()),
        "drago" => Operator::Drago(DragoParams::default()),
        "reinhard" => Operator::Reinhard(ReinhardParams::default()),
        other => return Err(format!("unknown operator {other}").into()),
    };
    write_pfm(output, &op.apply(&hdr)?)?;
    Ok(())
}
