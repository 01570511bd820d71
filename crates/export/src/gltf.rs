//! glTF 2.0 writer: the take as a keyframe animation of the mouth's points.
//!
//! Document: a `mouth` node placed in the character's model by the rig's placement, one child
//! node per point (named as in the character file, at its rest position, optionally with a
//! small marker mesh so viewers show something), and one animation `take` with a LINEAR
//! translation channel per point, keys at the frames' `t`. A take with the rig (docs/rig.md)
//! adds a `jaw` node under `mouth` at the hinge pivot, turning about the hinge axis and
//! sliding along it, and a `blendshapes` node whose mesh has one morph target per ARKit-named
//! curve (`mesh.extras.targetNames`), its `weights` animated with the curves.
//!
//! Memory stays constant in the take's length: each channel's keys go to its own spool file
//! (an anonymous temporary file next to the output) as they arrive; only per-channel counts
//! and bounds stay in memory. At the end the JSON is built from those counts and the binary
//! buffer is assembled by copying the spools, column by column, into the output.

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use gltf_json as json;
use json::validation::{Checked::Valid, USize64};
use serde_json::Value;

use mouthpiece_retarget::rig::{CURVES, CURVE_NAMES};

use crate::output::{parent_dir, PendingFile};
use crate::reduce::{Key, Reducer};
use crate::take::RigKeys;
use crate::{ExportError, MouthRig, TakeFrame};

mod assemble;
mod document;

use assemble::*;
use document::*;

/// How the glTF document and its binary buffer are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GltfLayout {
    /// `NAME.gltf` with the buffer in `NAME.bin` next to it.
    SeparateBin,
    /// `NAME.gltf` with the buffer inside, as a base64 `data:` URI (one file, 4/3 the size).
    Embedded,
    /// `NAME.glb`: binary glTF, JSON and buffer in one file.
    Glb,
}

/// Which way is up in the character's model frame (the frame its file's points are given in).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ModelUp {
    /// +Y up, front +Z: glTF's own convention (and the character file's default `up`).
    #[default]
    Y,
    /// +Z up, front −Y: Blender's and many DCC tools' convention. The export turns it into
    /// glTF's (x, y, z) = (x, z, −y), the same conversion Blender's glTF exporter applies, so
    /// the mouth lands on the artist's model again after import.
    Z,
}

/// What to write.
#[derive(Clone, Debug)]
pub struct GltfOptions {
    pub layout: GltfLayout,
    /// The axis convention of the character's model frame.
    pub model_up: ModelUp,
    /// Drop keys that linear interpolation reproduces within this tolerance (character units,
    /// per axis). `None` keeps every frame.
    pub reduce: Option<f64>,
    /// Also animate the take's smoothed mouth outline (`curve`, written by `retarget
    /// --smooth`): a `curve` node under `mouth` with one child `C0`, `C1`, … per curve point.
    pub curve: bool,
    /// Give each point node a small octahedron (2 % of the mouth width) so viewers show the
    /// points; without it the nodes are empties.
    pub markers: bool,
    /// Write the character's head and eyes (`head`, `eye_L`, `eye_R` nodes with rotation
    /// channels) when the rig has a head and the take carries `character_head`.
    pub head: bool,
    /// Write the performer's rig (the `jaw` node's rotation and translation keys, the
    /// `blendshapes` node's morph-target weights) when the take carries `rig`.
    pub rig: bool,
}

impl Default for GltfOptions {
    fn default() -> Self {
        Self {
            layout: GltfLayout::Glb,
            model_up: ModelUp::Y,
            reduce: None,
            curve: false,
            markers: true,
            head: true,
            rig: true,
        }
    }
}

/// What [`GltfWriter::finish`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct GltfSummary {
    /// Frames read.
    pub frames: u64,
    /// Point samples seen (frames × points, less `null`s).
    pub samples: u64,
    /// Keys written over all channels.
    pub keys: u64,
    /// Samples dropped by `--reduce` (`samples - keys`).
    pub dropped: u64,
    /// Rotation keys of the head and eyes (not in `samples`, `keys`, `dropped`).
    pub rotation_keys: u64,
    /// Frames of the rig written (one jaw rotation, one jaw translation and one set of curve
    /// weights each; frames without `rig` have the jaw at rest and the weights 0); 0 when the
    /// take has no rig.
    pub rig_keys: u64,
    /// Files written: the document, and the `.bin` for [`GltfLayout::SeparateBin`].
    pub files: Vec<PathBuf>,
}

