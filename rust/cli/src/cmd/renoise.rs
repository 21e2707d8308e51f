//! `noisecal renoise` (being written).

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args, _quiet: bool) -> anyhow::Result<()> {
    anyhow::bail!("noisecal renoise is not built yet")
}
