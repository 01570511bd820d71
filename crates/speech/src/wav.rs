//! WAV input: the first channel, converted to the model's 16 kHz 16-bit samples.
//!
//! Resampling (when the file is not 16 kHz) is a windowed-sinc interpolator (Hann window, 16
//! zero crossings each side, cut-off at the lower Nyquist frequency). It is written here, 40
//! lines, rather than taken from a resampling crate because speech recognition needs nothing
//! more than a clean low-pass, and it keeps the dependency tree to `hound`.

use std::f64::consts::PI;
use std::io::Read;

use crate::{Error, MODEL_RATE};

/// Longest accepted audio, seconds (a line of dialogue is seconds, a scene minutes):
/// alignment runs at about 40× real time, phone recognition below real time, and the first
/// channel is held as 4 bytes a sample (460 MB for 10 minutes at 192 kHz).
pub const MAX_SECONDS: f64 = 600.0;
/// Accepted sample rates, Hz: telephone speech to studio masters. Below, there is no speech
/// band to recognise (and upsampling a 1 Hz file to 16 kHz costs 16 000 outputs a sample);
/// above, no recorder.
pub const RATES: (u32, u32) = (8_000, 192_000);

/// Reads a WAV stream (`path` names it in errors) → first channel at 16 kHz, `i16`. The
/// header's rate and length are checked ([`RATES`], [`MAX_SECONDS`]) before any sample is
/// read; nothing is sized by the header.
pub fn read_16k<R: Read>(reader: R, path: &str) -> Result<Vec<i16>, Error> {
    let wav = |source| Error::Wav {
        path: path.to_string(),
        source,
    };
    let mut r = hound::WavReader::new(reader).map_err(wav)?;
    let spec = r.spec();
    let channels = spec.channels.max(1) as usize;
    if !(RATES.0..=RATES.1).contains(&spec.sample_rate) {
        return Err(Error::BadAudio {
            path: path.into(),
            what: format!(
                "sample rate {} Hz is outside {} to {} Hz",
                spec.sample_rate, RATES.0, RATES.1
            ),
        });
    }
    let seconds = r.duration() as f64 / spec.sample_rate as f64;
    if seconds > MAX_SECONDS {
        return Err(Error::BadAudio {
            path: path.into(),
            what: format!(
                "{seconds:.1} s of audio (as its header says), longer than {MAX_SECONDS} s: \
                 split it into lines or scenes"
            ),
        });
    }
    // Grown as samples arrive: a header may claim more than the file holds.
    let mut first: Vec<f32> = Vec::new();
    match spec.sample_format {
        hound::SampleFormat::Float => {
            for (i, s) in r.samples::<f32>().enumerate() {
                let s = s.map_err(wav)?;
                if i % channels == 0 {
                    first.push(if s.is_finite() {
                        s.clamp(-1.0, 1.0)
                    } else {
                        0.0
                    });
                }
            }
        }
        hound::SampleFormat::Int => {
            let scale = 1.0 / (1u64 << (spec.bits_per_sample.clamp(1, 32) - 1)) as f64;
            for (i, s) in r.samples::<i32>().enumerate() {
                let s = s.map_err(wav)?;
                if i % channels == 0 {
                    first.push((s as f64 * scale) as f32);
                }
            }
        }
    }
    if first.is_empty() {
        return Err(Error::BadAudio {
            path: path.into(),
            what: "no samples".into(),
        });
    }
    let resampled = if spec.sample_rate == MODEL_RATE {
        first.iter().map(|&x| f64::from(x)).collect()
    } else {
        resample(&first, spec.sample_rate as f64, MODEL_RATE as f64)
    };
    Ok(resampled
        .iter()
        .map(|&x| (x * 32767.0).round().clamp(-32768.0, 32767.0) as i16)
        .collect())
}

