//! The processing thread: takes the newest frame from the slot, runs the [`Processor`]
//! (detect → track → retarget, one or several characters), publishes the result to the
//! server's hub and the OSC output, feeds the take recorder, and answers control requests.
//!
//! It never blocks on I/O: the hub's publish is a non-blocking ring write, the take writer
//! and the OSC sender sit behind bounded queues, control replies are one-shot sends. In steady state, with no
//! take recording, the path from a new frame to the clients' queues reuses its buffers
//! ([`Output`] is refilled in place and the hub copies it with `clone_from` into recycled
//! slots).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

use crossbeam_channel::Receiver;
use mouthpiece_frame::Frame;
use mouthpiece_server::timecode_clock::TimecodeClock;
use mouthpiece_server::{
    ControlCommand, ControlFailure, ControlReceiver, ControlRequest, Hub, Recording,
    SourceState as WireSourceState, StreamInfo, TimecodeRate,
};
use serde_json::json;

use crate::slot::Taken;
use crate::source::{SourceShared, SourceState};
use mouthpiece_takes::{CharacterRecord, Derived, TakeEnded, Takes};

/// What a processor fills per frame (the live pipeline's step, reused from frame to frame)
/// and the flags it reports besides the stream frame.
pub use mouthpiece_pipeline::live::{Flags, Output};

/// Turns a frame into the stream's per-frame result. The real one is detect + track +
/// retarget; the trait keeps the daemon independent of how.
pub trait Processor: Send {
    /// A validated new configuration for the processor ([`crate::factory::Factory::reload`]).
    type Reload: Send + 'static;

    /// Processes `frame` into `out`, reusing `out`'s buffers.
    fn process(&mut self, frame: &Frame, out: &mut Output);

    /// Starts a new neutral calibration over `duration` of still, closed mouth (`None`: the
    /// configured length); the frame that takes the pose sets [`Flags::neutral_taken`].
    fn calibrate(&mut self, duration: Option<Duration>);

    /// The source was reopened (its clock may have started again). Default: nothing.
    fn source_restarted(&mut self) {}

    /// The audio thread's bus, when the daemon captures sound: a processor that drives
    /// mouths from speech subscribes to it. Default: nothing.
    fn set_audio(&mut self, _bus: &std::sync::Arc<mouthpiece_frame::AudioBus>) {}

    /// With speech alone driving every character and no calibrated camera timing the
    /// steps: fills `out` with the next step taken from the sound and returns the host time
    /// of that sound (`None`: no step due). Default: never.
    fn speech_step(&mut self, _out: &mut Output) -> Option<Instant> {
        None
    }

    /// Characters, point names and frame rate for `hello`.
    fn stream_info(&self, frame_rate: f64, source: &str) -> StreamInfo;

    /// True once after the stream's description changed (characters bound to a new neutral
    /// pose: new `M`); the pipeline then sends clients a new `hello`.
    fn take_info_changed(&mut self) -> bool;

    /// Names of [`Output::performer_camera`]'s entries.
    fn performer_names(&self) -> &[String];

    /// Applies a reloaded configuration (characters, colour ranges); the old one stays on
    /// error.
    fn reload(&mut self, update: Self::Reload) -> Result<(), String>;

    /// The dots on the last frame's camera image, for the console's preview (called only
    /// when a preview image is due).
    fn preview_overlay(&self, _frame: &Frame) -> mouthpiece_server::Overlay {
        mouthpiece_server::Overlay::default()
    }

    /// The colour ranges the detector runs with and the dot counts, for the paint check
    /// (`None`: this processor has none).
    fn detect_in_use(&self) -> Option<crate::tune::InUse> {
        None
    }

    /// Turns `character`'s head to `point` (its model frame), or back to following the
    /// performer (`None`): the `look_at` request. `Ok` carries the answer's `detail`.
    fn look_at(
        &mut self,
        character: &str,
        _point: Option<[f64; 3]>,
    ) -> Result<serde_json::Value, String> {
        Err(format!("character {character:?} has no head to turn here"))
    }

    /// How good the neutral pose taken on the last frame was, once (`wall_us` is set by
    /// the caller).
    fn take_calibration_report(&mut self) -> Option<mouthpiece_server::CalibrationReport> {
        None
    }
}

/// Requests from the daemon itself (signals, start-up options) to the processing thread.
#[derive(Debug)]
pub enum Command<R> {
    /// A validated new configuration for the processor (see [`Processor::reload`]).
    Reload(R),
    RecordStart {
        slate: String,
        take: Option<u32>,
    },
    RecordStop,
}

