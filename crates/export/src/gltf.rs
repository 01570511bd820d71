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

use mouthpiece_retarget::rig::{RigSettings, CURVES, CURVE_NAMES};

use crate::output::{parent_dir, PendingFile};
use crate::reduce::{Key, Reducer};
use crate::take::RigKeys;
use crate::{ExportError, MouthRig, TakeFrame};

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
}

impl Kind {
    fn is_rig(self) -> bool {
        matches!(
            self,
            Kind::JawRotation | Kind::JawTranslation | Kind::Weights
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
        let slide = rig.jaw_slide_m / self.rig.metres_per_unit().unwrap_or(1.0);
        let translation = [pivot[0] + slide, pivot[1], pivot[2]];
        if !translation.iter().all(|c| (*c as f32).is_finite()) {
            return Err(ExportError::BadLine {
                source_name: self.source_name.clone(),
                line: frame.line,
                problem: format!(
                    "rig.jaw.slide_m = {} is out of the range of glTF's 32-bit floats",
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
            .map_err(err)
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

    /// The glTF JSON, the binary buffer's pieces in order, and the buffer's length.
    fn document(&self, bin_path: &Path) -> Result<(json::Root, Vec<Piece>, u64), ExportError> {
        let mut root = json::Root {
            asset: json::Asset {
                generator: Some(format!("mouthpiece export {}", env!("CARGO_PKG_VERSION"))),
                ..Default::default()
            },
            ..Default::default()
        };
        let mut pieces = Vec::new();
        let mut offset = 0u64;
        let buffer = json::Index::<json::Buffer>::new(0);
        let mut view = |root: &mut json::Root,
                        pieces: &mut Vec<Piece>,
                        piece: Piece,
                        len: u64,
                        target: Option<json::buffer::Target>| {
            pieces.push(piece);
            let index = root.push(json::buffer::View {
                buffer,
                byte_length: USize64(len),
                byte_offset: Some(USize64(offset)),
                byte_stride: None,
                extensions: None,
                extras: Default::default(),
                name: None,
                target: target.map(Valid),
            });
            offset += len;
            index
        };

        let marker_mesh = if self.options.markers {
            let size = marker_size(self.rig.mouth_width());
            let (positions, indices, bounds) = octahedron(size);
            let pos_len = positions.len() as u64;
            let idx_len = indices.len() as u64;
            let pos_view = view(
                &mut root,
                &mut pieces,
                Piece::Bytes(positions),
                pos_len,
                Some(json::buffer::Target::ArrayBuffer),
            );
            let idx_view = view(
                &mut root,
                &mut pieces,
                Piece::Bytes(indices),
                idx_len,
                Some(json::buffer::Target::ElementArrayBuffer),
            );
            let (min, max) = bounds.json();
            let pos = root.push(accessor(
                pos_view,
                6,
                json::accessor::Type::Vec3,
                json::accessor::ComponentType::F32,
                Some((min, max)),
            ));
            let idx = root.push(accessor(
                idx_view,
                24,
                json::accessor::Type::Scalar,
                json::accessor::ComponentType::U16,
                None,
            ));
            Some(root.push(json::Mesh {
                extensions: None,
                extras: Default::default(),
                name: Some("point marker".into()),
                primitives: vec![json::mesh::Primitive {
                    attributes: [(Valid(json::mesh::Semantic::Positions), pos)].into(),
                    extensions: None,
                    extras: Default::default(),
                    indices: Some(idx),
                    material: None,
                    mode: Valid(json::mesh::Mode::Triangles),
                    targets: None,
                }],
                weights: None,
            }))
        } else {
            None
        };

        let node = |root: &mut json::Root, name: String, rest: &[f64; 3]| {
            root.push(json::Node {
                name: Some(name),
                translation: Some(rest.map(|c| c as f32)),
                mesh: marker_mesh,
                ..Default::default()
            })
        };
        let point_nodes: Vec<json::Index<json::Node>> = self
            .rig
            .points()
            .iter()
            .map(|p| node(&mut root, p.name.clone(), &p.rest))
            .collect();
        let mut mouth_children = point_nodes.clone();
        let mut channel_nodes = point_nodes;
        let mut channel_names = self.rig.names();
        if let Some(rest) = &self.curve_rest {
            let curve_nodes: Vec<_> = rest
                .iter()
                .enumerate()
                .map(|(i, p)| node(&mut root, format!("C{i}"), p))
                .collect();
            mouth_children.push(root.push(json::Node {
                name: Some("curve".into()),
                children: Some(curve_nodes.clone()),
                ..Default::default()
            }));
            channel_names.extend((0..rest.len()).map(|i| format!("C{i}")));
            channel_nodes.extend(curve_nodes);
        }
        let rig_nodes = if self.rig_start.is_some() && self.rig_seen {
            let pivot = jaw_pivot(&self.rig);
            let jaw = root.push(json::Node {
                name: Some("jaw".into()),
                translation: Some(pivot.map(|c| c as f32)),
                mesh: marker_mesh,
                ..Default::default()
            });
            let width = meter_width(self.rig.mouth_width());
            let meter = blendshape_meter(width);
            let indices_len = meter.indices.len() as u64;
            let positions_len = meter.positions.len() as u64;
            let pos_view = view(
                &mut root,
                &mut pieces,
                Piece::Bytes(meter.positions),
                positions_len,
                Some(json::buffer::Target::ArrayBuffer),
            );
            let idx_view = view(
                &mut root,
                &mut pieces,
                Piece::Bytes(meter.indices),
                indices_len,
                Some(json::buffer::Target::ElementArrayBuffer),
            );
            let (min, max) = meter.bounds.json();
            let positions = root.push(accessor(
                pos_view,
                meter.vertices,
                json::accessor::Type::Vec3,
                json::accessor::ComponentType::F32,
                Some((min, max)),
            ));
            let indices = root.push(accessor(
                idx_view,
                indices_len / 2,
                json::accessor::Type::Scalar,
                json::accessor::ComponentType::U16,
                None,
            ));
            let mut targets = Vec::with_capacity(CURVES);
            for (bytes, bounds) in meter.targets {
                let len = bytes.len() as u64;
                let target_view = view(
                    &mut root,
                    &mut pieces,
                    Piece::Bytes(bytes),
                    len,
                    Some(json::buffer::Target::ArrayBuffer),
                );
                targets.push(json::mesh::MorphTarget {
                    positions: Some(root.push(accessor(
                        target_view,
                        meter.vertices,
                        json::accessor::Type::Vec3,
                        json::accessor::ComponentType::F32,
                        Some(bounds.json()),
                    ))),
                    normals: None,
                    tangents: None,
                });
            }
            let names = serde_json::json!({ "targetNames": CURVE_NAMES });
            let mesh = root.push(json::Mesh {
                extensions: None,
                extras: Some(
                    serde_json::value::to_raw_value(&names).map_err(ExportError::Serialize)?,
                ),
                name: Some("blendshapes".into()),
                primitives: vec![json::mesh::Primitive {
                    attributes: [(Valid(json::mesh::Semantic::Positions), positions)].into(),
                    extensions: None,
                    extras: Default::default(),
                    indices: Some(indices),
                    material: None,
                    mode: Valid(json::mesh::Mode::Triangles),
                    targets: Some(targets),
                }],
                weights: Some(vec![0.0; CURVES]),
            });
            let shapes = root.push(json::Node {
                name: Some("blendshapes".into()),
                translation: Some([0.0, (-METER_BELOW * width) as f32, 0.0]),
                mesh: Some(mesh),
                ..Default::default()
            });
            mouth_children.extend([jaw, shapes]);
            Some([jaw, jaw, shapes])
        } else {
            None
        };
        let transform = mouth_transform(&self.rig, self.options.model_up);
        let mouth = root.push(json::Node {
            name: Some("mouth".into()),
            translation: transform.translation,
            rotation: transform.rotation,
            scale: transform.scale,
            children: Some(mouth_children),
            ..Default::default()
        });
        let mut scene_nodes = vec![mouth];
        if let (Some(head), Some(_)) = (self.rig.head(), self.head_start) {
            let offset = |p: &[f64; 3]| {
                let d = [0, 1, 2].map(|k| (p[k] - head.pivot[k]) as f32);
                Some(d)
            };
            let eye = |root: &mut json::Root, name: &str, at: &[f64; 3]| {
                root.push(json::Node {
                    name: Some(name.into()),
                    translation: offset(at),
                    mesh: marker_mesh,
                    ..Default::default()
                })
            };
            let eye_left = eye(&mut root, "eye_L", &head.eye_left);
            let eye_right = eye(&mut root, "eye_R", &head.eye_right);
            let place = head_transform(&self.rig, head, self.options.model_up);
            let head_node = root.push(json::Node {
                name: Some("head".into()),
                translation: place.translation,
                rotation: place.rotation,
                scale: place.scale,
                children: Some(vec![eye_left, eye_right]),
                ..Default::default()
            });
            scene_nodes.push(head_node);
            channel_names.extend(["head", "eye_L", "eye_R"].map(String::from));
            channel_nodes.extend([head_node, eye_left, eye_right]);
        }
        if let Some(nodes) = rig_nodes {
            channel_names.extend(["jaw", "jaw", "blendshapes"].map(String::from));
            channel_nodes.extend(nodes);
        }
        // The rig's channels come last; without a rig in the take they are left out.
        let written = self
            .channels
            .iter()
            .filter(|c| self.rig_seen || !c.kind.is_rig())
            .count();
        debug_assert_eq!(written, channel_nodes.len());
        let scene = root.push(json::Scene {
            extensions: None,
            extras: Default::default(),
            name: Some(self.rig.character().unwrap_or("take").to_owned()),
            nodes: scene_nodes,
        });
        root.scene = Some(scene);

        let time_accessor = |root: &mut json::Root, view, channel: &Channel| {
            let (min, max) = channel.t_bounds.json();
            root.push(accessor(
                view,
                channel.keys,
                json::accessor::Type::Scalar,
                json::accessor::ComponentType::F32,
                Some((min, max)),
            ))
        };
        let shared_input = if self.shared_times {
            let first = &self.channels[0];
            let v = view(
                &mut root,
                &mut pieces,
                Piece::Times { channel: 0 },
                4 * first.keys,
                None,
            );
            Some(time_accessor(&mut root, v, first))
        } else {
            None
        };
        let mut samplers = Vec::new();
        let mut channels = Vec::new();
        for (i, (channel, node)) in self.channels.iter().zip(&channel_nodes).enumerate() {
            if channel.keys == 0 {
                tracing::warn!(point = %channel_names[i], "point never seen in the take: no animation channel");
                continue;
            }
            let input = match shared_input {
                Some(input) => input,
                None => {
                    let v = view(
                        &mut root,
                        &mut pieces,
                        Piece::Times { channel: i },
                        4 * channel.keys,
                        None,
                    );
                    time_accessor(&mut root, v, channel)
                }
            };
            let v = view(
                &mut root,
                &mut pieces,
                Piece::Values { channel: i },
                4 * channel.width as u64 * channel.keys,
                None,
            );
            let (min, max) = channel.v_bounds.json_first(channel.width.min(4));
            let (kind, path, count) = match channel.kind {
                Kind::Head | Kind::JawRotation => (
                    json::accessor::Type::Vec4,
                    json::animation::Property::Rotation,
                    channel.keys,
                ),
                Kind::Point | Kind::JawTranslation => (
                    json::accessor::Type::Vec3,
                    json::animation::Property::Translation,
                    channel.keys,
                ),
                // One SCALAR per target and key, key by key.
                Kind::Weights => (
                    json::accessor::Type::Scalar,
                    json::animation::Property::MorphTargetWeights,
                    channel.keys * CURVES as u64,
                ),
            };
            let (min, max) = if channel.kind == Kind::Weights {
                channel.v_bounds.json_first(1)
            } else {
                (min, max)
            };
            let output = root.push(accessor(
                v,
                count,
                kind,
                json::accessor::ComponentType::F32,
                Some((min, max)),
            ));
            let sampler = json::Index::new(samplers.len() as u32);
            samplers.push(json::animation::Sampler {
                extensions: None,
                extras: Default::default(),
                input,
                interpolation: Valid(json::animation::Interpolation::Linear),
                output,
            });
            channels.push(json::animation::Channel {
                sampler,
                target: json::animation::Target {
                    extensions: None,
                    extras: Default::default(),
                    node: *node,
                    path: Valid(path),
                },
                extensions: None,
                extras: Default::default(),
            });
        }
        if channels.is_empty() {
            tracing::warn!("no point was ever seen: the glTF has no animation");
        } else {
            root.push(json::Animation {
                extensions: None,
                extras: Default::default(),
                channels,
                name: Some("take".into()),
                samplers,
            });
        }
        let uri = match self.options.layout {
            GltfLayout::Glb => None,
            GltfLayout::SeparateBin => Some(uri_escape(
                &bin_path.file_name().unwrap_or_default().to_string_lossy(),
            )),
            GltfLayout::Embedded => Some(DATA_URI_SENTINEL.to_owned()),
        };
        root.push(json::Buffer {
            byte_length: USize64(offset),
            extensions: None,
            extras: Default::default(),
            name: None,
            uri,
        });
        Ok((root, pieces, offset))
    }
}

/// Where the `jaw` node sits in the mouth frame (character units): the character's own
/// `[rig] jaw_pivot`, else the rig's default hinge pivot (docs/rig.md), `hinge_up` mouth
/// widths above and `hinge_back` behind the mouth centre, with the character's own mouth
/// width (the performer's `[rig]` hinge describes the performer's head, not the character's).
fn jaw_pivot(rig: &MouthRig) -> [f64; 3] {
    if let Some(p) = rig.jaw_pivot() {
        return p;
    }
    let settings = RigSettings::default();
    let w = rig.mouth_width();
    [0.0, settings.hinge_up * w, -settings.hinge_back * w]
}

/// How far below the mouth centre the `blendshapes` meter sits, in mouth widths.
const METER_BELOW: f64 = 1.5;

/// The mouth width the meter is drawn with (a take without a character file may have one of
/// 0: then 5 cm).
fn meter_width(width: f64) -> f64 {
    if width > 0.0 && width.is_finite() {
        width
    } else {
        0.05
    }
}

/// The `blendshapes` mesh: a row of one bar per curve (a tenth of a mouth width apart, a
/// stub at rest), each morph target raising its own bar's top by half a mouth width, so a
/// viewer playing the weights shows a bar chart of the curves.
struct Meter {
    vertices: u64,
    positions: Vec<u8>,
    indices: Vec<u8>,
    bounds: Bounds<3>,
    /// One POSITION displacement buffer per curve, with its bounds.
    targets: Vec<(Vec<u8>, Bounds<3>)>,
}

fn blendshape_meter(width: f64) -> Meter {
    let w = width as f32;
    let (pitch, bar, stub, rise) = (0.1 * w, 0.08 * w, 0.02 * w, 0.5 * w);
    let mut positions = Vec::with_capacity(CURVES * 4 * 12);
    let mut indices = Vec::with_capacity(CURVES * 6 * 2);
    let mut bounds = Bounds::new();
    for i in 0..CURVES {
        let x0 = (i as f32 - CURVES as f32 / 2.0) * pitch + 0.5 * (pitch - bar);
        let x1 = x0 + bar;
        for v in [
            [x0, 0.0, 0.0],
            [x1, 0.0, 0.0],
            [x1, stub, 0.0],
            [x0, stub, 0.0],
        ] {
            bounds.add(&v);
            for c in v {
                positions.extend_from_slice(&c.to_le_bytes());
            }
        }
        // Counter-clockwise seen from +z (the front).
        let base = (4 * i) as u16;
        for k in [0, 1, 2, 0, 2, 3] {
            indices.extend_from_slice(&(base + k).to_le_bytes());
        }
    }
    let targets = (0..CURVES)
        .map(|i| {
            let mut bytes = Vec::with_capacity(CURVES * 4 * 12);
            let mut b = Bounds::new();
            for v in 0..4 * CURVES {
                // The top two corners of bar i.
                let d = if v / 4 == i && v % 4 >= 2 {
                    [0.0, rise, 0.0]
                } else {
                    [0.0; 3]
                };
                b.add(&d);
                for c in d {
                    bytes.extend_from_slice(&c.to_le_bytes());
                }
            }
            (bytes, b)
        })
        .collect();
    Meter {
        vertices: 4 * CURVES as u64,
        positions,
        indices,
        bounds,
        targets,
    }
}

/// The `mouth` node's TRS, each part left out when it is the identity.
struct NodeTransform {
    translation: Option<[f32; 3]>,
    rotation: Option<json::scene::UnitQuaternion>,
    scale: Option<[f32; 3]>,
}

/// C, the rotation from the character's model axes to glTF's.
fn model_conversion(model_up: ModelUp) -> nalgebra::UnitQuaternion<f64> {
    use nalgebra::{UnitQuaternion, Vector3};
    match model_up {
        ModelUp::Y => UnitQuaternion::identity(),
        ModelUp::Z => {
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), -std::f64::consts::FRAC_PI_2)
        }
    }
}

/// The `head` node's rest TRS: translation s·C·pivot, rotation C (its keys are C·R_head),
/// scale s; its children (the eyes) are then in the model's axes and units, relative to the
/// pivot.
fn head_transform(rig: &MouthRig, head: &crate::RigHead, model_up: ModelUp) -> NodeTransform {
    let conversion = model_conversion(model_up);
    let s = rig.metres_per_unit().unwrap_or(1.0);
    let translation = (conversion * nalgebra::Vector3::from(head.pivot) * s).map(|c| c as f32);
    let q = conversion.coords.map(|c| c as f32).normalize();
    NodeTransform {
        translation: (translation.norm() > 0.0).then(|| translation.into()),
        rotation: (q.w.abs() < 1.0).then(|| json::scene::UnitQuaternion([q.x, q.y, q.z, q.w])),
        scale: (s != 1.0).then_some([s as f32; 3]),
    }
}

/// glTF world = C · s · placement · mouth, with C the model-axes conversion and s the units'
/// metres: translation s·C·o, rotation C·R, scale s.
fn mouth_transform(rig: &MouthRig, model_up: ModelUp) -> NodeTransform {
    let conversion = model_conversion(model_up);
    let s = rig.metres_per_unit().unwrap_or(1.0);
    let placement = rig.placement();
    let translation = (conversion * placement.translation.vector * s).map(|c| c as f32);
    let q = (conversion * placement.rotation)
        .coords
        .map(|c| c as f32)
        .normalize();
    NodeTransform {
        translation: (translation.norm() > 0.0).then(|| translation.into()),
        rotation: (q.w.abs() < 1.0).then(|| json::scene::UnitQuaternion([q.x, q.y, q.z, q.w])),
        scale: (s != 1.0).then_some([s as f32; 3]),
    }
}

/// Stand-in for the data URI in the serialised JSON; the base64 is streamed in its place.
const DATA_URI_SENTINEL: &str = "mouthpiece-embedded-buffer";
const DATA_URI_PREFIX: &str = "data:application/octet-stream;base64,";

fn accessor(
    view: json::Index<json::buffer::View>,
    count: u64,
    type_: json::accessor::Type,
    component: json::accessor::ComponentType,
    bounds: Option<(Value, Value)>,
) -> json::Accessor {
    let (min, max) = bounds.unzip();
    json::Accessor {
        buffer_view: Some(view),
        byte_offset: None,
        count: USize64(count),
        component_type: Valid(json::accessor::GenericComponentType(component)),
        extensions: None,
        extras: Default::default(),
        type_: Valid(type_),
        min,
        max,
        name: None,
        normalized: false,
        sparse: None,
    }
}

/// Marker half-size: 2 % of the mouth width, or 1 mm-ish when the width is unknown (0).
fn marker_size(width: f64) -> f32 {
    if width > 0.0 {
        (0.02 * width) as f32
    } else {
        0.001
    }
}

/// An octahedron of half-size `s`: positions (6 × VEC3 f32), indices (24 × u16, outward
/// counter-clockwise), and the positions' bounds.
fn octahedron(s: f32) -> (Vec<u8>, Vec<u8>, Bounds<3>) {
    let vertices = [
        [s, 0.0, 0.0],
        [-s, 0.0, 0.0],
        [0.0, s, 0.0],
        [0.0, -s, 0.0],
        [0.0, 0.0, s],
        [0.0, 0.0, -s],
    ];
    let mut bounds = Bounds::new();
    let mut positions = Vec::with_capacity(72);
    for v in &vertices {
        bounds.add(v);
        for c in v {
            positions.extend_from_slice(&c.to_le_bytes());
        }
    }
    let mut indices = Vec::with_capacity(48);
    for (sx, sy, sz) in [
        (0, 2, 4),
        (1, 2, 4),
        (0, 3, 4),
        (1, 3, 4),
        (0, 2, 5),
        (1, 2, 5),
        (0, 3, 5),
        (1, 3, 5),
    ] {
        // (+x, +y, +z) is counter-clockwise seen from outside; each negated axis flips it.
        let flips = sx % 2 + sy % 2 + sz % 2;
        let tri: [u16; 3] = if flips % 2 == 0 {
            [sx, sy, sz]
        } else {
            [sx, sz, sy]
        };
        for i in tri {
            indices.extend_from_slice(&i.to_le_bytes());
        }
    }
    (positions, indices, bounds)
}

/// Percent-encodes a file name for a relative URI (RFC 3986 unreserved characters stay).
fn uri_escape(name: &str) -> String {
    let mut out = String::with_capacity(name.len());
    for b in name.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// Copies the binary buffer's pieces, in order, from memory and the spool files.
struct Assembler<'a> {
    channels: &'a [Channel],
    spools: &'a mut [File],
    pieces: &'a [Piece],
}

impl Assembler<'_> {
    fn write_bin(&mut self, out: &mut dyn Write) -> Result<(), WriteError> {
        for piece in self.pieces {
            match *piece {
                Piece::Bytes(ref bytes) => out.write_all(bytes).map_err(WriteError::Out)?,
                Piece::Times { channel } => self.copy_column(channel, 0..4, out)?,
                Piece::Values { channel } => {
                    let end = self.channels[channel].record_len();
                    self.copy_column(channel, 4..end, out)?
                }
            }
        }
        Ok(())
    }

    fn copy_column(
        &mut self,
        channel: usize,
        columns: std::ops::Range<usize>,
        out: &mut dyn Write,
    ) -> Result<(), WriteError> {
        let spool = &mut self.spools[channel];
        spool.seek(SeekFrom::Start(0)).map_err(WriteError::Spool)?;
        let mut reader = BufReader::with_capacity(64 * 1024, spool);
        let mut buffer = [0u8; RECORD];
        let record = &mut buffer[..self.channels[channel].record_len()];
        for _ in 0..self.channels[channel].keys {
            reader.read_exact(record).map_err(WriteError::Spool)?;
            out.write_all(&record[columns.clone()])
                .map_err(WriteError::Out)?;
        }
        Ok(())
    }

    fn write_glb(
        &mut self,
        mut json: Vec<u8>,
        bin_len: u64,
        out: &mut dyn Write,
    ) -> Result<(), WriteError> {
        // Chunks are 4-byte aligned: JSON padded with spaces; our buffer is all 4-byte data.
        while !json.len().is_multiple_of(4) {
            json.push(b' ');
        }
        debug_assert_eq!(bin_len % 4, 0);
        let total = 12 + 8 + json.len() as u64 + 8 + bin_len;
        let total32 = u32::try_from(total).map_err(|_| WriteError::TooLarge(total))?;
        out.write_all(b"glTF").map_err(WriteError::Out)?;
        out.write_all(&2u32.to_le_bytes())
            .map_err(WriteError::Out)?;
        out.write_all(&total32.to_le_bytes())
            .map_err(WriteError::Out)?;
        out.write_all(&(json.len() as u32).to_le_bytes())
            .map_err(WriteError::Out)?;
        out.write_all(b"JSON").map_err(WriteError::Out)?;
        out.write_all(&json).map_err(WriteError::Out)?;
        out.write_all(&(bin_len as u32).to_le_bytes())
            .map_err(WriteError::Out)?;
        out.write_all(b"BIN\0").map_err(WriteError::Out)?;
        self.write_bin(out)
    }

    fn write_embedded(&mut self, json: &str, out: &mut dyn Write) -> Result<(), WriteError> {
        let (before, after) = json
            .split_once(DATA_URI_SENTINEL)
            .expect("the document holds the sentinel URI");
        out.write_all(before.as_bytes()).map_err(WriteError::Out)?;
        out.write_all(DATA_URI_PREFIX.as_bytes())
            .map_err(WriteError::Out)?;
        {
            let mut encoder = base64::write::EncoderWriter::new(
                &mut *out,
                &base64::engine::general_purpose::STANDARD,
            );
            self.write_bin(&mut encoder)?;
            encoder.finish().map_err(WriteError::Out)?;
        }
        out.write_all(after.as_bytes()).map_err(WriteError::Out)
    }
}

/// Failures while assembling an output file, told apart so the message names the right file.
#[derive(Debug)]
enum WriteError {
    Out(io::Error),
    Spool(io::Error),
    TooLarge(u64),
}

impl From<io::Error> for WriteError {
    fn from(e: io::Error) -> Self {
        Self::Out(e)
    }
}

/// Writes `path` through a temporary file in the same directory, renamed when complete.
fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut dyn Write) -> Result<(), WriteError>,
) -> Result<(), ExportError> {
    let out_err = |cause: io::Error| ExportError::write(path, cause);
    let mut pending = PendingFile::create(path).map_err(out_err)?;
    write(&mut pending).map_err(|e| match e {
        WriteError::Out(cause) => out_err(cause),
        WriteError::Spool(cause) => ExportError::write(parent_dir(path), cause),
        WriteError::TooLarge(bytes) => ExportError::TooLargeForGlb { bytes },
    })?;
    pending.commit().map_err(out_err)
}

#[cfg(test)]
mod tests {
    use super::*;

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