/// Windowed-sinc resampling of `x` from `from` Hz to `to` Hz.
pub fn resample(x: &[f32], from: f64, to: f64) -> Vec<f64> {
    const ZEROS: f64 = 16.0;
    let ratio = to / from;
    let cutoff = ratio.min(1.0); // fraction of the input Nyquist frequency kept
    let half = (ZEROS / cutoff).ceil() as i64;
    let n_out = ((x.len() as f64) * ratio).floor() as usize;
    let mut out = Vec::with_capacity(n_out);
    for k in 0..n_out {
        let centre = k as f64 / ratio;
        let c = centre.floor() as i64;
        let mut acc = 0.0;
        for j in (c - half + 1)..=(c + half) {
            if j < 0 || j as usize >= x.len() {
                continue;
            }
            let d = centre - j as f64;
            let arg = d * cutoff;
            let sinc = if arg.abs() < 1e-12 {
                1.0
            } else {
                (PI * arg).sin() / (PI * arg)
            };
            let w = 0.5 + 0.5 * (PI * d / (half as f64)).cos();
            if d.abs() < half as f64 {
                acc += f64::from(x[j as usize]) * cutoff * sinc * w;
            }
        }
        out.push(acc);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sine(rate: f64, hz: f64, n: usize) -> Vec<f32> {
        (0..n)
            .map(|i| 0.5 * (2.0 * PI * hz * i as f64 / rate).sin() as f32)
            .collect()
    }

    #[test]
    fn resampling_keeps_a_tone_and_removes_aliases() {
        // 1 kHz survives 44.1 kHz → 16 kHz; 12 kHz (above the new Nyquist) is removed.
        let kept = resample(&sine(44_100.0, 1000.0, 44_100), 44_100.0, 16_000.0);
        let expect = sine(16_000.0, 1000.0, kept.len());
        let err = kept[200..kept.len() - 200]
            .iter()
            .zip(&expect[200..])
            .map(|(a, b)| (a - f64::from(*b)).abs())
            .fold(0.0, f64::max);
        assert!(err < 0.01, "tone error {err}");
        let gone = resample(&sine(44_100.0, 12_000.0, 44_100), 44_100.0, 16_000.0);
        let rms = (gone[200..gone.len() - 200]
            .iter()
            .map(|v| v * v)
            .sum::<f64>()
            / (gone.len() - 400) as f64)
            .sqrt();
        assert!(rms < 0.01, "alias rms {rms}");
    }

    #[test]
    fn reads_first_channel_of_a_stereo_8k_file_and_rejects_garbage() {
        let mut buf = std::io::Cursor::new(Vec::new());
        let spec = hound::WavSpec {
            channels: 2,
            sample_rate: 8000,
            bits_per_sample: 16,
            sample_format: hound::SampleFormat::Int,
        };
        let mut w = hound::WavWriter::new(&mut buf, spec).unwrap();
        for i in 0..8000 {
            let s = (16000.0 * (2.0 * PI * 440.0 * i as f64 / 8000.0).sin()) as i16;
            w.write_sample(s).unwrap();
            w.write_sample(0i16).unwrap();
        }
        w.finalize().unwrap();
        let samples = read_16k(std::io::Cursor::new(buf.into_inner()), "t.wav").unwrap();
        assert_eq!(samples.len(), 16000);
        let peak = samples[100..15900].iter().map(|s| s.abs()).max().unwrap();
        assert!((15000..17000).contains(&peak), "peak {peak}");
        let err = read_16k(std::io::Cursor::new(b"RIFF nonsense".to_vec()), "bad.wav").unwrap_err();
        assert!(err.to_string().starts_with("bad.wav: "), "{err}");
    }

    /// A WAV header: PCM, `channels`, `rate`, 16 bits, with a data chunk claiming `data_len`
    /// bytes (followed by `body`).
    fn header(channels: u16, rate: u32, data_len: u32, body: &[u8]) -> Vec<u8> {
        let mut v = b"RIFF".to_vec();
        v.extend((36 + data_len).to_le_bytes());
        v.extend(b"WAVEfmt ");
        v.extend(16u32.to_le_bytes());
        v.extend(1u16.to_le_bytes());
        v.extend(channels.to_le_bytes());
        v.extend(rate.to_le_bytes());
        v.extend(rate.wrapping_mul(2 * u32::from(channels)).to_le_bytes());
        v.extend((2 * channels).to_le_bytes());
        v.extend(16u16.to_le_bytes());
        v.extend(b"data");
        v.extend(data_len.to_le_bytes());
        v.extend(body);
        v
    }

    #[test]
    fn headers_claiming_gigabytes_or_absurd_rates_are_refused_before_reading() {
        // 4 GiB at 2 GHz is one second: it used to size a 17 GB buffer (abort).
        let err = read_16k(
            std::io::Cursor::new(header(1, 2_000_000_000, u32::MAX - 63, &[0; 64])),
            "big.wav",
        )
        .unwrap_err();
        assert!(
            err.to_string()
                .contains("big.wav: sample rate 2000000000 Hz is outside"),
            "{err}"
        );
        // 4 GiB at 16 kHz: 37 hours.
        let err = read_16k(
            std::io::Cursor::new(header(1, 16_000, u32::MAX - 63, &[0; 64])),
            "long.wav",
        )
        .unwrap_err();
        assert!(err.to_string().contains("longer than 600 s"), "{err}");
        // An hour at 1 Hz: 57.6 million outputs of 32 taps each (a hang).
        let err = read_16k(
            std::io::Cursor::new(header(1, 1, 7200, &[0; 7200])),
            "slow.wav",
        )
        .unwrap_err();
        assert!(
            err.to_string().contains("slow.wav: sample rate 1 Hz"),
            "{err}"
        );
        // Within the limits, a header claiming more than there is reads what there is or
        // fails naming the file; nothing is sized by the claim.
        let r = read_16k(
            std::io::Cursor::new(header(1, 16_000, 16_000 * 2 * 500, &[0; 3200])),
            "short.wav",
        );
        match r {
            Ok(s) => assert!(s.len() <= 1600),
            Err(e) => assert!(e.to_string().starts_with("short.wav: "), "{e}"),
        }
    }
}
