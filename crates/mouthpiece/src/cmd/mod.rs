//! One module per subcommand.

pub mod retarget;
pub mod devices;
pub mod record;
