//! mouthpiece's retarget core: the mathematics of `docs/method.md` §2–§8, with no I/O
//! and no async.
//!
//! # Layout
//! - [`character`]: character files (TOML), the character's mouth frame and `P⁰`.
//! - [`layout`]: performer dot names (`D1..DN`, `F1..FK`) and one step's dots.
//! - [`frame`]: the mouth frame (§2).
//! - [`neutral`]: the neutral pose, robust per-dot averages (§3).
//! - [`kabsch`]: rigid alignment with the reflection fix (§4).
//! - [`deform`]: the deformation parameters `M` (§5).
//! - [`retarget`]: the streaming pipeline: [`Stabiliser`] (§4), [`CharacterRetarget`] (§6),
//!   [`Retargeter`] (both).
//! - [`smooth`]: shape smoothing across the points of a step (§8), and [`one_euro`]: the
//!   temporal filter.
//! - [`rig`]: jaw, lip motions and ARKit-named mouth curves (docs/rig.md); [`lip_fill`]:
//!   where the rig measures the lip dots (the unseen ones from the seen, the seen ones with
//!   their depth error along the camera's ray).
//! - [`head`]: the character's head and eyes: reach test, turns by slerp, following the
//!   performer.
//! - [`jsonl`]: the line formats of `mouthpiece retarget` (read by `export`, extended by
//!   `process`).
//!
//! # Use
//! ```
//! use mouthpiece_retarget::{Character, NeutralAccumulator, PerformerDots, Retargeter};
//! # fn demo(toml: &str, neutral_frames: &[PerformerDots], live: &[(f64, PerformerDots)])
//! #     -> Result<(), mouthpiece_retarget::Error> {
//! let character = Character::from_toml_str(toml)?;
//! let mut acc = NeutralAccumulator::new(character.performer_layout());
//! for dots in neutral_frames {
//!     acc.push(dots)?;
//! }
//! let mut retargeter = Retargeter::new(character, acc.finish()?, Default::default())?;
//! for (t, dots) in live {
//!     let out = retargeter.step(*t, dots)?;
//!     let _points = &out.character.points; // the character's mouth, its mouth frame
//! }
//! # Ok(()) }
//! ```

pub mod batch;
pub mod character;
pub mod deform;
mod error;
pub mod frame;
pub mod head;
mod head_file;
mod head_route;
pub mod jsonl;
pub mod kabsch;
pub mod layout;
pub mod lip_fill;
mod named;
pub mod neutral;
pub mod one_euro;
pub mod retarget;
pub mod rig;
pub mod smooth;
mod stabilised;

pub use character::{Character, MMode, Units};
pub use error::Error;
pub use frame::MouthFrame;
pub use head::{HeadConfig, HeadDriver, HeadFrame, LookMode, Reach};
pub use kabsch::RigidTransform;
pub use layout::{DotId, PerformerDots, PerformerLayout};
pub use named::Named;
pub use neutral::{NeutralAccumulator, NeutralPose};
pub use one_euro::{OneEuro, OneEuroGroup, OneEuroParams};
pub use retarget::{
    CharacterRetarget, CharacterSettings, CharacterStep, MissingDots, RetargetConfig,
    RetargetOutput, Retargeter, StabilisedFrame, Stabiliser,
};
pub use rig::{Rig, RigFrame, RigModel, RigSettings};
pub use smooth::{MovingAverageKind, ShapeSmoothing};

/// A 3D vector or point, `f64`.
pub type Vec3 = nalgebra::Vector3<f64>;
