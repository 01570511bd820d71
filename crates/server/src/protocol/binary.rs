//! The binary `frame` layout (`docs/protocol.md`, *Binary frames*): little-endian, every block
//! 4-byte aligned.

use super::{FrameSelection, BINARY_MAGIC, BINARY_VERSION};
use crate::hub::PublishedFrame;

/// Flags of the binary `frame` header (`docs/protocol.md`).
mod flag {
    pub const HEAD_LOST: u16 = 1;
    pub const CURVES: u16 = 1 << 1;
    pub const PERFORMER: u16 = 1 << 2;
    pub const WALL_CLOCK: u16 = 1 << 3;
    pub const HEADS: u16 = 1 << 4;
    pub const RIGS: u16 = 1 << 5;
}

/// Bytes of a character's head block: presence, mode and reach bytes, three quaternions and
/// the turn's progress.
pub const BINARY_HEAD_LEN: usize = 4 + 13 * 4;

/// Bytes of a character's rig block: presence, curve and viseme counts, jaw (2 floats), each
/// lip (rotation, translation, residual: 8 floats), one float per curve and per viseme.
pub const fn binary_rig_len(curves: usize, visemes: usize) -> usize {
    8 + (2 + 8 + 8 + curves + visemes) * 4
}

/// Encodes the binary form of `frame` (layout in `docs/protocol.md`), appending to `out`.
///
/// `character_names` is the `characters` list of the current `hello`: each character block
/// carries its index in it (`0xFFFF` when the name is not there).
pub fn encode_binary_frame(
    frame: &PublishedFrame,
    selection: &FrameSelection,
    character_names: &[String],
    out: &mut Vec<u8>,
) {
    let f = &frame.frame;
    let characters: Vec<_> = f
        .characters
        .iter()
        .filter(|c| selection.wants(&c.name))
        .collect();
    let with_curve = selection.curve;
    let performer = if selection.performer {
        f.performer.as_ref()
    } else {
        None
    };
    let mut flags = flag::HEADS;
    if f.head.lost {
        flags |= flag::HEAD_LOST;
    }
    if with_curve {
        flags |= flag::CURVES;
    }
    if performer.is_some() {
        flags |= flag::PERFORMER;
    }
    if f.wall_us.is_some() {
        flags |= flag::WALL_CLOCK;
    }
    if selection.rig {
        flags |= flag::RIGS;
    }
    out.extend_from_slice(BINARY_MAGIC);
    out.extend_from_slice(&BINARY_VERSION.to_le_bytes());
    out.extend_from_slice(&flags.to_le_bytes());
    out.extend_from_slice(&frame.seq.to_le_bytes());
    out.extend_from_slice(&f.t.to_le_bytes());
    out.extend_from_slice(&f.capture_us.to_le_bytes());
    out.extend_from_slice(&f.wall_us.unwrap_or(0).to_le_bytes());
    let tc = &frame.timecode;
    out.extend_from_slice(&[tc.hours, tc.minutes, tc.seconds, tc.frames]);
    out.extend_from_slice(&(characters.len() as u16).to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
    for v in f
        .head
        .pose
        .rotation
        .iter()
        .chain(f.head.pose.translation.iter())
    {
        out.extend_from_slice(&(*v as f32).to_le_bytes());
    }
    debug_assert_eq!(out.len() % 4, 0);
    for c in characters {
        let index = character_names
            .iter()
            .position(|n| *n == c.name)
            .map_or(u16::MAX, |i| i as u16);
        out.extend_from_slice(&index.to_le_bytes());
        out.extend_from_slice(&(c.points.len() as u16).to_le_bytes());
        push_points(out, &c.points);
        push_floats(out, &c.confidence, c.points.len());
        if with_curve {
            let curve = c.curve.as_deref().unwrap_or(&[]);
            out.extend_from_slice(&(curve.len() as u16).to_le_bytes());
            out.extend_from_slice(&0u16.to_le_bytes());
            push_points(out, curve);
        }
        push_head(out, c.head.as_ref(), c.source);
        if selection.rig {
            push_rig(out, c.rig.as_ref());
        }
    }
    if let Some(p) = performer {
        out.extend_from_slice(&(p.points.len() as u16).to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        push_points(out, &p.points);
        push_floats(out, &p.confidence, p.points.len());
    }
}

/// A character's head block: fixed size, with a presence byte (a character whose head the
/// daemon does not drive writes 0 and identities).
fn push_head(
    out: &mut Vec<u8>,
    head: Option<&mouthpiece_output::CharacterHead>,
    source: mouthpiece_output::MouthSource,
) {
    let start = out.len();
    let default = mouthpiece_output::CharacterHead::default();
    let h = head.unwrap_or(&default);
    let mode = match h.mode {
        mouthpiece_output::LookMode::Follow => 0u8,
        mouthpiece_output::LookMode::LookAt => 1,
    };
    let in_reach = match h.in_reach {
        Some(false) => 0u8,
        Some(true) => 1,
        None => 0xFF,
    };
    out.extend_from_slice(&[u8::from(head.is_some()), mode, in_reach, source.code()]);
    for v in h.rotation.iter().chain(&h.eye_left).chain(&h.eye_right) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&h.progress.to_le_bytes());
    debug_assert_eq!(out.len() - start, BINARY_HEAD_LEN);
}

/// A character's rig block: fixed size for a given curve list, with a presence flag (the rig
/// is absent before the performer is calibrated: 0 and zeros).
fn push_rig(out: &mut Vec<u8>, rig: Option<&mouthpiece_output::RigState>) {
    let start = out.len();
    let default = mouthpiece_output::RigState::default();
    let r = rig.unwrap_or(&default);
    let (curves, visemes) = (&r.curves.0, &r.visemes.0);
    out.extend_from_slice(&u16::from(rig.is_some()).to_le_bytes());
    out.extend_from_slice(&(curves.len() as u16).to_le_bytes());
    out.extend_from_slice(&(visemes.len() as u16).to_le_bytes());
    out.extend_from_slice(&0u16.to_le_bytes());
    let lip = |l: &mouthpiece_output::RigLip| {
        let mut v = [0f32; 8];
        v[..4].copy_from_slice(&l.rotation);
        v[4..7].copy_from_slice(&l.translation);
        v[7] = l.residual;
        v
    };
    let floats = [r.jaw.angle_deg, r.jaw.slide_m]
        .into_iter()
        .chain(lip(&r.lips.upper))
        .chain(lip(&r.lips.lower))
        .chain(curves.iter().copied())
        .chain(visemes.iter().copied());
    for v in floats {
        out.extend_from_slice(&v.to_le_bytes());
    }
    debug_assert_eq!(
        out.len() - start,
        binary_rig_len(curves.len(), visemes.len())
    );
}

fn push_points(out: &mut Vec<u8>, points: &[[f32; 3]]) {
    for p in points {
        for v in p {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
}

/// Exactly `n` floats: missing confidences are written as 0.
fn push_floats(out: &mut Vec<u8>, values: &[f32], n: usize) {
    for i in 0..n {
        out.extend_from_slice(&values.get(i).copied().unwrap_or(0.0).to_le_bytes());
    }
}
