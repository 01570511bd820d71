//! `mouthpiece export` of a recording with sound: the take's `/audio` as a Broadcast WAV
//! beside the glTF/CSV (same name, `.wav`). Sample 0 is the first exported frame's time (the
//! recording's first frame: `process` turns every frame into one exported frame); the `bext`
//! time reference is that instant as samples since midnight UTC, the clock of the take's
//! SMPTE time-of-day timecode. The file is written aside and moved into place only once the
//! animation is written too.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context as _};
use mouthpiece_export::{write_bwf, BextInfo, PendingFile, Timeline, MAX_WAV_DATA_BYTES};
use mouthpiece_recording::AudioReader;

use mouthpiece_server::Timecode;

use crate::cmd::export::take_error;
use crate::exit::{bad_input, bad_input_if};

/// A WAV written aside, to be moved into place with [`PreparedWav::commit`].
pub struct PreparedWav {
    pub path: PathBuf,
    file: PendingFile,
    pub summary: String,
}

impl PreparedWav {
    pub fn commit(self) -> anyhow::Result<PathBuf> {
        self.file
            .commit()
            .with_context(|| format!("cannot write {}", self.path.display()))?;
        eprintln!("wrote {}: {}", self.path.display(), self.summary);
        Ok(self.path)
    }
}

fn recording_error(err: mouthpiece_recording::RecordingError) -> anyhow::Error {
    let bad = err.is_bad_input();
    bad_input_if(bad, err)
}

/// The WAV of `recording`'s sound for an export to `out`; `None` when it has no sound.
pub fn prepare(recording: &Path, out: &Path) -> anyhow::Result<Option<PreparedWav>> {
    // The input named on the command line cannot be opened: the user's to fix (exit 2).
    let mut audio = AudioReader::open(recording).map_err(|e| bad_input(anyhow::Error::new(e)))?;
    let Some(first_audio) = audio.next_audio().map_err(recording_error)? else {
        return Ok(None);
    };
    // The frames' times (no image is decoded) and the take's metadata.
    let (span, take) = mouthpiece_takes::read::frame_span(recording).map_err(take_error)?;
    let Some(span) = span else {
        return Err(bad_input(anyhow!("{}: no frames", recording.display())));
    };
    let (start, last_frame, frames) = (span.first_ns, span.last_ns, span.frames);
    let period = if frames > 1 {
        (last_frame - start) / (frames - 1)
    } else {
        0
    };
    let format = first_audio.format;
    let span_ns = u128::from(last_frame - start + period);
    let len = (span_ns * u128::from(format.sample_rate)).div_ceil(1_000_000_000);
    let bytes = len * u128::from(format.channels) * 2;
    if bytes > u128::from(MAX_WAV_DATA_BYTES) {
        return Err(bad_input(anyhow!(
            "{}: the take's {:.0} s of {}-channel sound at {} Hz do not fit in a WAV file ({} bytes, at most {MAX_WAV_DATA_BYTES})",
            recording.display(),
            span_ns as f64 / 1e9,
            format.channels,
            format.sample_rate,
            bytes
        )));
    }
    let mut timeline = Timeline::new(format.sample_rate, format.channels, start, len as u64);
    let mut blocks = 0u64;
    let mut skipped = 0u64;
    let mut message = Some(first_audio);
    while let Some(m) = message {
        if m.format == format {
            timeline.place(m.log_time, &m.samples);
            blocks += 1;
        } else {
            skipped += 1;
        }
        message = audio.next_audio().map_err(recording_error)?;
    }
    if skipped > 0 {
        tracing::warn!(
            skipped,
            "sound in another format than the first block's ({} Hz, {} ch) left out of the WAV",
            format.sample_rate,
            format.channels
        );
    }
    let start_us = (start / 1000) as i64;
    let rate = take.as_ref().and_then(|t| t.rate()).unwrap_or_default();
    let of_day = Timecode::from_unix_micros(start_us, rate);
    const DAY_US: u64 = 86_400 * 1_000_000;
    let us_of_day = (start / 1000) % DAY_US;
    // The take's own timecode wins: when the booth followed the studio's LTC, the first frame
    // went out with the LTC's label, not the time of day, and sample 0 is placed there (at
    // the start of that frame). Otherwise the time of day, to the microsecond.
    let recorded = span
        .first_label
        .as_deref()
        .and_then(mouthpiece_takes::read::parse_timecode_label)
        .and_then(|tc| Some((tc, tc.to_frame_count(rate)?)))
        .filter(|(tc, _)| tc.to_string() != of_day.to_string());
    let (timecode, time_reference) = match recorded {
        Some((tc, frame)) => {
            let (num, den) = rate.fraction();
            let samples = u128::from(frame) * u128::from(den) * u128::from(format.sample_rate)
                / u128::from(num);
            (tc, samples as u64)
        }
        None => (
            of_day,
            (u128::from(us_of_day) * u128::from(format.sample_rate) / 1_000_000) as u64,
        ),
    };
    let name = match take {
        Some(take) => format!("{} take {}", take.slate, take.take),
        None => recording
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
    };
    let (date, time) = utc_date_time(start_us);
    let bext = BextInfo {
        description: format!(
            "mouthpiece {name}; sample 0 = first frame, timecode {timecode} ({} fps)",
            rate.name()
        ),
        origination_date: date,
        origination_time: time,
        time_reference,
    };
    let path = out.with_extension("wav");
    let mut file = PendingFile::create(&path)
        .with_context(|| format!("cannot create {}", path.display()))
        .map_err(bad_input)?;
    write_bwf(
        &mut file,
        format.sample_rate,
        format.channels,
        &bext,
        &timeline.samples,
    )
    .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(Some(PreparedWav {
        path,
        file,
        summary: format!(
            "{:.2} s of sound, {} Hz, {} ch, {blocks} blocks; starts at timecode {timecode} (bext time reference {time_reference})",
            len as f64 / f64::from(format.sample_rate),
            format.sample_rate,
            format.channels
        ),
    }))
}

/// `yyyy-mm-dd` and `hh-mm-ss` (UTC) of Unix microseconds.
fn utc_date_time(unix_us: i64) -> (String, String) {
    let secs = unix_us.div_euclid(1_000_000);
    let days = secs.div_euclid(86_400);
    let rem = secs.rem_euclid(86_400);
    // Civil from days (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    (
        format!("{y:04}-{m:02}-{d:02}"),
        format!("{:02}-{:02}-{:02}", rem / 3600, rem / 60 % 60, rem % 60),
    )
}

#[cfg(test)]
mod tests {
    #[test]
    fn dates_are_utc_civil_dates() {
        assert_eq!(
            super::utc_date_time(1_795_316_645_000_000),
            ("2026-11-22".into(), "03-04-05".into())
        );
        assert_eq!(
            super::utc_date_time(951_782_400_000_000),
            ("2000-02-29".into(), "00-00-00".into())
        );
    }
}
