//! `scanfuse check --config FILE`: validates a site config without starting anything.

use std::path::PathBuf;

use scanfuse::daemon::config::Config;
use scanfuse::daemon::state::{POSES_FILE, PosesFile};

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
    let dir = &config.site.state_dir;
    match PosesFile::load(dir) {
        Ok(None) => println!("  no saved poses yet in {}", dir.display()),
        Ok(Some(poses)) => match poses.matches(&config, &dir.join(POSES_FILE)) {
            Ok(()) => println!("  saved poses in {} match the config", dir.display()),
            Err(e) => println!("  note: {e}"),
        },
        Err(e) => println!("  note: {e}"),
    }
    println!("config OK");
    Ok(())
}
