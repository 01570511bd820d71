//! Reading sessions: [`MessageReader`] (every message, in file order) and [`SessionReader`]
//! (frames with calibration and ground truth, seeking, looping).
//!
//! Both stream the file through mcap's sans-io linear reader with chunk CRCs checked before a
//! chunk's messages are released, so a file cut at any byte yields exactly the messages of its
//! complete chunks; the cut is logged as a warning, not returned as an error.

mod frames;
mod messages;

pub use frames::{SessionFrame, SessionReader};
pub use messages::{MessageReader, RawMessage};
