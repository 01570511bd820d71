//! One module per subcommand.

pub mod retarget;
pub mod synth;
