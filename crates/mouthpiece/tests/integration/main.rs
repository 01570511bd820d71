//! The crate's integration tests, one module per former test file, in one test binary
//! (each test binary links the whole dependency tree: one binary builds and links once).

#[path = "../../../../tests/alsa/booth.rs"]
#[allow(unused_imports)]
mod helper_alsa_booth;
#[path = "../../../../tests/alsa/read_back.rs"]
#[allow(unused_imports)]
mod helper_alsa_read_back;
#[path = "../../../../tests/daemon/run.rs"]
#[allow(unused_imports)]
mod helper_daemon_run;
#[path = "../../../lipsync/tests/festival/mod.rs"]
#[allow(unused_imports)]
mod helper_festival;
#[path = "../../../nats/tests/harness/mod.rs"]
#[allow(unused_imports)]
mod helper_harness;
#[path = "../../../../tests/speech/cover_mouth.rs"]
#[allow(dead_code, unused_imports)]
mod helper_speech_cover_mouth;
#[path = "../../../server/tests/webdriver/mod.rs"]
#[allow(dead_code, unused_imports)]
mod helper_webdriver;

mod audio_booth;
mod bind;
mod check_config;
mod console_e2e;
mod console_player;
mod console_tune;
mod daemon_e2e;
mod export;
mod export_onto;
mod lipsync;
mod lipsync_learn;
mod live_record;
mod nats_e2e;
mod oni_hostile;
mod record_audio;
mod retarget_cli;
mod speech_booth;
mod synth_cli;
mod systemd_unit;
mod takes_hostile;
mod tune_colours;

/// The workspace's root (configuration, characters, recordings, docs), absolute.
pub fn repo() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .expect("the workspace root")
}

/// The `mouthpiece` binary under test.
pub fn mouthpiece() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_mouthpiece"))
}
