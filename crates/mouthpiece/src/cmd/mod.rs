//! One module per subcommand.

pub mod check_config;
pub mod devices;
pub mod record;
pub mod retarget;
pub mod run;
pub mod synth;