/// Everything the processing thread needs (`R`: the processor's reload payload).
pub struct Context<R> {
    pub source: Arc<SourceShared>,
    pub spec: String,
    pub hub: Hub,
    pub control: ControlReceiver,
    pub commands: Receiver<Command<R>>,
    pub takes: Takes,
    pub default_slate: String,
    pub timecode_rate: TimecodeRate,
    pub stall_timeout: Duration,
    /// Milliseconds since `epoch` of the loop's last turn: the watchdog's heartbeat.
    pub heartbeat: Arc<AtomicU64>,
    pub epoch: Instant,
    pub stop: Arc<AtomicBool>,
    /// The OSC output (`[osc]`): offered every published frame, never blocks.
    pub osc: crate::osc::OscOutput,
    /// Live Link Face's stream, offered the same frames as `osc`.
    pub livelink: crate::livelink::LiveLinkOutput,
    /// The iFacialMocap output (`[ifacialmocap]`): offered every published frame, never
    /// blocks.
    pub ifacialmocap: crate::ifacialmocap::IfmOutput,
    /// The console's paint check: offered every frame while it samples, never blocks.
    pub tuner: crate::tune::Tuner,
}

/// Starts the processing thread.
pub fn spawn<P: Processor + 'static>(
    processor: P,
    ctx: Context<P::Reload>,
) -> std::io::Result<JoinHandle<()>> {
    std::thread::Builder::new()
        .name("mouthpiece-process".into())
        .spawn(move || run(processor, ctx))
}

/// How long a `calibrate` request waits for a still, closed mouth beyond its duration
/// before it is answered with an error (the calibration itself goes on; `status` says when it
/// ends). Twenty seconds are a few attempts at holding still; the server waits for the answer
/// for its control timeout plus the duration.
pub const CALIBRATE_ANSWER_GRACE: Duration = Duration::from_secs(20);

/// `calibrate` requests waiting for the neutral pose, each with the time it gives up.
#[derive(Default)]
struct PendingCalibrations {
    waiting: Vec<(ControlRequest, Instant)>,
}

impl PendingCalibrations {
    fn push(&mut self, request: ControlRequest, duration: Option<Duration>) {
        let wait = duration.unwrap_or(Duration::from_secs(1)) + CALIBRATE_ANSWER_GRACE;
        self.waiting.push((request, Instant::now() + wait));
    }

    /// Answers every waiting request: the neutral pose was taken.
    fn taken(&mut self, seq: u64) {
        for (request, _) in self.waiting.drain(..) {
            tracing::info!(client = %request.client, "calibration done");
            request.reply(Ok(json!({ "calibrated": true, "seq": seq })));
        }
    }

    /// Answers the requests that waited too long.
    fn expire(&mut self, now: Instant) {
        let mut i = 0;
        while i < self.waiting.len() {
            if self.waiting[i].1 <= now {
                let (request, _) = self.waiting.swap_remove(i);
                let failure = ControlFailure::new(
                    "no still, closed mouth long enough yet; the calibration goes on (see status) and the previous neutral pose stays in use until it ends",
                );
                tracing::warn!(client = %request.client, "calibrate: {}", failure.message);
                request.reply(Err(failure));
            } else {
                i += 1;
            }
        }
    }
}

