//! One module per subcommand.

pub mod process;
pub mod retarget;
