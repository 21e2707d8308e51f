//! `noisecal report` (being written).

#[derive(clap::Args, Debug)]
pub struct Args {}

pub fn run(_args: Args, _quiet: bool) -> anyhow::Result<()> {
    anyhow::bail!("noisecal report is not built yet")
}
