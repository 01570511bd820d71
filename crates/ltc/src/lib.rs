//! SMPTE linear timecode (LTC) carried on an audio line: a safe decoder and encoder over
//! libltc (`ltc-sys`).
//!
//! [`Decoder`] takes one channel's 16-bit samples, numbered from the start of the stream, and
//! yields each LTC frame it finds with the sample at which the frame ended: the moment the
//! frame's label was true. Frames whose digits are not a timecode (a BCD digit above 9, a
//! field out of range, a frame number the rate does not have) are refused and counted, so
//! noise that happens to contain a sync word is not mistaken for time. So are frames whose
//! length is not the rate's (within [`SPEED_TOLERANCE`]): LTC at another rate than the one
//! configured (25 fps read as 30) would otherwise look like valid labels.
//!
//! [`Encoder`] writes LTC as audio, as a timecode generator would (used by the tests and by
//! anyone who wants to check a booth's wiring).
//!
//! [`ChannelDecoder`] reads one channel of an interleaved stream that may stop and start
//! again, stamping each frame with the wall-clock time it ended at.
//!
//! Rates: 23.976 and 24 (film, 24 labels a second), 25, 29.97 drop-frame and 30.

use std::ptr::NonNull;

pub mod channel;
pub use channel::ChannelDecoder;

use ltc_sys as sys;

/// An LTC rate: the real frame rate and whether labels are counted drop-frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LtcRate {
    /// Real frames per second (24000/1001 for 23.976).
    pub fps: f64,
    /// Labels per second: the `FF` field counts 0..nominal.
    pub nominal: u8,
    /// Drop-frame counting (29.97): labels 0 and 1 skipped each minute but every tenth.
    pub drop_frame: bool,
}

impl LtcRate {
    /// The rates LTC is decoded at, as (real fps, drop-frame); `None` for others.
    pub fn new(fps: f64, drop_frame: bool) -> Option<LtcRate> {
        let nominal = fps.ceil();
        let known = [
            (24_000.0 / 1001.0, false),
            (24.0, false),
            (25.0, false),
            (30_000.0 / 1001.0, true),
            (30.0, false),
        ];
        known
            .iter()
            .any(|(f, df)| (f - fps).abs() < 1e-6 && *df == drop_frame)
            .then_some(LtcRate {
                fps,
                nominal: nominal as u8,
                drop_frame,
            })
    }

    /// libltc's binary-group-flag assignment for the rate.
    fn standard(self) -> sys::LTC_TV_STANDARD {
        match self.nominal {
            25 => sys::LTC_TV_STANDARD::LTC_TV_625_50,
            24 => sys::LTC_TV_STANDARD::LTC_TV_FILM_24,
            _ => sys::LTC_TV_STANDARD::LTC_TV_525_60,
        }
    }
}

/// A timecode label as LTC carries it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Label {
    pub hours: u8,
    pub minutes: u8,
    pub seconds: u8,
    pub frames: u8,
    /// The frame's drop-frame flag.
    pub drop_frame: bool,
}

impl Label {
    /// Whether the label exists at `rate`: fields in range, and not a label drop-frame
    /// counting skips.
    pub fn valid_at(&self, rate: LtcRate) -> bool {
        if self.hours >= 24 || self.minutes >= 60 || self.seconds >= 60 {
            return false;
        }
        if self.frames >= rate.nominal {
            return false;
        }
        if self.drop_frame != rate.drop_frame {
            return false;
        }
        // Drop-frame skips labels 0 and 1 at the start of every minute but every tenth.
        !(rate.drop_frame
            && self.seconds == 0
            && self.frames < 2
            && !self.minutes.is_multiple_of(10))
    }
}

impl std::fmt::Display for Label {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let sep = if self.drop_frame { ';' } else { ':' };
        write!(
            f,
            "{:02}:{:02}:{:02}{sep}{:02}",
            self.hours, self.minutes, self.seconds, self.frames
        )
    }
}

