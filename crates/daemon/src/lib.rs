//! The daemon's machinery, behind `mouthpiece run`.
//!
//! # Layout
//! - [`source`]: the source thread: opens the source, feeds the [`slot`], reopens a lost
//!   source with [`backoff`];
//! - [`console`]: what the booth console page needs: the preview's image and dots, health
//!   figures, the calibration report;
//! - [`live`]: the processor: the live pipeline (`mouthpiece_pipeline::live`: detect +
//!   track + retarget + rig and the mouths from speech, which fills the published step) for
//!   every configured character, plus the console's view of the dots;
//! - [`pipeline`]: the processing thread around a [`pipeline::Processor`];
//! - [`factory`]: builds the processor and its reloads from a configuration;
//! - [`check`]: everything a configuration must satisfy; [`error`], [`settings`]: leaf
//!   modules the checks and the daemon share (no module imports one that imports it back);
//! - [`slot`]: the latest-frame slot between the source thread and processing (newest wins);
//! - [`notify`]: systemd's notify protocol (READY, STATUS, WATCHDOG, STOPPING);
//! - [`osc`]: the rig, head and eyes as VMC protocol messages over UDP, from its own sender
//!   thread behind a bounded queue;
//! - [`livelink`]: Live Link Face's stream to Unreal and its OSC remote control, each on a
//!   thread of its own (the stream behind a bounded queue);
//! - [`logging`]: journald-friendly `tracing` set-up;
//! - [`ltc`]: the LTC thread: the studio's timecode decoded from a channel of the booth's
//!   audio into the hub's timecode clock;
//! - [`take_player`]: the takes folder read chunk by chunk for the console's player;
//! - [`tune`]: the console's paint check (propose colour ranges, count what they find, apply).
//!
//! Threads: the source thread, the processing thread, one take-writer thread while a take
//! records, the OSC sender thread once `[osc]` has a target, the Live Link sender thread, the
//! Live Link control thread when `[livelink] control` is set, the LTC thread with
//! `[timecode] source = "ltc"`, and the async server's runtime. Only bounded queues connect
//! them.

pub mod audio;
pub mod backoff;
pub mod capture;
pub mod check;
pub mod console;
pub mod daemon;
pub mod error;
pub mod factory;
pub mod hardening;
pub mod ifacialmocap;
pub mod live;
pub mod livelink;
pub mod logging;
pub mod ltc;
pub mod notify;
pub mod osc;
pub mod pipeline;
pub mod settings;
pub mod slot;
pub mod source;
pub mod take_player;
pub mod tune;

pub use daemon::{run, DaemonError, RunOptions};
/// Takes (one MCAP file per take from its own writer thread) live in their own crate.
pub use mouthpiece_takes as takes;

/// Runs the daemon with the real pipeline: detect + track + retarget ([`live`]).
pub fn run_live(config: mouthpiece_config::Config, options: RunOptions) -> Result<(), DaemonError> {
    run(config, live::LiveFactory, options)
}
