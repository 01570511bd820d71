//! The booth's microphone through ALSA (`libasound`, via the `alsa` crate), as an
//! [`AudioSource`].
//!
//! Opened in capture direction with interleaved read access; asks for the configured rate,
//! channels, period and buffer, and reads back what the device agreed to (the delivered
//! blocks carry that format, never the one asked for). Samples come as S16_LE; a device that
//! only offers S32_LE or FLOAT_LE (JACK's ALSA plugin, some USB interfaces) is converted to
//! 16 bits, and one offering none of the three is refused with an error that lists what it
//! offers. Overruns (EPIPE: the thread was late and the device's buffer filled) are recovered
//! from and counted; the lost stretch shows as a jump of `first_frame`. A device that
//! delivers nothing for `stall_timeout` (a stopped clock, a server gone) is reported lost.

use std::time::{Duration, Instant};

use alsa::pcm::{Access, Format, HwParams, PCM};
use alsa::{Direction, ValueOr};
use mouthpiece_frame::{AudioBlock, AudioFormat, AudioSource, AudioSourceInfo, SourceError};

/// What to ask the device for.
#[derive(Debug, Clone, PartialEq)]
pub struct AlsaRequest {
    /// ALSA PCM name.
    pub device: String,
    pub sample_rate: u32,
    pub channels: u16,
    pub period_frames: u32,
    pub buffer_frames: u32,
    /// No sound for this long from an open device: lost.
    pub stall_timeout: Duration,
}

/// How the device's samples become 16-bit ones.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Sample {
    S16,
    S32,
    F32,
}

/// An open ALSA capture PCM.
pub struct AlsaSource {
    pcm: PCM,
    info: AudioSourceInfo,
    sample: Sample,
    stall_timeout: Duration,
    seq: u64,
    frames_read: u64,
    overruns: u64,
    /// Estimated host time of sample frame 0: the earliest `receipt − duration so far` seen,
    /// allowed to creep forward 100 ppm so it follows a device clock slower than the host's.
    anchor: Option<Instant>,
    buf_s32: Vec<i32>,
    buf_f32: Vec<f32>,
}

fn alsa_error(spec: &str, what: &str, err: alsa::Error) -> SourceError {
    SourceError::Open {
        spec: spec.to_owned(),
        message: format!("{what}: {err}"),
        cause: Some(Box::new(err)),
    }
}