/// One LTC frame found in the audio.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Decoded {
    pub label: Label,
    /// The sample (counted from the stream's first) at which the frame began.
    pub start_sample: u64,
    /// The sample at which the frame ended (its last bit): the next frame starts here.
    pub end_sample: u64,
    /// Played backwards (a tape rewinding): the label is right but time runs the other way.
    pub reverse: bool,
    /// Signal level of the frame, dBFS.
    pub volume_dbfs: f64,
}

/// Decodes LTC from one channel of audio.
pub struct Decoder {
    raw: NonNull<sys::LTCDecoder>,
    rate: LtcRate,
    /// Samples one frame lasts at the rate.
    frame_samples: f64,
    /// Frames found whose digits are not a timecode at the rate.
    refused: u64,
    scratch: Vec<i16>,
}

// The decoder is plain memory owned by this value; libltc keeps no global state.
unsafe impl Send for Decoder {}

/// How far a frame's length may be from the rate's: 2 %, so 24 and 25 fps (4 % apart) are
/// told apart while a generator a little off speed still reads.
pub const SPEED_TOLERANCE: f64 = 0.02;

/// Frames libltc may hold between two reads; more are dropped by libltc.
const QUEUE_FRAMES: i32 = 32;

impl Decoder {
    /// A decoder for audio at `sample_rate` carrying LTC at `rate`.
    pub fn new(sample_rate: u32, rate: LtcRate) -> Decoder {
        // Audio samples per LTC frame: libltc's starting guess, it tracks the real speed.
        let apv = (f64::from(sample_rate) / rate.fps).round() as i32;
        // SAFETY: plain constructor; a null return is an allocation failure.
        let raw = unsafe { sys::ltc_decoder_create(apv.max(1), QUEUE_FRAMES) };
        let raw = NonNull::new(raw).expect("libltc could not allocate a decoder");
        Decoder {
            raw,
            rate,
            frame_samples: f64::from(sample_rate) / rate.fps,
            refused: 0,
            scratch: Vec::new(),
        }
    }

    /// Frames found whose digits were not a timecode at the rate (noise, a wrong rate).
    pub fn refused(&self) -> u64 {
        self.refused
    }

    /// Feeds `samples` of one channel, the first being sample `first_sample` of the stream,
    /// and appends the frames that ended in them to `out`.
    pub fn write(&mut self, samples: &[i16], first_sample: u64, out: &mut Vec<Decoded>) {
        self.scratch.clear();
        self.scratch.extend_from_slice(samples);
        // SAFETY: the decoder is ours; libltc reads `size` samples from the buffer (it takes
        // `short *` but does not write to it).
        unsafe {
            sys::ltc_decoder_write_s16(
                self.raw.as_ptr(),
                self.scratch.as_mut_ptr(),
                self.scratch.len(),
                first_sample as sys::ltc_off_t,
            );
        }
        let mut ext = sys::LTCFrameExt::default();
        // SAFETY: `ext` is a valid out-parameter for one frame.
        while unsafe { sys::ltc_decoder_read(self.raw.as_ptr(), &mut ext) } != 0 {
            let Some(label) = label_of(&ext.ltc) else {
                self.refused += 1;
                continue;
            };
            let length = (ext.off_end - ext.off_start + 1) as f64;
            let speed_ok = (length / self.frame_samples - 1.0).abs() <= SPEED_TOLERANCE;
            if !label.valid_at(self.rate) || ext.off_end < 0 || ext.off_start < 0 || !speed_ok {
                self.refused += 1;
                continue;
            }
            out.push(Decoded {
                label,
                start_sample: ext.off_start as u64,
                end_sample: ext.off_end as u64,
                reverse: ext.reverse != 0,
                volume_dbfs: ext.volume,
            });
        }
    }
}

impl Drop for Decoder {
    fn drop(&mut self) {
        // SAFETY: created by ltc_decoder_create, freed once.
        unsafe {
            sys::ltc_decoder_free(self.raw.as_ptr());
        }
    }
}

