//! Speech-driven lip sync: phones on a timeline → viseme classes → designed segments of
//! basic-pose weight curves → one stitched curve per basic pose → a mouth shape per sample.
//!
//! The method (described in `docs/lipsync.md`):
//! - [`phones`]: phone timing files (TIMIT `.phn`, Praat TextGrid, HTK and Festival labels,
//!   JSONL) read into [`PhoneSpan`]s, checked (times forward, no overlaps), gaps filled with
//!   silence.
//! - [`classes`]: the class table (TOML): every TIMIT and ARPAbet phone → one of 16 classes,
//!   each class with its target weights on the key poses.
//! - [`poses`]: the basic lip poses (TOML): the neutral dots and, per key pose, the 12 lip-dot
//!   displacements in the performer's mouth frame.
//! - [`curve`]: the stage curves (monotone cubic Hermite, flat at both ends).
//! - [`segments`]: the 16 × 16 designed segments A(a, b): a stable stage then a change stage,
//!   generated from the class targets and overridable by control points.
//! - [`mapping`]: segments placed on the phone timeline (stable stage scaled, change stage of
//!   constant length T; short phones start their change stage early).
//! - [`mod@stitch`]: one pass over the placed segments, blending overlaps linearly.
//! - [`take`]: the weight curves → the performer's lip dots → the retarget core → take lines.
//! - [`live`]: the causal analyser: sound blocks → a class and key-pose weights every 10 ms
//!   (MFCC profiles), and the weights → a character's points.
//!
//! No file I/O: everything parses `&str` and writes to a caller's `Write`; the
//! `mouthpiece lipsync` command reads the files and places the take.

pub mod classes;
pub mod curve;
mod error;
pub mod input;
pub mod live;
pub mod mapping;
pub mod phones;
pub mod poses;
pub mod segments;
pub mod stitch;
pub mod take;

pub use classes::ClassTable;
pub use error::Error;
pub use mapping::{map_phones, Placed};
pub use phones::{PhoneFormat, PhoneSpan};
pub use poses::BasicPoses;
pub use segments::{Segment, SegmentTable};
pub use stitch::{stitch, Weights};

/// Default length of the change stage, seconds.
pub const DEFAULT_T_CHANGE: f64 = 0.040;
/// Allowed change-stage lengths, seconds.
pub const T_CHANGE_RANGE: (f64, f64) = (0.030, 0.050);

/// Lowest sample rate accepted, samples per second (below it a phone falls between samples).
pub const MIN_FPS: f64 = 1.0;
/// Highest sample rate accepted, samples per second.
pub const MAX_FPS: f64 = 10_000.0;
/// Most samples one call makes (about 18 hours at 60 per second; 200 MB of weights).
pub const MAX_SAMPLES: f64 = 4_000_000.0;

/// Phones → weight curves sampled at `fps`: classes, mapping and stitching in one call.
/// `source_name` names the phones' source in errors.
pub fn weights_for_phones(
    phones: &[PhoneSpan],
    source_name: &str,
    table: &ClassTable,
    segments: &SegmentTable,
    t_change: f64,
    fps: f64,
) -> Result<Weights, Error> {
    if !(MIN_FPS..=MAX_FPS).contains(&fps) {
        return Err(Error::Setting {
            what: format!(
                "--fps: the sample rate must be within {MIN_FPS} to {MAX_FPS} per second, got {fps}"
            ),
        });
    }
    let end = phones.iter().map(|p| p.end).fold(0.0, f64::max);
    if end * fps > MAX_SAMPLES {
        return Err(Error::Setting {
            what: format!(
                "{source_name}: the phones last {end} s; at {fps} samples per second that is \
                 more than {MAX_SAMPLES} samples"
            ),
        });
    }
    let classes = table.classify(phones, source_name)?;
    let placed = map_phones(phones, &classes, segments, table.silence(), t_change)?;
    Ok(stitch(&placed, segments, fps))
}