/// Streaming glTF writer: [`push`](Self::push) each frame, then [`finish`](Self::finish).
pub struct GltfWriter {
    rig: MouthRig,
    options: GltfOptions,
    spool_dir: PathBuf,
    /// What error messages call the take (its file name; "take" until set).
    source_name: String,
    /// The points' channels, then the curve's (created at the first line with a curve), then
    /// the head's and the rig's.
    channels: Vec<Channel>,
    /// Rest positions of the curve's points (the first curve's), with `options.curve`.
    curve_rest: Option<Vec<[f64; 3]>>,
    frames: u64,
    /// Every channel has a key at every frame: one time accessor serves them all.
    shared_times: bool,
    /// Index of the head's first rotation channel (then the eyes'), once the first frame
    /// showed that the take has a head.
    head_start: Option<usize>,
    /// Index of the jaw's rotation channel (then its translation, then the weights), with
    /// `options.rig`.
    rig_start: Option<usize>,
    /// Whether any frame had a `rig` (without one the rig's nodes are left out).
    rig_seen: bool,
}

/// What a channel animates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// A point's (or curve point's) translation.
    Point,
    /// The head's or an eye's rotation.
    Head,
    /// The jaw's rotation about the hinge axis.
    JawRotation,
    /// The jaw's translation (pivot plus slide).
    JawTranslation,
    /// The morph-target weights, one per curve.
    Weights,
    /// A lip's rotation (its rigid motion from neutral).
    LipRotation,
    /// A lip's translation, in the character's units.
    LipTranslation,
}

impl Kind {
    fn is_rig(self) -> bool {
        matches!(
            self,
            Kind::JawRotation
                | Kind::JawTranslation
                | Kind::Weights
                | Kind::LipRotation
                | Kind::LipTranslation
        )
    }
}

/// One node's channel while the take streams in: a point's translation (3 values a key) or
/// a head or eye rotation (4: x, y, z, w).
struct Channel {
    spool: BufWriter<File>,
    reducer: Option<Reducer>,
    samples: u64,
    keys: u64,
    t_bounds: Bounds<1>,
    v_bounds: Bounds<4>,
    /// Values per key: 3 (translation), 4 (rotation) or [`CURVES`] (weights).
    width: usize,
    kind: Kind,
    /// The last rotation key, to keep consecutive quaternions in one hemisphere.
    last_rotation: Option<[f32; 4]>,
}

/// Longest spool record: t, then the values (x, y, z (, w), or one weight per curve) as
/// little-endian f32 (what glTF stores).
const RECORD: usize = 4 + 4 * CURVES;

impl Channel {
    fn new(spool_dir: &Path, reduce: Option<f64>) -> Result<Self, ExportError> {
        let file = tempfile::tempfile_in(spool_dir)
            .map_err(|cause| ExportError::write(spool_dir, cause))?;
        Ok(Self {
            spool: BufWriter::with_capacity(16 * 1024, file),
            reducer: reduce.map(Reducer::new),
            samples: 0,
            keys: 0,
            t_bounds: Bounds::new(),
            v_bounds: Bounds::new(),
            width: 3,
            kind: Kind::Point,
            last_rotation: None,
        })
    }

    /// A channel of `width` values a key, never reduced.
    fn unreduced(spool_dir: &Path, kind: Kind, width: usize) -> Result<Self, ExportError> {
        let mut channel = Self::new(spool_dir, None)?;
        channel.kind = kind;
        channel.width = width;
        Ok(channel)
    }

    /// A rotation channel: never reduced (glTF interpolates rotations spherically, which
    /// the reducer's linear test does not model).
    fn rotation(spool_dir: &Path, kind: Kind) -> Result<Self, ExportError> {
        Self::unreduced(spool_dir, kind, 4)
    }