fn run<P: Processor>(mut processor: P, mut ctx: Context<P::Reload>) {
    let mut pending = PendingCalibrations::default();
    let mut up_before = false;
    let mut out = Output::default();
    let mut seen_generation = u64::MAX;
    let mut last_frame: Option<Instant> = None;
    let mut stalled = false;
    let mut calibrating = None;
    let mut frame_rate = 0.0;
    let mut frames = 0u64;
    let mut health = crate::console::HealthMeter::new(ctx.takes.settings().folder.clone());
    tracing::info!("processing thread started");
    loop {
        ctx.heartbeat
            .store(ctx.epoch.elapsed().as_millis() as u64, Ordering::Relaxed);
        if ctx.stop.load(Ordering::Acquire) {
            break;
        }
        match ctx.source.frames.take_timeout(Duration::from_millis(50)) {
            Taken::Value(mut frame) => {
                let started = Instant::now();
                frames += 1;
                last_frame = Some(started);
                if stalled {
                    stalled = false;
                    seen_generation = u64::MAX; // republish the source state
                }
                // Wall clock of receipt: what the audio recorder beside us saw at that moment.
                let wall = SystemTime::now() - frame.host_rx.elapsed();
                frame.wall_clock = Some(wall);
                let wall_us = mouthpiece_takes::unix_us(wall);
                out.flags.neutral_taken = false;
                processor.process(&frame, &mut out);
                ctx.tuner.offer(&frame);
                if processor.take_info_changed() {
                    ctx.hub
                        .set_info(processor.stream_info(frame_rate, &ctx.spec));
                }
                out.stream.t = frame
                    .host_rx
                    .saturating_duration_since(ctx.epoch)
                    .as_secs_f64();
                out.stream.capture_us = frame.device_ts_us;
                out.stream.wall_us = Some(wall_us);
                out.stream.processing = Some(started.elapsed());
                let time = ctx.hub.frame_time(&out.stream);
                let seq = ctx.hub.publish_at(&out.stream, time);
                ctx.osc.offer(&out.stream);
                ctx.livelink.offer(&out.stream, time);
                ctx.ifacialmocap.offer(&out.stream);
                tracing::trace!(seq, device_ts_us = frame.device_ts_us, "frame processed");
                health.frame(
                    processor.performer_names().len(),
                    out.flags.dots_missing,
                    started.elapsed(),
                    frame.host_rx.elapsed(),
                    [frame.color.width, frame.color.height],
                );
                if let Some(mut report) = processor.take_calibration_report() {
                    report.wall_us = wall_us;
                    tracing::info!(?report, "calibration report");
                    ctx.hub.set_calibration(report);
                }
                let preview_due = ctx.hub.preview_due(out.stream.t);
                let frame = if preview_due || ctx.takes.is_recording() {
                    Some(Arc::new(frame))
                } else {
                    None
                };
                if let (true, Some(frame)) = (preview_due, &frame) {
                    ctx.hub.offer_preview(mouthpiece_server::PreviewInput {
                        seq,
                        t: out.stream.t,
                        capture_us: out.stream.capture_us,
                        wall_us: out.stream.wall_us,
                        image: Arc::new(crate::console::FrameImage(frame.clone())),
                        overlay: processor.preview_overlay(frame),
                    });
                }
                if out.flags.neutral_taken {
                    pending.taken(seq);
                }
                if calibrating != Some(out.flags.calibrating) {
                    calibrating = Some(out.flags.calibrating);
                    let now = out.flags.calibrating;
                    ctx.hub.update_status(|s| s.calibrating = now);
                    tracing::info!(calibrating = now, "calibration state");
                }
                if let (true, Some(frame)) = (ctx.takes.is_recording(), frame) {
                    let info = ctx.hub.info();
                    let derived = derive(
                        processor.performer_names(),
                        &info,
                        &out,
                        seq,
                        wall_us,
                        &ctx.hub.timecode_clock(),
                    );
                    ctx.takes.push(frame, Box::new(derived));
                }
            }
            Taken::Empty => {
                if let (Some(last), false) = (last_frame, stalled) {
                    if last.elapsed() >= ctx.stall_timeout
                        && matches!(ctx.source.state().1, SourceState::Up(_))
                    {
                        stalled = true;
                        let message = format!(
                            "source down: no frame for {:.1} s",
                            last.elapsed().as_secs_f64()
                        );
                        tracing::warn!("{message}");
                        ctx.hub.update_status(|s| {
                            s.source = WireSourceState::Down;
                            s.message = Some(message);
                        });
                    }
                }
            }
            Taken::Closed => break,
        }
        // A booth without camera steps: the sound's own clock times them.
        while let Some(heard_at) = processor.speech_step(&mut out) {
            let wall = SystemTime::now() - heard_at.elapsed();
            out.stream.t = heard_at.saturating_duration_since(ctx.epoch).as_secs_f64();
            out.stream.capture_us = 0;
            out.stream.wall_us = Some(mouthpiece_takes::unix_us(wall));
            out.stream.processing = None;
            let time = ctx.hub.frame_time(&out.stream);
            let seq = ctx.hub.publish_at(&out.stream, time);
            ctx.osc.offer(&out.stream);
            ctx.livelink.offer(&out.stream, time);
            ctx.ifacialmocap.offer(&out.stream);
            frames += 1;
            if ctx.takes.is_recording() {
                let info = ctx.hub.info();
                let wall_us = out.stream.wall_us.unwrap_or_default();
                let derived = derive(
                    processor.performer_names(),
                    &info,
                    &out,
                    seq,
                    wall_us,
                    &ctx.hub.timecode_clock(),
                );
                ctx.takes.push_step(Box::new(derived));
            }
        }
        let generation = ctx.source.generation();
        if generation != seen_generation && !stalled {
            seen_generation = generation;
            let (_, state) = ctx.source.state();
            if let SourceState::Up(_) = state {
                if up_before {
                    // Reopened: the source's clock may have started again.
                    processor.source_restarted();
                }
                up_before = true;
            }
            publish_source_state(&ctx, &processor, &state, &mut frame_rate);
        }
        while let Some(request) = ctx.control.try_recv() {
            handle_control(&mut processor, &mut ctx, &mut pending, request);
        }
        pending.expire(Instant::now());
        while let Ok(command) = ctx.commands.try_recv() {
            handle_command(&mut processor, &mut ctx, command, frame_rate);
        }
        ctx.takes.poll();
        if let Some(figures) = health.tick(Instant::now()) {
            ctx.hub.set_health(figures);
        }
    }
    // Finish every take (bounded by its queue), synced to disk, before the daemon exits.
    ctx.takes.shutdown();
    tracing::info!(
        frames,
        overwritten = ctx.source.frames.overwritten(),
        "processing thread stopped"
    );
}

