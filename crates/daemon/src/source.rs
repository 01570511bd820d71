//! The source thread: opens the configured source, hands every frame to the latest-frame
//! slot, and when the source fails or ends reports it down and reopens it with exponential
//! backoff, for as long as the daemon runs.
//!
//! It owns the source (native libraries such as OpenNI2 want one thread per handle) and
//! never waits for processing: [`LatestSlot::put`] replaces an untaken frame.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mouthpiece_frame::{Frame, FrameSource, SourceError, SourceInfo};

use crate::backoff::Backoff;
use crate::slot::LatestSlot;
use mouthpiece_output::Throttle;

/// Opens the source; called again after every loss.
pub type Opener = Box<dyn FnMut() -> Result<Box<dyn FrameSource>, SourceError> + Send>;

/// What the source thread last reported.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceState {
    /// Not opened yet.
    Starting,
    /// Open; frames flow.
    Up(SourceInfo),
    /// Absent, failed or ended; retried after `retry_in`.
    Down { reason: String, retry_in: Duration },
}

/// Shared between the source thread and its readers.
#[derive(Debug)]
pub struct SourceShared {
    pub frames: LatestSlot<Frame>,
    state: Mutex<SourceState>,
    /// Bumped on every state change, so readers notice changes cheaply.
    generation: AtomicU64,
    stop: AtomicBool,
}

impl SourceShared {
    pub fn new() -> Arc<Self> {
        Arc::new(SourceShared {
            frames: LatestSlot::new(),
            state: Mutex::new(SourceState::Starting),
            generation: AtomicU64::new(0),
            stop: AtomicBool::new(false),
        })
    }

    /// The state and its generation.
    pub fn state(&self) -> (u64, SourceState) {
        let state = self.state.lock().unwrap_or_else(|p| p.into_inner()).clone();
        (self.generation.load(Ordering::Acquire), state)
    }

    pub fn generation(&self) -> u64 {
        self.generation.load(Ordering::Acquire)
    }

    fn set_state(&self, state: SourceState) {
        let mut current = self.state.lock().unwrap_or_else(|p| p.into_inner());
        if *current != state {
            *current = state;
            self.generation.fetch_add(1, Ordering::AcqRel);
        }
    }

    /// Asks the source thread to stop after the frame it is waiting for.
    pub fn stop(&self) {
        self.stop.store(true, Ordering::Release);
        self.frames.close();
    }

    pub fn is_stopping(&self) -> bool {
        self.stop.load(Ordering::Acquire)
    }
}

/// Starts the source thread.
pub fn spawn(
    mut open: Opener,
    spec: String,
    shared: Arc<SourceShared>,
    mut backoff: Backoff,
    throttle_interval: Duration,
) -> std::io::Result<JoinHandle<()>> {
    std::thread::Builder::new()
        .name("mouthpiece-source".into())
        .spawn(move || {
            if spec == mouthpiece_config::SourceSpec::NONE {
                // No camera: nothing to open; the thread only waits to be stopped.
                tracing::info!("no camera (source spec none)");
                while !shared.is_stopping() {
                    sleep_unless_stopped(&shared, Duration::from_secs(1));
                }
                return;
            }
            let mut open_failures = Throttle::new(throttle_interval);
            while !shared.is_stopping() {
                // A panic in a source (a library bug, arithmetic on a crafted file) is a
                // source failure like any other: reported down, retried with backoff.
                let opened = catch_panic(&mut open).unwrap_or_else(|panic| {
                    Err(SourceError::Open {
                        spec: spec.clone(),
                        message: format!("the source panicked while opening: {panic}"),
                        cause: None,
                    })
                });
                let reason = match opened {
                    Ok(mut source) => {
                        let info = source.info().clone();
                        tracing::info!(spec = %info.spec, description = %info.description,
                        width = info.color_width, height = info.color_height, fps = info.fps,
                        "source open");
                        shared.set_state(SourceState::Up(info));
                        open_failures.reset();
                        let (reason, delivered) = catch_panic(|| pump(&mut *source, &shared))
                            .unwrap_or_else(|panic| {
                                tracing::error!(%spec, "source panicked: {panic}");
                                (Some(format!("the source panicked: {panic}")), false)
                            });
                        if delivered {
                            backoff.reset();
                        }
                        drop(source);
                        match reason {
                            Some(reason) => reason,
                            None => break, // stopping
                        }
                    }
                    Err(err) => {
                        let reason = error_chain(&err);
                        if let Some(held_back) = open_failures.allow(Instant::now()) {
                            tracing::warn!(%spec, held_back, "cannot open source: {reason}");
                        }
                        reason
                    }
                };
                let retry_in = backoff.next_delay();
                shared.set_state(SourceState::Down { reason, retry_in });
                sleep_unless_stopped(&shared, retry_in);
            }
            tracing::info!(%spec, "source thread stopped");
        })
}

