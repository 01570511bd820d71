//! `mouthpiece`: the command-line front end and daemon.
//!
//! Thin glue: every subcommand lives in `cmd/<name>.rs`, parses its arguments with clap and
//! calls into the library crates. Errors travel as `anyhow::Error`; `main` prints the chain
//! once and maps it to an exit code (2 for bad input or configuration, 1 otherwise).

mod cmd;
mod exit;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(name = "mouthpiece", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Retarget 3D dot positions (JSONL) onto a character's mouth (JSONL).
    Retarget(cmd::retarget::Args),
    /// Run the whole pipeline (detect, track, retarget) over a recorded session, offline.
    Process(cmd::process::Args),
    /// Measure detection, tracking and retargeting on synthetic sessions with ground truth.
    Evaluate(cmd::evaluate::Args),
    /// Validate a daemon configuration file and exit (0 valid, 2 invalid).
    CheckConfig(cmd::check_config::Args),
    /// Run the daemon: source → detect → track → retarget → WebSocket server, with takes.
    Run(cmd::run::Args),
    /// Render a synthetic performer (head with painted dots, depth + colour, ground truth) to MCAP.
    Synth(cmd::synth::Args),
    /// Record a source (camera, Dummy device, replay) to MCAP, or an OpenNI2 source to .oni.
    Record(cmd::record::Args),
    /// List OpenNI2 devices and V4L2 nodes with their modes and formats.
    Devices(cmd::devices::Args),
    /// Export a take (JSONL or recording) as keyframe animation: glTF 2.0, GLB or CSV.
    Export(cmd::export::Args),
    /// Propose the detector's colour classes from the first seconds of a session (prints a
    /// `[detect]` TOML snippet).
    #[command(name = "tune-colours")]
    TuneColours(cmd::tune_colours::Args),
    /// Bind a character's mesh to its mouth points (skin weights, skinned GLB); train and
    /// evaluate the binding network.
    Bind(cmd::bind::Args),
    /// Speech to a take: phone files or WAV audio (PocketSphinx) → viseme weight curves → the
    /// character's mouth (JSONL, the format of `process`).
    Lipsync(cmd::lipsync::Args),
    /// Send a take (JSONL) over the VMC protocol, each frame at its time, as the daemon sends
    /// a live character: rig curves, VRM visemes, head and eyes.
    Play(cmd::play::Args),
    /// List and fetch the takes booths uploaded to the studio's NATS object store.
    Takes(cmd::takes::Args),
}

fn main() -> ExitCode {
    init_logging();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Retarget(args) => cmd::retarget::run(args),
        Command::Play(args) => cmd::play::run(args),
        Command::Process(args) => cmd::process::run(args),
        Command::Evaluate(args) => cmd::evaluate::run(args),
        Command::CheckConfig(args) => cmd::check_config::run(args),
        Command::Run(args) => cmd::run::run(args),
        Command::Synth(args) => cmd::synth::run(args),
        Command::Record(args) => cmd::record::run(args),
        Command::Devices(args) => cmd::devices::run(args),
        Command::Export(args) => cmd::export::run(args),
        Command::TuneColours(args) => cmd::tune_colours::run(args),
        Command::Bind(args) => cmd::bind::run(args),
        Command::Lipsync(args) => cmd::lipsync::run(args),
        Command::Takes(args) => cmd::takes::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => exit::report(&err),
    }
}

/// Logs go to stderr (stdout may carry data, e.g. `retarget --out -`). `RUST_LOG` filters;
/// the default is INFO. journald-friendly: no colours unless stderr is a terminal, no
/// timestamps under systemd (see `mouthpiece_daemon::logging`).
fn init_logging() {
    mouthpiece_daemon::logging::init();
}
