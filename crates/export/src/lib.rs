//! mouthpiece-export: a take as keyframe animation (docs/method.md §9).
//!
//! A take is the stream `mouthpiece retarget` or `mouthpiece process` writes: one JSON line
//! per time step with the character's mouth points in its mouth frame. This crate turns it
//! into what animators load: glTF 2.0 (`.gltf` + `.bin`, embedded `.gltf`, or `.glb`) with
//! one translation channel per point, or CSV.
//!
//! # Layout
//! - [`take`]: the streaming, checking JSONL reader → [`TakeFrame`]s.
//! - [`rig`]: the [`MouthRig`], the points' names, rest pose and the mouth's placement in the
//!   character's model.
//! - [`gltf`]: the streaming [`GltfWriter`]: keys spool to temporary files, the document is
//!   assembled at the end. Memory is constant in the number of frames.
//! - [`reduce`]: the [`Reducer`], streaming key reduction within a tolerance.
//! - [`csv`]: the streaming [`CsvWriter`].
//! - [`livelink_csv`]: the streaming [`LiveLinkCsvWriter`], Live Link Face's CSV take layout.
//! - [`onto_rig`]: a take's animation copied onto a rigged mesh (`export --rig`).
//! - [`onto`]: a take's curves as morph-target weights on the user's avatar (`export --onto`).
//! - [`play`]: the [`PlayClock`], when each frame of a take is due when it is played.
//! - [`asset`]: files a glTF names, read only from its own folder; bounded reads.
//!
//! The writers take frames from any source, so a recording turned into frames by the
//! processing pipeline feeds them the same way as a JSONL file.

pub mod asset;
pub mod csv;
mod error;
pub mod gltf;
pub mod livelink_csv;
pub mod onto;
pub mod onto_rig;
mod output;
pub mod play;
pub mod reduce;
pub mod retarget_files;
pub mod rig;
pub mod take;
pub mod wav;

pub use csv::{CsvSummary, CsvWriter};
pub use error::ExportError;
pub use gltf::{GltfLayout, GltfOptions, GltfSummary, GltfWriter, ModelUp};
pub use livelink_csv::{livelink_timecode, LiveLinkCsvWriter, LIVELINK_CSV_COLUMNS};
pub use onto_rig::{animate_rig, RigSummary};
pub use output::PendingFile;
pub use play::PlayClock;
pub use reduce::Reducer;
pub use rig::{MouthRig, RigHead, RigPoint};
pub use take::{HeadKeys, LipKeys, RigKeys, TakeFrame, TakeReader};
pub use wav::{write_bwf, BextInfo, Timeline, MAX_WAV_DATA_BYTES};
