//! Learning profiles from speech whose phone timing is known: every analysis window of the
//! sound labelled with the class of the phone at its centre (silence outside the phones),
//! then [`Profiles::learn`]. The shipped profiles are made this way from Festival's voice;
//! `mouthpiece lipsync learn` makes a booth's own from its actor's recordings.

use super::features::{Feature, FeatureExtractor, SAMPLE_RATES};
use super::profiles::Profiles;
use crate::{ClassTable, Error, PhoneSpan};

/// Classes with fewer learning frames than this get no profile.
pub const MIN_FRAMES: u64 = 20;

/// One recording: mono samples at `rate` and its phones (times in seconds from sample 0).
pub struct Recording<'a> {
    pub samples: &'a [i16],
    pub rate: u32,
    pub phones: &'a [PhoneSpan],
    /// Names the recording in errors.
    pub name: &'a str,
}

/// The class of the phone holding `t` (silence between and outside the phones).
fn class_at(phones: &[PhoneSpan], classes: &[usize], silence: usize, t: f64) -> usize {
    let i = phones.partition_point(|p| p.end <= t);
    match phones.get(i) {
        Some(p) if p.start <= t => classes[i],
        // Past the last phone: its class, as the phone files' last silence runs on.
        None if !phones.is_empty() => classes[phones.len() - 1],
        _ => silence,
    }
}

/// The features of a recording, each labelled with the class at its window's centre. A
/// phone the table does not know or a rate outside [`SAMPLE_RATES`] is an error naming the
/// recording.
pub fn labelled_features(
    table: &ClassTable,
    recording: &Recording<'_>,
) -> Result<Vec<(Feature, usize)>, Error> {
    if !(SAMPLE_RATES.0..=SAMPLE_RATES.1).contains(&recording.rate) {
        return Err(Error::Setting {
            what: format!(
                "{}: {} Hz; live profiles are learned from {} to {} Hz",
                recording.name, recording.rate, SAMPLE_RATES.0, SAMPLE_RATES.1
            ),
        });
    }
    let classes = table.classify(recording.phones, recording.name)?;
    let mut fx = FeatureExtractor::new(recording.rate);
    let half = fx.window_len() as f64 / 2.0;
    let rate = f64::from(recording.rate);
    let mut out = Vec::with_capacity(recording.samples.len() / fx.hop().max(1) + 1);
    for (i, s) in recording.samples.iter().enumerate() {
        if let Some(f) = fx.push(*s) {
            let centre = (i as f64 + 1.0 - half) / rate;
            out.push((
                f,
                class_at(recording.phones, &classes, table.silence(), centre),
            ));
        }
    }
    Ok(out)
}

/// Profiles learned from recordings with known phone timing.
pub fn learn_from_recordings(
    table: &ClassTable,
    recordings: &[Recording<'_>],
    learned_on: &str,
) -> Result<Profiles, Error> {
    let mut labelled = Vec::new();
    for r in recordings {
        labelled.extend(labelled_features(table, r)?);
    }
    Ok(Profiles::learn(table, &labelled, MIN_FRAMES, learned_on))
}