fn publish_source_state<P: Processor>(
    ctx: &Context<P::Reload>,
    processor: &P,
    state: &SourceState,
    frame_rate: &mut f64,
) {
    match state {
        SourceState::Starting => {}
        SourceState::Up(info) => {
            *frame_rate = info.fps;
            ctx.hub.set_info(processor.stream_info(info.fps, &ctx.spec));
            ctx.hub.update_status(|s| {
                s.source = WireSourceState::Up;
                s.message = None;
            });
        }
        SourceState::Down { reason, retry_in } => {
            let message = format!(
                "source down: {reason}; retrying in {:.1} s",
                retry_in.as_secs_f64()
            );
            ctx.hub.update_status(|s| {
                s.source = WireSourceState::Down;
                s.message = Some(message);
            });
        }
    }
}

fn handle_control<P: Processor>(
    processor: &mut P,
    ctx: &mut Context<P::Reload>,
    pending: &mut PendingCalibrations,
    request: ControlRequest,
) {
    tracing::info!(client = %request.client, command = ?request.command, "control request");
    let command = request.command.clone();
    if let ControlCommand::Calibrate { duration } = command {
        processor.calibrate(duration);
        ctx.hub.update_status(|s| s.calibrating = true);
        // Answered once the neutral pose is taken (or given up on).
        pending.push(request, duration);
        return;
    }
    // Takes answer from their writer thread once the file is open or closed.
    let reply = move |outcome: Result<serde_json::Value, String>| {
        let outcome = outcome.map_err(ControlFailure::new);
        if let Err(failure) = &outcome {
            tracing::warn!(client = %request.client, "control request failed: {}", failure.message);
        }
        request.reply(outcome);
    };
    match command {
        ControlCommand::Calibrate { .. } => {}
        ControlCommand::LookAt { character, point } => {
            let outcome = processor.look_at(&character, point);
            if outcome.is_ok() {
                tracing::info!(%character, ?point, "look_at");
            }
            reply(outcome);
        }
        ControlCommand::RecordStart { slate, take } => {
            let slate = slate.unwrap_or_else(|| ctx.default_slate.clone());
            start_take(ctx, &slate, take, Box::new(reply));
        }
        ControlCommand::RecordStop => stop_take(ctx, Box::new(reply)),
        ControlCommand::TuneColours { apply: true, .. } => reply(ctx.tuner.apply()),
        ControlCommand::TuneColours {
            apply: false,
            seconds,
        } => reply(match processor.detect_in_use() {
            Some(in_use) => ctx.tuner.run(in_use, seconds),
            None => Err("this processor has no colour ranges to check".into()),
        }),
    }
}

/// Where the outcome of a take request goes (a client's reply, or the log).
type TakeReply = Box<dyn FnOnce(Result<serde_json::Value, String>) + Send>;

fn handle_command<P: Processor>(
    processor: &mut P,
    ctx: &mut Context<P::Reload>,
    command: Command<P::Reload>,
    frame_rate: f64,
) {
    match command {
        Command::Reload(update) => match processor.reload(update) {
            Ok(()) => {
                ctx.hub
                    .set_info(processor.stream_info(frame_rate, &ctx.spec));
                tracing::info!("configuration reloaded");
            }
            Err(e) => tracing::error!("reload rejected, old configuration kept: {e}"),
        },
        Command::RecordStart { slate, take } => start_take(
            ctx,
            &slate,
            take,
            Box::new(|outcome| {
                if let Err(e) = outcome {
                    tracing::error!("cannot start take: {e}");
                }
            }),
        ),
        Command::RecordStop => stop_take(
            ctx,
            Box::new(|outcome| {
                if let Err(e) = outcome {
                    tracing::warn!("{e}");
                }
            }),
        ),
    }
}

