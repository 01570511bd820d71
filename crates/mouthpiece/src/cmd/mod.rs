//! One module per subcommand.

pub mod bind;
pub mod check_config;
pub mod devices;
pub mod evaluate;
pub mod export;
pub mod export_audio;
pub mod lipsync;
pub mod lipsync_learn;
pub mod lipsync_poses;
pub mod play;
pub mod process;
pub mod record;
pub mod retarget;
pub mod run;
pub mod synth;
pub mod synth_speech;
pub mod takes;
pub mod tune_colours;