    /// Bytes per spool record.
    fn record_len(&self) -> usize {
        4 + 4 * self.width
    }

    /// Takes one rotation (`[x, y, z, w]`, unit) as a key, in the previous key's hemisphere.
    fn sample_rotation(&mut self, t: f64, q: [f64; 4]) -> io::Result<()> {
        self.samples += 1;
        let mut q32 = q.map(|c| c as f32);
        let norm = q32.iter().map(|c| c * c).sum::<f32>().sqrt();
        q32 = q32.map(|c| c / norm);
        if let Some(last) = self.last_rotation {
            let dot: f32 = last.iter().zip(&q32).map(|(a, b)| a * b).sum();
            if dot < 0.0 {
                q32 = q32.map(|c| -c);
            }
        }
        self.last_rotation = Some(q32);
        self.write_record(t as f32, &q32)
    }

    /// Takes one sample (through the reducer, if any) and spools the key it settles.
    fn sample(&mut self, t: f64, v: [f64; 3]) -> io::Result<()> {
        self.samples += 1;
        let key = match &mut self.reducer {
            Some(reducer) => reducer.push(t, v),
            None => Some((t, v)),
        };
        match key {
            Some(key) => self.write_key(key),
            None => Ok(()),
        }
    }

    fn write_key(&mut self, (t, v): Key) -> io::Result<()> {
        self.write_record(t as f32, &v.map(|c| c as f32))
    }

    fn write_record(&mut self, t32: f32, v32: &[f32]) -> io::Result<()> {
        let mut record = [0u8; RECORD];
        record[0..4].copy_from_slice(&t32.to_le_bytes());
        let mut bounds = [0.0f32; 4];
        for (k, c) in v32.iter().enumerate() {
            record[4 + 4 * k..8 + 4 * k].copy_from_slice(&c.to_le_bytes());
            if let Some(b) = bounds.get_mut(k) {
                *b = *c;
            }
        }
        self.spool.write_all(&record[..4 + 4 * v32.len()])?;
        self.keys += 1;
        self.t_bounds.add(&[t32]);
        if v32.len() <= 4 {
            self.v_bounds.add(&bounds);
        } else {
            // Weights: a SCALAR accessor, one bound over all of them (component 0).
            for &c in v32 {
                self.v_bounds.add(&[c; 4]);
            }
        }
        Ok(())
    }
}

/// Component-wise min/max of f32 values, as accessors declare them.
#[derive(Clone, Copy, Debug)]
struct Bounds<const N: usize> {
    min: [f32; N],
    max: [f32; N],
}

impl<const N: usize> Bounds<N> {
    fn new() -> Self {
        Self {
            min: [f32::INFINITY; N],
            max: [f32::NEG_INFINITY; N],
        }
    }
    fn add(&mut self, v: &[f32; N]) {
        for (k, &c) in v.iter().enumerate() {
            self.min[k] = self.min[k].min(c);
            self.max[k] = self.max[k].max(c);
        }
    }
    /// JSON arrays holding the f32 values exactly (as f64), so validators compare equal.
    fn json(&self) -> (Value, Value) {
        self.json_first(N)
    }

    /// [`Bounds::json`] of the first `n` components.
    fn json_first(&self, n: usize) -> (Value, Value) {
        let arr =
            |a: &[f32; N]| Value::from(a[..n].iter().map(|&c| f64::from(c)).collect::<Vec<_>>());
        (arr(&self.min), arr(&self.max))
    }
}

/// Where a piece of the binary buffer comes from when it is assembled.
enum Piece {
    Bytes(Vec<u8>),
    Times { channel: usize },
    Values { channel: usize },
}

impl GltfWriter {
    /// A writer for `rig`'s points. Spool files go to `spool_dir` (use the output's
    /// directory: same disk as the result, and not a RAM-backed /tmp).
    pub fn new(rig: MouthRig, options: GltfOptions, spool_dir: &Path) -> Result<Self, ExportError> {
        if let Some(tol) = options.reduce {
            if !tol.is_finite() || tol < 0.0 {
                return Err(ExportError::BadTolerance(tol));
            }
        }
        let channels = (0..rig.points().len())
            .map(|_| Channel::new(spool_dir, options.reduce))
            .collect::<Result<Vec<_>, ExportError>>()?;
        Ok(Self {
            source_name: "take".into(),
            curve_rest: None,
            shared_times: options.reduce.is_none(),
            rig,
            options,
            spool_dir: spool_dir.to_path_buf(),
            channels,
            frames: 0,
            head_start: None,
            rig_start: None,
            rig_seen: false,
        })
    }

