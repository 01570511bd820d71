//! The one error type of this crate.

use std::io;
use std::path::PathBuf;

/// Everything that can go wrong while reading a mesh, binding it or writing the result.
///
/// [`BindError::is_bad_input`] tells the user's mistakes (a mesh that cannot be bound, a
/// character that does not fit it) from the machine's (disk full).
#[derive(Debug, thiserror::Error)]
pub enum BindError {
    /// The mesh file cannot be read.
    #[error("reading the mesh {}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        cause: io::Error,
    },
    /// The mesh file is larger than the binder accepts.
    #[error("{}: more than the {limit} bytes a mesh may have", path.display())]
    TooLarge { path: PathBuf, limit: u64 },
    /// The file is not glTF/GLB, or its JSON does not parse.
    #[error("{}: not a glTF/GLB file: {problem}", path.display())]
    NotGltf { path: PathBuf, problem: String },
    /// The glTF parses but its mesh cannot be used (what and where is in `problem`).
    #[error("{}: {problem}", path.display())]
    BadMesh { path: PathBuf, problem: String },
    /// The mesh's geometry cannot be bound (no triangles, non-manifold edges, …).
    #[error("the mesh cannot be bound: {0}")]
    Geometry(String),
    /// A mouth point lies far from every vertex of the mesh.
    #[error(
        "{}mouth point {name} is {distance:.4} from the mesh's surface, more than {limit:.4} \
         ({fraction} of the mouth width): is the mesh in the character's model frame and units? \
         (the mesh spans {extent:.4}, the mouth is {width:.4} wide)",
        mesh.as_ref().map_or(String::new(), |p| format!("{}: ", p.display()))
    )]
    PointFarFromMesh {
        /// The mesh file, when the mesh came from one.
        mesh: Option<PathBuf>,
        name: String,
        distance: f64,
        limit: f64,
        fraction: f64,
        /// The mesh's bounding box's longest side and the mouth's width (character units),
        /// which tell a mesh in other units at a glance.
        extent: f64,
        width: f64,
    },
    /// The character file cannot be loaded.
    #[error(transparent)]
    Character(#[from] mouthpiece_export::ExportError),
    /// A model file (trained network weights) is malformed.
    #[error("{}: not a network weights file: {problem}", path.display())]
    BadModel { path: PathBuf, problem: String },
    /// A rigged glTF given to be animated lacks what a `mouthpiece bind` output has.
    #[error("{}: not a rig written by `mouthpiece bind`: {problem}", path.display())]
    BadRig { path: PathBuf, problem: String },
    /// An invalid argument (a count of zero, a non-finite number).
    #[error("{0}")]
    BadArgument(String),
    /// A network weights file cannot be read.
    #[error("reading the model {}", path.display())]
    ReadModel {
        path: PathBuf,
        #[source]
        cause: io::Error,
    },
    /// The character does not have the twelve mouth points binding needs.
    #[error("{}: the character has {points} mouth points; binding needs the 12 points P1…P12", path.display())]
    NotTwelvePoints { path: PathBuf, points: usize },
    /// The character's mouth corners do not lie apart.
    #[error("{}: the mouth's width is {width}: its corners must lie apart along x", path.display())]
    NoMouthWidth { path: PathBuf, width: f64 },
    #[error("--heads {heads} is more than the {max} procedural heads allowed")]
    TooManyHeads { heads: usize, max: usize },
    #[error("seed {seed} is the held-out heads' seed")]
    HeldOutSeed { seed: u64 },
    #[error("--rate must be a positive number")]
    Rate,
    #[error("give one --snout per --character ({characters} characters, {snouts} snouts)")]
    SnoutCount { characters: usize, snouts: usize },
    #[error("--snout number {number} is {snout}: it must be in 0…1")]
    Snout { number: usize, snout: f64 },
    /// Writing an output failed.
    #[error("writing {}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        cause: io::Error,
    },
}

impl BindError {
    /// True when the user's input is wrong (exit code 2), false for the machine's failures.
    pub fn is_bad_input(&self) -> bool {
        match self {
            Self::Read { .. } | Self::Write { .. } => false,
            Self::Character(e) => e.is_bad_input(),
            _ => true,
        }
    }
}
