//! `mouthpiece check-config FILE`: validates a daemon configuration and exits, without
//! opening the source or the port. Exit code 0 when valid, 2 with file, line, key and what
//! was expected when not.

use std::path::PathBuf;

use crate::exit::bad_input;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The config file (e.g. /etc/mouthpiece/mouthpiece.toml).
    pub file: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = mouthpiece_config::Config::load(&args.file).map_err(bad_input)?;
    mouthpiece_daemon::check::check(&config).map_err(bad_input)?;
    println!("{}: ok", args.file.display());
    println!("{}", config.summary());
    Ok(())
}