    /// Names the take in error messages (its file).
    pub fn named(mut self, source_name: impl Into<String>) -> Self {
        self.source_name = source_name.into();
        self
    }

    /// Adds one frame (times strictly increasing, as [`crate::TakeReader`] guarantees).
    pub fn push(&mut self, frame: &TakeFrame) -> Result<(), ExportError> {
        let points = self.rig.points().len();
        if frame.points.len() != points {
            return Err(ExportError::BadRig(format!(
                "line {}: the frame has {} points, the rig {points}",
                frame.line,
                frame.points.len(),
            )));
        }
        let source_name = self.source_name.clone();
        let bad_line = |problem: String| ExportError::BadLine {
            source_name: source_name.clone(),
            line: frame.line,
            problem,
        };
        let in_f32 = |v: &[f64; 3]| v.iter().all(|&c| (c as f32).is_finite());
        for (i, value) in frame.points.iter().enumerate() {
            let Some(v) = *value else {
                self.shared_times = false;
                continue;
            };
            if !in_f32(&v) {
                return Err(bad_line(format!(
                    "point {} = {v:?} is out of the range of glTF's 32-bit floats",
                    self.rig.points()[i].name
                )));
            }
            self.channels[i]
                .sample(frame.t, v)
                .map_err(|cause| ExportError::write(&self.spool_dir, cause))?;
        }
        if self.options.curve {
            let Some(curve) = &frame.curve else {
                return Err(bad_line(
                    "no `curve` on this line: the take was made without shape smoothing \
                     (retarget --smooth); export without --curve"
                        .into(),
                ));
            };
            // A `process` line before the neutral pose has an empty curve: no keys there.
            if curve.is_empty() {
                self.shared_times = false;
            } else {
                match &self.curve_rest {
                    None => {
                        // After the points' channels, before the head's and the rig's.
                        let points = self.rig.points().len();
                        for k in 0..curve.len() {
                            let channel = Channel::new(&self.spool_dir, self.options.reduce)?;
                            self.channels.insert(points + k, channel);
                        }
                        for start in [&mut self.head_start, &mut self.rig_start]
                            .into_iter()
                            .flatten()
                        {
                            *start += curve.len();
                        }
                        if self.frames > 0 {
                            self.shared_times = false;
                        }
                        self.curve_rest = Some(curve.clone());
                    }
                    Some(rest) if rest.len() != curve.len() => {
                        return Err(bad_line(format!(
                            "the `curve` has {} points, the first curve's {}",
                            curve.len(),
                            rest.len()
                        )));
                    }
                    Some(_) => {}
                }
                for (channel, v) in self.channels[points..].iter_mut().zip(curve) {
                    if !in_f32(v) {
                        return Err(bad_line(format!("curve point {v:?} is out of f32 range")));
                    }
                    channel
                        .sample(frame.t, *v)
                        .map_err(|cause| ExportError::write(&self.spool_dir, cause))?;
                }
            }
        }
        self.push_head(frame)?;
        self.push_rig(frame)?;
        self.frames += 1;
        Ok(())
    }

