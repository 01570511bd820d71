//! One module per subcommand.

pub mod devices;
pub mod record;
pub mod retarget;
pub mod synth;