/// The label in an LTC frame's BCD fields; `None` when a digit is not a decimal digit.
fn label_of(frame: &sys::LTCFrame) -> Option<Label> {
    let digit = |tens: u32, units: u32| (units <= 9).then(|| (tens * 10 + units) as u8);
    Some(Label {
        hours: digit(frame.hours_tens(), frame.hours_units())?,
        minutes: digit(frame.mins_tens(), frame.mins_units())?,
        seconds: digit(frame.secs_tens(), frame.secs_units())?,
        frames: digit(frame.frame_tens(), frame.frame_units())?,
        drop_frame: frame.dfbit() != 0,
    })
}

/// Writes LTC as audio.
pub struct Encoder {
    raw: NonNull<sys::LTCEncoder>,
    rate: LtcRate,
}

// Plain memory owned by this value, like the decoder.
unsafe impl Send for Encoder {}

impl Encoder {
    /// An encoder writing `rate` at `sample_rate`, starting at `start`, at −3 dBFS.
    pub fn new(sample_rate: u32, rate: LtcRate, start: Label) -> Encoder {
        let flags = sys::LTC_BG_FLAGS::LTC_TC_CLOCK.0 as i32;
        // SAFETY: plain constructor; null is an allocation failure.
        let raw = unsafe {
            sys::ltc_encoder_create(f64::from(sample_rate), rate.fps, rate.standard(), flags)
        };
        let raw = NonNull::new(raw).expect("libltc could not allocate an encoder");
        let mut encoder = Encoder { raw, rate };
        encoder.set_label(start);
        encoder
    }

    /// Continues from `label` (a jump in the timecode).
    pub fn set_label(&mut self, label: Label) {
        let mut tc = sys::SMPTETimecode {
            hours: label.hours,
            mins: label.minutes,
            secs: label.seconds,
            frame: label.frames,
            ..Default::default()
        };
        tc.timezone[..5].copy_from_slice(&[b'+' as _, b'0' as _, b'0' as _, b'0' as _, b'0' as _]);
        // SAFETY: the encoder is ours; `tc` and `frame` are valid for the calls.
        unsafe {
            sys::ltc_encoder_set_timecode(self.raw.as_ptr(), &mut tc);
            // The drop-frame flag decides how libltc counts labels on.
            let mut frame = sys::LTCFrame::default();
            sys::ltc_encoder_get_frame(self.raw.as_ptr(), &mut frame);
            frame.set_dfbit(u32::from(self.rate.drop_frame));
            sys::ltc_frame_set_parity(&mut frame, self.rate.standard());
            sys::ltc_encoder_set_frame(self.raw.as_ptr(), &mut frame);
        }
    }

    /// The label the next [`Encoder::frame`] writes.
    pub fn label(&self) -> Label {
        let mut frame = sys::LTCFrame::default();
        // SAFETY: the encoder is ours; `frame` is a valid out-parameter.
        unsafe { sys::ltc_encoder_get_frame(self.raw.as_ptr(), &mut frame) };
        label_of(&frame).expect("the encoder holds a valid label")
    }

    /// Appends one LTC frame of audio (16-bit) to `out` and moves on to the next label.
    pub fn frame(&mut self, out: &mut Vec<i16>) {
        // SAFETY: the encoder is ours; the buffer pointer returned stays valid until the next
        // encoder call, and `len` samples of it are written.
        unsafe {
            sys::ltc_encoder_encode_frame(self.raw.as_ptr());
            let mut buf: *mut sys::ltcsnd_sample_t = std::ptr::null_mut();
            let len = sys::ltc_encoder_get_bufferptr(self.raw.as_ptr(), &mut buf, 1);
            if len > 0 && !buf.is_null() {
                let samples = std::slice::from_raw_parts(buf, len as usize);
                // libltc writes unsigned 8-bit samples centred on 128.
                out.extend(samples.iter().map(|&s| (i16::from(s) - 128) * 256));
            }
            sys::ltc_encoder_inc_timecode(self.raw.as_ptr());
        }
    }
}

impl Drop for Encoder {
    fn drop(&mut self) {
        // SAFETY: created by ltc_encoder_create, freed once.
        unsafe { sys::ltc_encoder_free(self.raw.as_ptr()) };
    }
}

#[cfg(test)]
mod tests;