/// Starts a take; `done` gets the reply once the writer thread has the file open.
fn start_take<R>(ctx: &mut Context<R>, slate: &str, take: Option<u32>, done: TakeReply) {
    let hub = ctx.hub.clone();
    let hub_at_end = ctx.hub.clone();
    ctx.takes.start(
        slate,
        take,
        &ctx.spec,
        Box::new(move |started| match started {
            Ok(info) => {
                let file = info.path.display().to_string();
                let recording = Recording {
                    slate: info.slate.clone(),
                    take: info.take,
                    file: Some(file.clone()),
                    started_wall_us: Some(mouthpiece_takes::unix_us(info.started)),
                };
                hub.update_status(|s| {
                    s.recording = Some(recording);
                    if s.message
                        .as_deref()
                        .is_some_and(|m| m.starts_with("take stopped"))
                    {
                        s.message = None;
                    }
                });
                done(Ok(
                    json!({ "slate": info.slate, "take": info.take, "file": file }),
                ));
            }
            Err(e) => done(Err(e)),
        }),
        Box::new(move |ended| announce_take_end(&hub_at_end, ended)),
    );
}

/// Stops the take; `done` gets the reply once it is closed and synced.
fn stop_take<R>(ctx: &mut Context<R>, done: TakeReply) {
    ctx.takes.stop(Box::new(move |ended| {
        done(ended.map(|ended| {
            let info = ended.info.as_ref();
            json!({
                "slate": info.map(|i| i.slate.clone()),
                "take": info.map(|i| i.take),
                "file": info.map(|i| i.path.display().to_string()),
                "frames": ended.frames,
                "dropped": ended.dropped,
            })
        }))
    }));
}

/// A take ended: clear `recording` (unless a newer take is already recording) and say why
/// when it stopped by itself.
fn announce_take_end(hub: &Hub, ended: &TakeEnded) {
    // A take whose file was never created has nothing to list.
    if let Some(info) = &ended.info {
        hub.add_take(mouthpiece_server::TakeSummary {
            slate: info.slate.clone(),
            take: info.take,
            file: info.path.display().to_string(),
            frames: ended.frames,
            seconds: info.started.elapsed().map_or(0.0, |d| d.as_secs_f64()),
            error: ended.error.clone(),
        });
    }
    let message = ended.error.as_ref().map(|e| format!("take stopped: {e}"));
    let file = ended.info.as_ref().map(|i| i.path.display().to_string());
    hub.update_status(|s| {
        let this_take = match (&s.recording, &file) {
            (Some(recording), Some(file)) => recording.file.as_deref() == Some(file.as_str()),
            _ => true,
        };
        if this_take {
            s.recording = None;
        }
        if message.is_some() {
            s.message = message;
        }
    });
}

/// The frame's derived channels for the take (allocates; only while recording).
fn derive(
    names: &[String],
    info: &StreamInfo,
    out: &Output,
    seq: u64,
    wall_us: i64,
    clock: &TimecodeClock,
) -> Derived {
    let stream = &out.stream;
    let stabilised = match &stream.performer {
        Some(p) => names
            .iter()
            .zip(p.points.iter().zip(&p.confidence))
            .map(|(n, (pt, c))| (n.clone(), pt.map(f64::from), f64::from(*c)))
            .collect(),
        None => Vec::new(),
    };
    Derived {
        seq,
        t: stream.t,
        wall_us,
        // The published frame's clock (time of day or the studio's LTC).
        timecode: clock.timecode_at(wall_us).to_string(),
        performer: names
            .iter()
            .cloned()
            .zip(out.performer_camera.iter().copied())
            .collect(),
        stabilised,
        head: stream.head,
        characters: stream
            .characters
            .iter()
            .map(|c| {
                let point_names = info
                    .characters
                    .iter()
                    .find(|i| i.name == c.name)
                    .map(|i| i.points.clone());
                CharacterRecord {
                    name: c.name.clone(),
                    points: c
                        .points
                        .iter()
                        .enumerate()
                        .map(|(i, p)| {
                            let name = point_names
                                .as_ref()
                                .and_then(|n| n.get(i).cloned())
                                .unwrap_or_else(|| format!("P{}", i + 1));
                            (name, *p)
                        })
                        .collect(),
                    confidence: c.confidence.clone(),
                    curve: c.curve.clone(),
                    head: c.head,
                    rig: c.rig,
                    source: c.source,
                }
            })
            .collect(),
        status: json!({
            "calibrating": out.flags.calibrating,
            "head_lost": out.flags.head_lost,
            "dots_missing": out.flags.dots_missing,
            "no_dots": out.flags.no_dots,
        }),
    }
}
