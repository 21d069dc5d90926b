//! `scanfuse simulate` (being written).

#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("scanfuse simulate is not built yet")
}
