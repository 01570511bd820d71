//! The output vocabulary: what mouthpiece produces per time step, defined once for every
//! place that carries it (the WebSocket protocol and its Foxglove bridge, OSC/VMC, takes,
//! exports, the retarget core's curve list).
//!
//! - [`arkit`]: a character's face as ARKit's 52 blend shapes and head and eye angles (Live
//!   Link Face, iFacialMocap);
//! - [`curves`]: the rig's curve names (ARKit's), in the one order every output uses;
//! - [`rig`]: a character's rig in one frame (jaw, lips, curves), fixed-size;
//! - [`head`]: the performer's head pose and a character's head and eyes;
//! - [`frame`]: one published frame: the performer's head and dots and every character's
//!   points, confidences, curve, rig and head;
//! - [`slate`]: the one rule for naming a take;
//! - [`shown`](mod@shown): how a name from a file or the network is printed (control characters escaped);
//! - [`log`]: how the long-running outputs report trouble (error chains, throttled warnings,
//!   a thread's panic as its message).
//!
//! Plain data with serde; no I/O, no threads, no dependencies beyond serde, so the pure
//! math at the bottom of the workspace and the servers at the top can share it.

pub mod arkit;
pub mod curves;
pub mod frame;
pub mod head;
pub mod log;
pub mod rig;
pub mod shown;
pub mod slate;

pub use arkit::{
    angles_of, arkit_index, ArkitFace, HeadAxes, ARKIT_NAMES, BLENDSHAPES, EYE_LOOK_FULL_SCALE_DEG,
    LIVELINK_NAMES, LIVELINK_VALUES, UNMEASURED,
};
pub use curves::{
    curve_index, pascal_name, visemes_from, CurveNaming, VisemeNaming, CURVES, CURVE_NAMES,
    PASCAL_NAMES, VISEMES, VISEME_NAMES, VISEME_NAMES_VRM0,
};
pub use frame::{CharacterFrame, MouthSource, PerformerFrame, StreamFrame};
pub use head::{CharacterHead, HeadPose, LookMode, RigidPose};
pub use log::{catch_panic, error_chain, panic_message, Throttle, TokenBucket};
pub use rig::{RigCurves, RigJaw, RigLip, RigLips, RigState, RigVisemes};
pub use shown::{shown, shown_message, Shown};
pub use slate::{valid_slate, SLATE_RULE};