    /// The rig's keys: the jaw's rotation about the hinge axis (the mouth frame's x axis;
    /// positive angles open), its translation (the pivot, moved by the slide along the
    /// axis, in the character's units) and the curves as morph-target weights. A frame
    /// without `rig` (before the neutral pose) gets the rest keys: jaw closed, weights 0.
    fn push_rig(&mut self, frame: &TakeFrame) -> Result<(), ExportError> {
        if self.frames == 0 && self.options.rig {
            self.rig_start = Some(self.channels.len());
            for (kind, width) in [
                (Kind::JawRotation, 4),
                (Kind::JawTranslation, 3),
                (Kind::Weights, CURVES),
                (Kind::LipRotation, 4),
                (Kind::LipTranslation, 3),
                (Kind::LipRotation, 4),
                (Kind::LipTranslation, 3),
            ] {
                self.channels
                    .push(Channel::unreduced(&self.spool_dir, kind, width)?);
            }
        }
        let Some(start) = self.rig_start else {
            return Ok(());
        };
        self.rig_seen |= frame.rig.is_some();
        let rig = frame.rig.unwrap_or(RigKeys::REST);
        let pivot = jaw_pivot(&self.rig);
        let half = 0.5 * rig.jaw_angle_deg.to_radians();
        // The slide and the lips' translations in the character's units (its mouth width over
        // the performer's, as the points).
        let k = rig.to_character(self.rig.mouth_width(), self.rig.metres_per_unit());
        let slide = rig.jaw_slide_m * k;
        let translation = [pivot[0] + slide, pivot[1], pivot[2]];
        let lips = rig.lips.map(|l| l.translation_m.map(|c| c * k));
        if !translation
            .iter()
            .chain(lips.iter().flatten())
            .all(|c| (*c as f32).is_finite())
        {
            return Err(ExportError::BadLine {
                source_name: self.source_name.clone(),
                line: frame.line,
                problem: format!(
                    "rig.jaw.slide_m = {} or a lip's translation is out of the range of glTF's \
                     32-bit floats in the character's units",
                    rig.jaw_slide_m
                ),
            });
        }
        let err = |cause| ExportError::write(&self.spool_dir, cause);
        self.channels[start]
            .sample_rotation(frame.t, [half.sin(), 0.0, 0.0, half.cos()])
            .map_err(err)?;
        let jaw = &mut self.channels[start + 1];
        jaw.samples += 1;
        jaw.write_key((frame.t, translation)).map_err(err)?;
        let weights = &mut self.channels[start + 2];
        weights.samples += 1;
        weights
            .write_record(frame.t as f32, &rig.curves.map(|w| w as f32))
            .map_err(err)?;
        for (i, (lip, t)) in rig.lips.iter().zip(lips).enumerate() {
            let [w, x, y, z] = lip.rotation;
            self.channels[start + 3 + 2 * i]
                .sample_rotation(frame.t, [x, y, z, w])
                .map_err(err)?;
            let channel = &mut self.channels[start + 4 + 2 * i];
            channel.samples += 1;
            channel.write_key((frame.t, t)).map_err(err)?;
        }
        Ok(())
    }

