//! One module per subcommand.

pub mod evaluate;
pub mod process;
pub mod retarget;
pub mod synth;
