//! `mouthpiece run`: the daemon. With no `--config` it runs the embedded default: the demo
//! session in `recordings/` looped at real-time pace, the human and wolf characters, the
//! server and viewer on http://127.0.0.1:9870/.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use mouthpiece_config::{Config, SourceSpec};
use mouthpiece_daemon::daemon::{DaemonError, Overrides, RunOptions};

use crate::exit::bad_input;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Config file (TOML; see config/mouthpiece.toml). Without it: the embedded default.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Listen address, overriding the config (e.g. 127.0.0.1:9870).
    #[arg(long, value_name = "ADDR:PORT")]
    pub listen: Option<SocketAddr>,
    /// Source spec, overriding the config: replay:PATH[?loop=1&speed=1.0], `openni2:[URI]`,
    /// v4l2:COLOUR[+DEPTH].
    #[arg(long, value_name = "SPEC")]
    pub source: Option<String>,
    /// Start recording a take at once, with this slate.
    #[arg(long, value_name = "SLATE")]
    pub record: Option<String>,
    /// Take number for --record (default: one more than the slate's highest).
    #[arg(long, value_name = "N", requires = "record")]
    pub take: Option<u32>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut config = match &args.config {
        Some(path) => Config::load(path).map_err(bad_input)?,
        None => embedded_default(),
    };
    if let Some(source) = &args.source {
        SourceSpec::try_from(source.clone())
            .map_err(|e| bad_input(anyhow::anyhow!("--source: {e}")))?;
    }
    if let Some(slate) = &args.record {
        if !mouthpiece_daemon::takes::valid_slate(slate) {
            return Err(bad_input(anyhow::anyhow!(
                "--record: invalid slate {slate:?}: use 1-64 letters, digits, '-', '_' or '.'"
            )));
        }
    }
    let overrides = Overrides {
        listen: args.listen,
        source: args.source.clone(),
    };
    mouthpiece_daemon::daemon::apply_overrides(&mut config, &overrides);
    let options = RunOptions {
        config_path: args.config.clone(),
        record: args.record.clone().map(|slate| (slate, args.take)),
        overrides,
    };
    match mouthpiece_daemon::run_live(config, options) {
        Ok(()) => Ok(()),
        Err(err @ DaemonError::Config(_)) => Err(bad_input(err)),
        Err(err) => Err(err.into()),
    }
}

/// The built-in configuration. Its relative paths are relative to the working directory
/// (the repository root for `scripts/run`); the demo session is also found in the source
/// tree this binary was built from, so the default works from any directory on the build
/// machine.
fn embedded_default() -> Config {
    let mut config = Config::embedded();
    if let Some(path) = config.source.spec.replay_path() {
        let built_from = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../..")
            .join(path);
        if !Path::new(path).exists() && built_from.exists() {
            let query = config
                .source
                .spec
                .as_str()
                .split_once('?')
                .map(|(_, q)| q.to_owned());
            let resolved = built_from.canonicalize().unwrap_or(built_from);
            let spec = match query {
                Some(q) => format!("replay:{}?{q}", resolved.display()),
                None => format!("replay:{}", resolved.display()),
            };
            config.source.spec = SourceSpec(spec);
        }
    }
    config
}
