//! One module per subcommand.

pub mod retarget;
