//! `mouthpiece retarget`: 3D dots (JSONL) → character mouth points (JSONL).

use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Character file (TOML).
    #[arg(long)]
    pub character: PathBuf,
    /// Input JSONL, `-` for stdin.
    #[arg(long)]
    pub input: PathBuf,
    /// Output JSONL, `-` for stdout.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("retarget is being built (issue 2)")
}