impl AlsaSource {
    /// Opens, configures and starts the device.
    pub fn open(request: &AlsaRequest) -> Result<AlsaSource, SourceError> {
        let spec = request.device.clone();
        let pcm = PCM::new(&request.device, Direction::Capture, false)
            .map_err(|e| alsa_error(&spec, "cannot open the ALSA capture device", e))?;
        let sample;
        {
            let hw = HwParams::any(&pcm)
                .map_err(|e| alsa_error(&spec, "cannot read the device's parameters", e))?;
            hw.set_access(Access::RWInterleaved)
                .map_err(|e| alsa_error(&spec, "interleaved read access refused", e))?;
            sample = choose_format(&hw).map_err(|e| match e {
                FormatChoice::Set(e) => alsa_error(&spec, "sample format refused", e),
                FormatChoice::NoneRead { offered } => SourceError::Format {
                    spec: spec.clone(),
                    message: format!(
                        "the device offers none of the sample formats mouthpiece reads (S16_LE, S32_LE, FLOAT_LE); it offers {offered}"
                    ),
                    cause: None,
                },
            })?;
            hw.set_channels_near(u32::from(request.channels))
                .map_err(|e| alsa_error(&spec, "no channel count near the one asked for", e))?;
            hw.set_rate_near(request.sample_rate, ValueOr::Nearest)
                .map_err(|e| alsa_error(&spec, "no sample rate near the one asked for", e))?;
            hw.set_period_size_near(request.period_frames as alsa::pcm::Frames, ValueOr::Nearest)
                .map_err(|e| alsa_error(&spec, "period size refused", e))?;
            hw.set_buffer_size_near(request.buffer_frames as alsa::pcm::Frames)
                .map_err(|e| alsa_error(&spec, "buffer size refused", e))?;
            pcm.hw_params(&hw)
                .map_err(|e| alsa_error(&spec, "the device refused the parameters", e))?;
        }
        // What the device agreed to, read back.
        let (rate, channels, period, buffer, format) = {
            let hw = pcm
                .hw_params_current()
                .map_err(|e| alsa_error(&spec, "cannot read back the agreed parameters", e))?;
            let get = |r: alsa::Result<u32>| {
                r.map_err(|e| alsa_error(&spec, "cannot read back the agreed parameters", e))
            };
            (
                get(hw.get_rate())?,
                get(hw.get_channels())?,
                hw.get_period_size()
                    .map_err(|e| alsa_error(&spec, "cannot read back the period", e))?,
                hw.get_buffer_size()
                    .map_err(|e| alsa_error(&spec, "cannot read back the buffer", e))?,
                hw.get_format()
                    .map_err(|e| alsa_error(&spec, "cannot read back the format", e))?,
            )
        };
        if !(1..=192_000 * 4).contains(&rate) || !(1..=256).contains(&channels) || period <= 0 {
            return Err(SourceError::Format {
                spec,
                message: format!(
                    "the device agreed to an unusable format: {rate} Hz, {channels} channels, period {period}"
                ),
                cause: None,
            });
        }
        if rate != request.sample_rate || channels != u32::from(request.channels) {
            tracing::warn!(
                device = %spec,
                asked_rate = request.sample_rate,
                rate,
                asked_channels = request.channels,
                channels,
                "the audio device agreed to another format than asked; using what it delivers"
            );
        }
        let info = AudioSourceInfo {
            spec: spec.clone(),
            description: format!(
                "ALSA {spec}: {rate} Hz, {channels} ch, {format:?}{}, period {period}, buffer {buffer}",
                if sample == Sample::S16 { "" } else { " (converted to S16)" }
            ),
            format: AudioFormat {
                sample_rate: rate,
                channels: channels as u16,
            },
            frames_per_block: period as u32,
            live: true,
        };
        // Capture starts now (a read would start it too, but the wait before it would not).
        pcm.start()
            .map_err(|e| alsa_error(&spec, "the device would not start capturing", e))?;
        tracing::info!(device = %spec, description = %info.description, "audio device open");
        Ok(AlsaSource {
            pcm,
            info,
            sample,
            stall_timeout: request.stall_timeout,
            seq: 0,
            frames_read: 0,
            overruns: 0,
            anchor: None,
            buf_s32: Vec::new(),
            buf_f32: Vec::new(),
        })
    }

    fn lost(&self, message: String, cause: Option<alsa::Error>) -> SourceError {
        SourceError::Disconnected {
            spec: self.info.spec.clone(),
            message,
            cause: cause.map(|c| Box::new(c) as Box<dyn std::error::Error + Send + Sync>),
        }
    }

    /// Reads up to one period into `out` (interleaved i16); returns sample frames read.
    fn read(&mut self, out: &mut [i16]) -> alsa::Result<usize> {
        match self.sample {
            Sample::S16 => self.pcm.io_i16()?.readi(out),
            Sample::S32 => {
                self.buf_s32.resize(out.len(), 0);
                let n = self.pcm.io_i32()?.readi(&mut self.buf_s32)?;
                for (o, s) in out.iter_mut().zip(&self.buf_s32) {
                    *o = (s >> 16) as i16;
                }
                Ok(n)
            }
            Sample::F32 => {
                self.buf_f32.resize(out.len(), 0.0);
                let n = self.pcm.io_f32()?.readi(&mut self.buf_f32)?;
                for (o, s) in out.iter_mut().zip(&self.buf_f32) {
                    let v = if s.is_finite() { *s } else { 0.0 };
                    *o = (v * 32768.0).round().clamp(-32768.0, 32767.0) as i16;
                }
                Ok(n)
            }
        }
    }
}

/// Why no sample format was set.
enum FormatChoice {
    /// The device refused the format it offered.
    Set(alsa::Error),
    /// None of those read is offered; `offered`: those that are, in words.
    NoneRead { offered: String },
}

