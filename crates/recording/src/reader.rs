//! Reading sessions: [`MessageReader`] (every message, in file order) and [`SessionReader`]
//! (frames with calibration and ground truth, seeking, looping), [`AudioReader`] (`/audio`).
//!
//! Both stream the file through mcap's sans-io linear reader with chunk CRCs checked before a
//! chunk's messages are released, so a file cut at any byte yields exactly the messages of its
//! complete chunks; the cut is logged as a warning, not returned as an error.

mod audio;
mod frames;
mod messages;

pub use audio::{AudioMessage, AudioReader, MAX_AUDIO_CHANNELS, MAX_AUDIO_RATE};
pub use frames::{SessionFrame, SessionReader};
pub use messages::{MessageReader, RawMessage};
