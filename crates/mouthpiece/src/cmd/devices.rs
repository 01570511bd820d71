//! `mouthpiece devices`: OpenNI2 devices with their modes, V4L2 nodes with their formats.

#[derive(Debug, clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    print!("{}", mouthpiece_capture::devices::list());
    Ok(())
}
