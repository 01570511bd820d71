//! `mouthpiece export` of a recording with sound: the take's `/audio` as a Broadcast WAV
//! beside the glTF/CSV (same name, `.wav`). Sample 0 is the first exported frame's time (the
//! recording's first frame: `process` turns every frame into one exported frame); the `bext`
//! time reference is that instant as samples since midnight UTC, the clock of the take's
//! SMPTE time-of-day timecode. The file is written aside and moved into place only once the
//! animation is written too.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context as _};
use mouthpiece_export::{write_bwf, BextInfo, PendingFile, Timeline, MAX_WAV_DATA_BYTES};
use mouthpiece_recording::{AudioReader, MessageReader, TOPIC_COLOR};

use mouthpiece_server::{Timecode, TimecodeRate};

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
    let mut messages = MessageReader::open(recording).map_err(recording_error)?;
    // A take from a booth without a camera has no images: its frames are the steps of
    // its (first) character.
    let (mut first_frame, mut last_frame, mut frames) = (None, 0u64, 0u64);
    let mut steps: (Option<u64>, u64, u64) = (None, 0, 0);
    let mut step_topic: Option<String> = None;
    // The timecode the first frame was published with (`/head` is stamped with every frame).
    let mut first_label: Option<String> = None;
    while let Some(m) = messages.next_message().map_err(recording_error)? {
        if first_label.is_none() && &*m.topic == "/head" && m.data.len() < 1 << 20 {
            first_label = serde_json::from_slice::<serde_json::Value>(&m.data)
                .ok()
                .and_then(|v| v["timecode"].as_str().map(str::to_owned));
        }
        if &*m.topic == TOPIC_COLOR {
            first_frame.get_or_insert(m.log_time);
            last_frame = last_frame.max(m.log_time);
            frames += 1;
        } else if m.topic.starts_with("/character/")
            && step_topic.get_or_insert_with(|| m.topic.to_string()) == &*m.topic
        {
            steps.0.get_or_insert(m.log_time);
            steps.1 = steps.1.max(m.log_time);
            steps.2 += 1;
        }
    }
    if first_frame.is_none() {
        (first_frame, last_frame, frames) = steps;
    }
    let Some(start) = first_frame else {
        return Err(bad_input(anyhow!("{}: no frames", recording.display())));
    };
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
    let meta = |name: &str, key: &str| -> Option<String> {
        messages
            .metadata()
            .iter()
            .find(|(n, _)| n == name)
            .and_then(|(_, m)| m.get(key).cloned())
    };
    let start_us = (start / 1000) as i64;
    let rate = meta("mouthpiece.take", "timecode_rate")
        .and_then(|r| TimecodeRate::ALL.into_iter().find(|t| t.name() == r))
        .unwrap_or_default();
    let of_day = Timecode::from_unix_micros(start_us, rate);
    const DAY_US: u64 = 86_400 * 1_000_000;
    let us_of_day = (start / 1000) % DAY_US;
    // The take's own timecode wins: when the booth followed the studio's LTC, the first frame
    // went out with the LTC's label, not the time of day, and sample 0 is placed there (at
    // the start of that frame). Otherwise the time of day, to the microsecond.
    let recorded = first_label
        .as_deref()
        .and_then(parse_label)
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
    let name = match (
        meta("mouthpiece.take", "slate"),
        meta("mouthpiece.take", "take"),
    ) {
        (Some(slate), Some(take)) => format!("{slate} take {take}"),
        _ => recording
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
/// A timecode label `HH:MM:SS:FF` (`;` before the frames: drop-frame) as recorded in a take.
fn parse_label(label: &str) -> Option<Timecode> {
    let b = label.as_bytes();
    if b.len() != 11 || b[2] != b':' || b[5] != b':' || !(b[8] == b':' || b[8] == b';') {
        return None;
    }
    let field = |i: usize| -> Option<u8> { label.get(i..i + 2)?.parse().ok() };
    Some(Timecode {
        hours: field(0)?,
        minutes: field(3)?,
        seconds: field(6)?,
        frames: field(9)?,
        drop_frame: b[8] == b';',
    })
}

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
    fn recorded_labels_parse_and_junk_does_not() {
        let tc = super::parse_label("10:20:30;04").unwrap();
        assert_eq!(
            (tc.hours, tc.minutes, tc.seconds, tc.frames),
            (10, 20, 30, 4)
        );
        assert!(tc.drop_frame);
        for junk in [
            "",
            "10:20:30",
            "1x:20:30:04",
            "10-20-30-04",
            "10:20:30:04\n",
        ] {
            assert!(super::parse_label(junk).is_none(), "{junk:?}");
        }
    }

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