/// S16 if offered, else S32, else FLOAT (converted); the offered formats in words otherwise.
fn choose_format(hw: &HwParams) -> Result<Sample, FormatChoice> {
    for (format, sample) in [
        (Format::s16(), Sample::S16),
        (Format::s32(), Sample::S32),
        (Format::float(), Sample::F32),
    ] {
        if hw.test_format(format).is_ok() {
            hw.set_format(format).map_err(FormatChoice::Set)?;
            return Ok(sample);
        }
    }
    let offered: Vec<String> = [
        Format::U8,
        Format::S8,
        Format::S24LE,
        Format::S243LE,
        Format::U16LE,
        Format::S16BE,
        Format::FloatBE,
        Format::Float64LE,
        Format::MuLaw,
        Format::ALaw,
    ]
    .into_iter()
    .filter(|f| hw.test_format(*f).is_ok())
    .map(|f| format!("{f:?}"))
    .collect();
    Err(FormatChoice::NoneRead {
        offered: if offered.is_empty() {
            "no format mouthpiece knows".to_owned()
        } else {
            offered.join(", ")
        },
    })
}

impl AudioSource for AlsaSource {
    fn info(&self) -> &AudioSourceInfo {
        &self.info
    }

    fn next_block(&mut self) -> Result<Option<AudioBlock>, SourceError> {
        let format = self.info.format;
        let channels = usize::from(format.channels);
        let mut samples = vec![0i16; self.info.frames_per_block as usize * channels];
        let started = Instant::now();
        loop {
            // Wait with a timeout, so that a device whose clock stopped is noticed.
            let waited_ms = started.elapsed().as_millis() as u32;
            let left = (self.stall_timeout.as_millis() as u32).saturating_sub(waited_ms);
            if left == 0 {
                return Err(self.lost(
                    format!("no sound for {:.1} s", self.stall_timeout.as_secs_f64()),
                    None,
                ));
            }
            match self.pcm.wait(Some(left.min(250))) {
                Ok(false) => continue,
                Ok(true) => {}
                Err(e) if self.recover(&e) => continue,
                Err(e) => return Err(self.lost("the device failed".into(), Some(e))),
            }
            match self.read(&mut samples) {
                Ok(0) => continue,
                Ok(frames) => {
                    samples.truncate(frames * channels);
                    let now = Instant::now();
                    let first_frame = self.frames_read;
                    self.frames_read += frames as u64;
                    let since_start = format.duration_of(self.frames_read);
                    let estimate = now.checked_sub(since_start).unwrap_or(now);
                    let anchor = match self.anchor {
                        None => estimate,
                        Some(a) => {
                            let creep = format.duration_of(frames as u64) / 10_000;
                            (a + creep).min(estimate)
                        }
                    };
                    self.anchor = Some(anchor);
                    let block = AudioBlock {
                        seq: self.seq,
                        first_frame,
                        format,
                        samples,
                        host_rx: anchor + since_start,
                        wall_clock: None,
                    };
                    self.seq += 1;
                    return Ok(Some(block));
                }
                Err(e) if self.recover(&e) => {
                    // The buffer overflowed while we were late: the lost stretch is skipped
                    // in `first_frame` (estimated from the host clock).
                    if let Some(anchor) = self.anchor {
                        let due = anchor.elapsed().as_secs_f64() * f64::from(format.sample_rate);
                        self.frames_read = self.frames_read.max(due as u64);
                    }
                    continue;
                }
                Err(e) => return Err(self.lost("reading the device failed".into(), Some(e))),
            }
        }
    }

    fn overruns(&self) -> u64 {
        self.overruns
    }
}

impl AlsaSource {
    /// Recovers from an overrun (EPIPE) or a suspend (ESTRPIPE); false for anything else.
    fn recover(&mut self, err: &alsa::Error) -> bool {
        let errno = err.errno();
        if errno != libc::EPIPE && errno != libc::ESTRPIPE {
            return false;
        }
        if self.pcm.try_recover(*err, true).is_err() {
            return false;
        }
        if errno == libc::EPIPE {
            self.overruns += 1;
            tracing::warn!(device = %self.info.spec, overruns = self.overruns, "audio overrun (xrun): recovered");
        }
        // Capture does not start by itself after `prepare`.
        let _ = self.pcm.start();
        true
    }
}
