//! `blueshift synth NAME OUT`: writes a deterministic synthetic dataset.
//!
//! Output layout: one NRRD per channel. The first channel goes to OUT, every further channel
//! to `OUT-stem_<channel>.nrrd` beside it (e.g. `galaxy.nrrd`, `galaxy_he_density.nrrd`, ...,
//! `galaxy_velocity_m_per_s.nrrd`); `--channel` writes only the named one to OUT. The channel
//! name is in each file's `content:` field. The files written are listed on stderr.
//!
//! A `.bsv` OUT writes bricked out-of-core files instead, computed slice by slice and
//! bricked in the same pass, so the dataset never exists whole in memory (a 1536^3 galaxy
//! is 58 GB): one file per scalar, a vector channel as three files `..._x.bsv`, `_y`, `_z`
//! (how Doppler scene files name bricked velocities).

use std::path::PathBuf;

use anyhow::{Context, Result};
use blueshift_volume::io::nrrd;
use blueshift_volume::ooc::{self, BrickLayout};
use blueshift_volume::synth;

use super::volume_common::{sibling, write_volume};

/// Arguments of `blueshift synth`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset: galaxy, hydrogen-shell, three-cubes, turbulence, marschner-lobb, channels12.
    #[arg(value_parser = clap::builder::PossibleValuesParser::new(synth::NAMES))]
    pub name: String,
    /// Output file (.nrrd, .nhdr, .raw, or .bsv: streamed into bricked files without
    /// holding the grid in memory); extra channels go beside it.
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
    /// Brick edge for .bsv output (even, 2..=1024).
    #[arg(long, default_value_t = 64)]
    pub brick: usize,
}

/// Runs `blueshift synth`.
pub fn run(args: Args) -> Result<()> {
    if args
        .output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("bsv"))
    {
        return run_bricked(&args);
    }
    crate::output::check_output(&args.output)?;
    let vol = synth::by_name_within(&args.name, args.res, args.seed, crate::limits::budget())
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

/// `synth NAME OUT.bsv`: every component streamed into its own bricked file in one pass.
fn run_bricked(args: &Args) -> Result<()> {
    if args.gzip {
        anyhow::bail!("--gzip applies to NRRD output; .bsv bricks are stored uncompressed");
    }
    let cannot = || format!("cannot make '{}'", args.name);
    let mut stream = synth::stream_by_name(&args.name, args.res, args.seed).with_context(cannot)?;
    if let Some(c) = &args.channel {
        stream.select(c).with_context(cannot)?;
    }
    let names = stream.selected_names();
    // The first channel goes to OUT; when it is a vector (`--channel velocity`), its
    // components go to OUT-stem_x, _y, _z, as `convert` writes a vector volume.
    let first_is_vector = stream
        .channels()
        .iter()
        .any(|(n, c)| *c == 3 && names.first() == Some(&format!("{n}_x")));
    let paths: Vec<PathBuf> = names
        .iter()
        .enumerate()
        .map(|(i, n)| match i {
            0..3 if first_is_vector => sibling(&args.output, ["x", "y", "z"][i]),
            0 => args.output.clone(),
            _ => sibling(&args.output, n),
        })
        .collect();
    let refs: Vec<&std::path::Path> = paths.iter().map(PathBuf::as_path).collect();
    crate::output::check_outputs(&refs, &[])?;
    let layout = BrickLayout {
        brick: args.brick,
        ..BrickLayout::default()
    };
    let outs: Vec<(&std::path::Path, &str)> = refs
        .iter()
        .zip(&names)
        .map(|(p, n)| (*p, n.as_str()))
        .collect();
    let pb = crate::progress::Progress::new(
        stream.geometry().dims[2] as u64,
        "synth [{bar:40}] {pos}/{len} slices ({eta})",
        "synth",
        "slices",
    );
    ooc::convert_many_within(
        &mut stream,
        &outs,
        layout,
        crate::limits::budget(),
        &mut |done, total| {
            pb.set_length(total);
            pb.set_position(done);
        },
    )
    .with_context(cannot)?;
    pb.finish();
    for p in &paths {
        crate::output::wrote(p);
    }
    Ok(())
}
