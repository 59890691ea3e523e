//! `blueshift synth NAME OUT`: writes a deterministic synthetic dataset.
//!
//! Output layout: one NRRD per channel. The first channel goes to OUT, every further channel
//! to `OUT-stem_<channel>.nrrd` beside it (e.g. `galaxy.nrrd`, `galaxy_he_density.nrrd`, ...,
//! `galaxy_velocity_m_per_s.nrrd`); `--channel` writes only the named one to OUT. The channel
//! name is in each file's `content:` field. The files written are listed on stderr.

use std::path::PathBuf;

use anyhow::{Context, Result};
use blueshift_volume::io::nrrd;
use blueshift_volume::synth;

use super::volume_common::write_volume;

/// Arguments of `blueshift synth`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset: galaxy, hydrogen-shell, three-cubes, turbulence, marschner-lobb, channels12.
    #[arg(value_parser = clap::builder::PossibleValuesParser::new(synth::NAMES))]
    pub name: String,
    /// Output file (.nrrd, .nhdr or .raw); extra channels go beside it.
    pub output: PathBuf,
    /// Voxels per edge (2..=2048; galaxy has half as many along z).
    #[arg(long, default_value_t = 64)]
    pub res: usize,
    /// Seed of the noise (same seed and resolution, same voxels).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write only this channel.
    #[arg(long)]
    pub channel: Option<String>,
    /// gzip the NRRD data.
    #[arg(long)]
    pub gzip: bool,
}

/// Runs `blueshift synth`.
pub fn run(args: Args) -> Result<()> {
    crate::output::check_output(&args.output)?;
    let vol = synth::by_name(&args.name, args.res, args.seed)
        .with_context(|| format!("cannot make '{}'", args.name))?;
    let opts = nrrd::WriteOptions {
        gzip: args.gzip,
        disk: None,
    };
    for p in write_volume(&args.output, &vol, args.channel.as_deref(), &opts)? {
        crate::output::wrote(&p);
    }
    Ok(())
}
