//! `scanfuse check --config FILE`: validates a site config without starting anything.

use std::path::PathBuf;

use scanfuse::daemon::config::Config;
use scanfuse::daemon::state::PosesFile;

use super::BadInput;

#[derive(clap::Args)]
pub struct Args {
    /// The site config (TOML) to check.
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = Config::load(&args.config).map_err(|e| BadInput(e.to_string()))?;
    print!("{}", config.summary());
    // Saved poses are informational here: the daemon registers afresh when they do not fit.
    // A site daemon saves none (its zones do).
    let dir = config.site.state_dir.display();
    match PosesFile::load_matching(&config) {
        _ if config.site.role == scanfuse::daemon::config::Role::Site => {}
        Ok(None) => println!("  no saved poses yet in {dir}"),
        Ok(Some(_)) => println!("  saved poses in {dir} match the config"),
        Err(e) => println!("  note: {e}"),
    }
    println!("config OK");
    Ok(())
}
