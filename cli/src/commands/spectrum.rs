//! `blueshift spectrum` (being written).

/// Arguments of `blueshift spectrum`.
#[derive(Debug, clap::Args)]
pub struct Args {}

/// Runs `blueshift spectrum`.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("blueshift spectrum is not built yet")
}