    /// The head's and eyes' rotation keys: the head node's rotation is the model-axes
    /// conversion times the head's rotation in the model frame; the eyes' are their
    /// rotations relative to the head.
    fn push_head(&mut self, frame: &TakeFrame) -> Result<(), ExportError> {
        if self.frames == 0
            && self.options.head
            && self.rig.head().is_some()
            && frame.head.is_some()
        {
            self.head_start = Some(self.channels.len());
            for _ in 0..3 {
                self.channels
                    .push(Channel::rotation(&self.spool_dir, Kind::Head)?);
            }
        }
        let Some(start) = self.head_start else {
            return Ok(());
        };
        let Some(head) = &frame.head else {
            return Err(ExportError::BadLine {
                source_name: self.source_name.clone(),
                line: frame.line,
                problem: "no `character_head` on this line, though the first line had one".into(),
            });
        };
        let conversion = model_conversion(self.options.model_up);
        for (k, q) in head.rotations().iter().enumerate() {
            let q = nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]);
            let q = if k == 0 {
                conversion.into_inner() * q
            } else {
                q
            };
            self.channels[start + k]
                .sample_rotation(frame.t, [q.i, q.j, q.k, q.w])
                .map_err(|cause| ExportError::write(&self.spool_dir, cause))?;
        }
        Ok(())
    }

    /// Frames pushed so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Writes the document to `out` (and `out` with extension `.bin` for
    /// [`GltfLayout::SeparateBin`]). Files appear complete or not at all: each is written
    /// to a temporary name in its directory and renamed at the end.
    pub fn finish(mut self, out: &Path) -> Result<GltfSummary, ExportError> {
        if self.frames == 0 {
            return Err(ExportError::EmptyTake {
                source_name: self.source_name,
            });
        }
        if self.options.curve && self.curve_rest.is_none() {
            return Err(ExportError::NoCurve {
                source_name: self.source_name,
            });
        }
        let spool_dir = self.spool_dir.clone();
        let spool_err = |cause: io::Error| ExportError::write(&spool_dir, cause);
        for channel in &mut self.channels {
            if let Some(key) = channel.reducer.as_mut().and_then(Reducer::finish) {
                channel.write_key(key).map_err(spool_err)?;
            }
        }
        let mut spools = Vec::with_capacity(self.channels.len());
        for channel in &mut self.channels {
            let spool = std::mem::replace(
                &mut channel.spool,
                BufWriter::new(tempfile::tempfile_in(&spool_dir).map_err(spool_err)?),
            );
            let file = spool.into_inner().map_err(|e| spool_err(e.into_error()))?;
            spools.push(file);
        }
        let bin_path = out.with_extension("bin");
        let (root, pieces, bin_len) = self.document(&bin_path)?;
        let points = self.channels.iter().filter(|c| c.kind == Kind::Point);
        let samples: u64 = points.clone().map(|c| c.samples).sum();
        let keys: u64 = points.map(|c| c.keys).sum();
        let summary = GltfSummary {
            frames: self.frames,
            samples,
            keys,
            dropped: samples - keys,
            rotation_keys: self
                .channels
                .iter()
                .filter(|c| c.kind == Kind::Head)
                .map(|c| c.keys)
                .sum(),
            rig_keys: self
                .channels
                .iter()
                .filter(|c| c.kind == Kind::Weights && self.rig_seen)
                .map(|c| c.keys)
                .sum(),
            files: match self.options.layout {
                GltfLayout::SeparateBin => vec![out.to_path_buf(), bin_path.clone()],
                _ => vec![out.to_path_buf()],
            },
        };
        let mut assembler = Assembler {
            channels: &self.channels,
            spools: &mut spools,
            pieces: &pieces,
        };
        match self.options.layout {
            GltfLayout::Glb => {
                let json = serde_json::to_vec(&root).map_err(ExportError::Serialize)?;
                write_atomically(out, |w| assembler.write_glb(json, bin_len, w))?;
            }
            GltfLayout::SeparateBin => {
                write_atomically(&bin_path, |w| assembler.write_bin(w))?;
                let json = serde_json::to_vec_pretty(&root).map_err(ExportError::Serialize)?;
                write_atomically(out, |w| w.write_all(&json).map_err(Into::into))?;
            }
            GltfLayout::Embedded => {
                let json = serde_json::to_string_pretty(&root).map_err(ExportError::Serialize)?;
                write_atomically(out, |w| assembler.write_embedded(&json, w))?;
            }
        }
        tracing::debug!(
            frames = summary.frames,
            keys = summary.keys,
            dropped = summary.dropped,
            out = %out.display(),
            "glTF written"
        );
        Ok(summary)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// docs/export.md states the blend-shape mesh's target count the code writes.
    #[test]
    fn the_documented_morph_target_count_is_the_curve_count() {
        let page = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/export.md"),
        )
        .unwrap();
        let flat = page.split_whitespace().collect::<Vec<_>>().join(" ");
        assert!(
            flat.contains(&format!("carries a mesh with {CURVES} morph targets")),
            "docs/export.md does not say {CURVES} morph targets"
        );
    }

    /// The first key of the `path` channel (`translation` or `rotation`) of node `name`, in
    /// a `.gltf` with its `.bin` beside it.
    fn first_key(dir: &Path, gltf: &serde_json::Value, name: &str, path: &str) -> Vec<f32> {
        let node = gltf["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .position(|n| n["name"] == name)
            .unwrap();
        let animation = &gltf["animations"][0];
        let channel = animation["channels"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["target"]["node"] == node && c["target"]["path"] == path)
            .unwrap();
        let sampler = &animation["samplers"][channel["sampler"].as_u64().unwrap() as usize];
        let accessor = &gltf["accessors"][sampler["output"].as_u64().unwrap() as usize];
        let view = &gltf["bufferViews"][accessor["bufferView"].as_u64().unwrap() as usize];
        let offset = (view["byteOffset"].as_u64().unwrap_or(0)
            + accessor["byteOffset"].as_u64().unwrap_or(0)) as usize;
        let bin = std::fs::read(dir.join(gltf["buffers"][0]["uri"].as_str().unwrap())).unwrap();
        let width = if path == "rotation" { 4 } else { 3 };
        (0..width)
            .map(|k| {
                f32::from_le_bytes(bin[offset + 4 * k..offset + 4 * k + 4].try_into().unwrap())
            })
            .collect()
    }

    /// In glTF too the jaw's slide and the lips' translations are in the character's units,
    /// scaled by its mouth width over the performer's: a character twice the performer's
    /// width gets twice the slide and twice the lips' motion; the lips' rotations as taken.
    #[test]
    fn the_slide_and_the_lips_are_scaled_to_the_characters_mouth() {
        let dir = tempfile::tempdir().unwrap();
        let keys = |width: f64| {
            let rig = crate::csv::tests::rig_of_width(width);
            let pivot = document::jaw_pivot(&rig);
            let options = GltfOptions {
                layout: GltfLayout::SeparateBin,
                ..GltfOptions::default()
            };
            let mut w = GltfWriter::new(rig, options, dir.path()).unwrap();
            w.push(&crate::csv::tests::performer_frame()).unwrap();
            let out = dir.path().join(format!("{width}.gltf"));
            w.finish(&out).unwrap();
            let gltf: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
            let jaw = first_key(dir.path(), &gltf, "jaw", "translation");
            let slide = f64::from(jaw[0]) - pivot[0];
            let upper = first_key(dir.path(), &gltf, "lip_upper", "translation");
            let lower = first_key(dir.path(), &gltf, "lip_lower", "translation");
            let rotation = first_key(dir.path(), &gltf, "lip_lower", "rotation");
            (slide, upper, lower, rotation)
        };
        let (slide, upper, lower, rotation) = keys(0.05);
        let (slide2, upper2, lower2, rotation2) = keys(0.1);
        assert!((slide - -0.0015).abs() < 1e-8, "{slide}");
        assert!((slide2 - -0.003).abs() < 1e-8, "{slide2}");
        let want = [0.001, 0.002, -0.0005, -0.0025, -0.004, 0.003];
        for (k, (a, b)) in upper
            .iter()
            .chain(&lower)
            .zip(upper2.iter().chain(&lower2))
            .enumerate()
        {
            assert!(
                (f64::from(*a) - want[k]).abs() < 1e-9,
                "{upper:?} {lower:?}"
            );
            assert!(
                (f64::from(*b) - 2.0 * want[k]).abs() < 1e-9,
                "{upper2:?} {lower2:?}"
            );
        }
        // glTF's [x, y, z, w].
        assert_eq!(rotation, [0.8, 0.0, 0.0, 0.6]);
        assert_eq!(rotation2, rotation);
    }

    #[test]
    fn uri_escape_keeps_safe_names() {
        assert_eq!(uri_escape("take-01_a.bin"), "take-01_a.bin");
        assert_eq!(uri_escape("my take#1.bin"), "my%20take%231.bin");
    }

    #[test]
    fn octahedron_faces_point_outwards() {
        let (positions, indices, _) = octahedron(1.0);
        let vertex = |i: usize| -> [f32; 3] {
            [0, 1, 2].map(|k| {
                f32::from_le_bytes(
                    positions[12 * i + 4 * k..12 * i + 4 * k + 4]
                        .try_into()
                        .unwrap(),
                )
            })
        };
        for tri in indices.chunks(6) {
            let idx = [0, 1, 2].map(|k| u16::from_le_bytes([tri[2 * k], tri[2 * k + 1]]) as usize);
            let [a, b, c] = idx.map(vertex);
            let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
            let n = [
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ];
            let centre = [0, 1, 2].map(|k| a[k] + b[k] + c[k]);
            let outward: f32 = (0..3).map(|k| n[k] * centre[k]).sum();
            assert!(outward > 0.0, "triangle {idx:?} faces inwards");
        }
    }
}