/// Moves frames into the slot until the source fails, ends or the daemon stops. Returns why
/// it stopped (`None`: the daemon stops) and whether any frame came through.
fn pump(source: &mut dyn FrameSource, shared: &SourceShared) -> (Option<String>, bool) {
    let mut delivered = false;
    loop {
        if shared.is_stopping() {
            return (None, delivered);
        }
        match source.next_frame() {
            Ok(Some(frame)) => {
                tracing::trace!(
                    seq = frame.seq,
                    device_ts_us = frame.device_ts_us,
                    "frame in"
                );
                delivered = true;
                shared.frames.put(frame);
            }
            Ok(None) => {
                tracing::info!(spec = %source.info().spec, "source ended");
                return (Some("the source ended".into()), delivered);
            }
            Err(err) => {
                let reason = error_chain(&err);
                tracing::warn!(spec = %source.info().spec, "source lost: {reason}");
                return (Some(reason), delivered);
            }
        }
    }
}

fn sleep_unless_stopped(shared: &SourceShared, total: Duration) {
    let until = Instant::now() + total;
    while !shared.is_stopping() {
        let now = Instant::now();
        if now >= until {
            break;
        }
        std::thread::sleep((until - now).min(Duration::from_millis(50)));
    }
}

pub use mouthpiece_output::{catch_panic, error_chain, panic_message};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::slot::Taken;
    use mouthpiece_frame::{Calibration, ColorImage, DepthImage, Intrinsics};
    use std::collections::VecDeque;

    /// A scripted source for the supervisor's logic: `Some(n)` frames then an error.
    struct Scripted {
        info: SourceInfo,
        frames_left: u32,
        seq: u64,
    }

    impl FrameSource for Scripted {
        fn info(&self) -> &SourceInfo {
            &self.info
        }
        fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
            std::thread::sleep(Duration::from_millis(2));
            if self.frames_left == 0 {
                return Err(SourceError::Disconnected {
                    spec: self.info.spec.clone(),
                    message: "unplugged".into(),
                    cause: None,
                });
            }
            self.frames_left -= 1;
            self.seq += 1;
            Ok(Some(Frame {
                seq: self.seq,
                device_ts_us: self.seq * 33_000,
                host_rx: Instant::now(),
                wall_clock: None,
                color: ColorImage::new(4, 4),
                depth: DepthImage::new(4, 4),
                calibration: Arc::new(Calibration::registered(Intrinsics::ideal(
                    4, 4, 4.0, 4.0, 2.0, 2.0,
                ))),
            }))
        }
    }

    /// A source whose reads panic, like a library bug or overflowing arithmetic would.
    struct Panicky(SourceInfo);

    impl FrameSource for Panicky {
        fn info(&self) -> &SourceInfo {
            &self.0
        }
        fn next_frame(&mut self) -> Result<Option<Frame>, SourceError> {
            panic!("cannot convert float seconds to Duration: value is too big");
        }
    }

    #[test]
    fn a_panicking_source_is_reported_down_and_reopened() {
        let mut attempt = 0;
        let opener: Opener = Box::new(move || {
            attempt += 1;
            match attempt {
                1 => panic!("open exploded"),
                2 => Ok(Box::new(Panicky(info())) as Box<dyn FrameSource>),
                _ => Ok(Box::new(Scripted {
                    info: info(),
                    frames_left: 100_000,
                    seq: 0,
                })),
            }
        });
        let (frames, seen_down) = run_until_frames(opener, "test:panicky", 5);
        assert!(frames >= 5, "frames flow after the panics ({frames})");
        assert!(
            seen_down
                .iter()
                .any(|r| r.contains("panicked while opening: open exploded")),
            "{seen_down:?}"
        );
        assert!(
            seen_down
                .iter()
                .any(|r| r.contains("panicked: cannot convert")),
            "{seen_down:?}"
        );
    }

    /// Runs a source thread over `opener` until `want` frames arrived (or 60 s passed) and
    /// returns the frames seen and every `Down` reason reported on the way.
    fn run_until_frames(opener: Opener, spec: &str, want: usize) -> (usize, Vec<String>) {
        // Each reopen waits until the test has seen the `Down` before it: on a loaded machine
        // the next `Down` could otherwise replace one the test never saw.
        let downs_seen = Arc::new((std::sync::Mutex::new(0usize), std::sync::Condvar::new()));
        let gate = downs_seen.clone();
        let mut inner = opener;
        let mut attempts = 0usize;
        let opener: Opener = Box::new(move || {
            if attempts > 0 {
                let (count, changed) = &*gate;
                let count = count.lock().unwrap();
                let _ = changed
                    .wait_timeout_while(count, Duration::from_secs(30), |c| *c < attempts)
                    .unwrap();
            }
            attempts += 1;
            inner()
        });
        let shared = SourceShared::new();
        let ms = Duration::from_millis;
        let thread = spawn(
            opener,
            spec.into(),
            shared.clone(),
            Backoff::new(ms(10), ms(40)),
            ms(1000),
        )
        .unwrap();
        let mut seen_down = Vec::new();
        let mut frames = 0;
        let mut generation = 0;
        let deadline = Instant::now() + Duration::from_secs(60);
        while frames < want && Instant::now() < deadline {
            if let Taken::Value(_) = shared.frames.take_timeout(ms(5)) {
                frames += 1;
            }
            let (g, state) = shared.state();
            if g != generation {
                generation = g;
                if let SourceState::Down { reason, .. } = state {
                    seen_down.push(reason);
                    let (count, changed) = &*downs_seen;
                    *count.lock().unwrap() += 1;
                    changed.notify_all();
                }
            }
        }
        shared.stop();
        thread
            .join()
            .expect("the source thread survives its source's failures and panics");
        (frames, seen_down)
    }

    fn info() -> SourceInfo {
        SourceInfo {
            spec: "test:scripted".into(),
            description: "scripted".into(),
            color_width: 4,
            color_height: 4,
            depth_width: 4,
            depth_height: 4,
            fps: 30.0,
            live: true,
        }
    }

    #[test]
    fn a_failing_source_goes_down_and_comes_back() {
        // Attempt 1 fails to open, attempt 2 gives 3 frames then fails, attempt 3 fails to
        // open, attempt 4 streams for long.
        let mut script: VecDeque<Option<u32>> = [None, Some(3), None, Some(100_000)].into();
        let opener: Opener = Box::new(move || match script.pop_front().flatten() {
            Some(frames_left) => Ok(Box::new(Scripted {
                info: info(),
                frames_left,
                seq: 0,
            })),
            None => Err(SourceError::Open {
                spec: "test:scripted".into(),
                message: "no device".into(),
                cause: None,
            }),
        });
        let (frames, seen_down) = run_until_frames(opener, "test:scripted", 20);
        assert!(
            frames >= 20,
            "frames flowed again after the failures ({frames})"
        );
        assert!(
            seen_down.iter().any(|r| r.contains("no device")),
            "{seen_down:?}"
        );
        assert!(
            seen_down.iter().any(|r| r.contains("unplugged")),
            "{seen_down:?}"
        );
    }
}
