//! A take's animation written onto a rigged mesh (`mouthpiece export --rig`).
//!
//! A rig is a skinned glTF whose joints carry the point names (`P1` …) under a `mouth`
//! joint placed like the export's `mouth` node, so a point's local translation means the same
//! in both: its position in the mouth frame. The take is first written as an ordinary GLB;
//! its animation (samplers, their accessors and bytes) is then copied into the rig's document,
//! each channel retargeted to the rig's joint of the same name.

use std::io::Write;
use std::path::Path;

use gltf_json as json;
use json::validation::{Checked::Valid, USize64};

use crate::{ExportError, PendingFile};

/// A binary glTF's two chunks.
#[derive(Clone, Debug)]
pub struct Glb {
    pub json: Vec<u8>,
    pub bin: Vec<u8>,
}

/// Splits a GLB file into its JSON and binary chunks (the binary chunk may be absent).
pub fn parse_glb(bytes: &[u8]) -> Result<Glb, String> {
    let u32_at = |at: usize| -> Result<u32, String> {
        bytes
            .get(at..at + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| format!("truncated at byte {at}"))
    };
    if bytes.get(0..4) != Some(b"glTF") {
        return Err("no GLB magic".into());
    }
    let version = u32_at(4)?;
    if version != 2 {
        return Err(format!("GLB version {version}, not 2"));
    }
    let total = (u32_at(8)? as usize).min(bytes.len());
    let mut at = 12;
    let mut json_chunk = None;
    let mut bin = Vec::new();
    while at + 8 <= total {
        let len = u32_at(at)? as usize;
        let kind = u32_at(at + 4)?;
        let body = bytes
            .get(at + 8..at + 8 + len)
            .ok_or_else(|| format!("chunk at byte {at} runs past the end of the file"))?;
        match kind {
            0x4E4F_534A => json_chunk = Some(body.to_vec()),
            0x004E_4942 => bin = body.to_vec(),
            _ => {}
        }
        at += 8 + len;
    }
    let json = json_chunk.ok_or("no JSON chunk")?;
    Ok(Glb { json, bin })
}

/// Writes a GLB (chunks padded to 4 bytes: JSON with spaces, binary with zeros).
pub fn write_glb(json: &[u8], bin: &[u8], out: &mut dyn Write) -> std::io::Result<()> {
    let pad = |n: usize| (4 - n % 4) % 4;
    let json_len = json.len() + pad(json.len());
    let bin_len = bin.len() + pad(bin.len());
    let total = 12 + 8 + json_len + if bin.is_empty() { 0 } else { 8 + bin_len };
    let total =
        u32::try_from(total).map_err(|_| std::io::Error::other("more than GLB's 4 GiB limit"))?;
    out.write_all(b"glTF")?;
    out.write_all(&2u32.to_le_bytes())?;
    out.write_all(&total.to_le_bytes())?;
    out.write_all(&(json_len as u32).to_le_bytes())?;
    out.write_all(b"JSON")?;
    out.write_all(json)?;
    out.write_all(&b"   "[..pad(json.len())])?;
    if !bin.is_empty() {
        out.write_all(&(bin_len as u32).to_le_bytes())?;
        out.write_all(b"BIN\0")?;
        out.write_all(bin)?;
        out.write_all(&[0u8; 3][..pad(bin.len())])?;
    }
    Ok(())
}

/// What [`animate_rig`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct RigSummary {
    /// Channels copied onto the rig's joints.
    pub channels: usize,
}

fn rig_error(path: &Path, problem: impl Into<String>) -> ExportError {
    ExportError::Rig {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

/// Largest rig (and take GLB) read by [`animate_rig`]; a bound head is far smaller.
pub const MAX_RIG_BYTES: u64 = 256 * 1024 * 1024;

/// Copies the animation of `take_glb` (a GLB from [`crate::GltfWriter`]) onto the rig
/// `rig_glb` (a GLB from `mouthpiece bind`), writing `out`.
pub fn animate_rig(rig_glb: &Path, take_glb: &Path, out: &Path) -> Result<RigSummary, ExportError> {
    let read = |path: &Path| {
        crate::asset::read_bounded(path, MAX_RIG_BYTES).map_err(|cause| {
            if cause.kind() == std::io::ErrorKind::InvalidData {
                rig_error(path, format!("the file is {cause}: not a rig"))
            } else {
                ExportError::RigRead {
                    path: path.to_path_buf(),
                    cause,
                }
            }
        })
    };
    let rig_bytes = read(rig_glb)?;
    let take_bytes = read(take_glb)?;
    let rigged = animate_rig_bytes(&rig_bytes, rig_glb, &take_bytes, take_glb)?;
    let out_err = |cause: std::io::Error| ExportError::write(out, cause);
    let mut pending = PendingFile::create(out).map_err(out_err)?;
    write_glb(&rigged.json, &rigged.bin, &mut pending).map_err(out_err)?;
    pending.commit().map_err(out_err)?;
    Ok(RigSummary {
        channels: rigged.channels,
    })
}

/// A rig with a take's animation, ready to be written as GLB.
#[derive(Clone, Debug)]
pub struct RiggedGlb {
    pub json: Vec<u8>,
    pub bin: Vec<u8>,
    /// Channels copied onto the rig's joints.
    pub channels: usize,
}

/// [`animate_rig`] on the files' bytes (`rig_glb` and `take_glb` name them in errors; the
/// rig's folder is where its image URIs must stay). Nothing outside the two byte strings is
/// read: the rig's one buffer must be its binary chunk.
pub fn animate_rig_bytes(
    rig_bytes: &[u8],
    rig_glb: &Path,
    take_bytes: &[u8],
    take_glb: &Path,
) -> Result<RiggedGlb, ExportError> {
    let rig = parse_glb(rig_bytes).map_err(|p| rig_error(rig_glb, p))?;
    let mut root: json::Root = serde_json::from_slice(&rig.json)
        .map_err(|e| rig_error(rig_glb, format!("glTF JSON: {e}")))?;
    if root.buffers.len() != 1 || root.buffers[0].uri.is_some() {
        return Err(rig_error(
            rig_glb,
            "expected one buffer, the GLB's binary chunk",
        ));
    }
    let folder = crate::output::parent_dir(rig_glb);
    for (i, image) in root.images.iter().enumerate() {
        if let Some(uri) = image.uri.as_deref().filter(|u| !u.starts_with("data:")) {
            crate::asset::check_inside(folder, uri).map_err(|why| {
                rig_error(
                    rig_glb,
                    format!("image {i}: URI `{}` {why}", crate::asset::shown(uri)),
                )
            })?;
        }
    }
    if root.skins.is_empty() {
        return Err(rig_error(
            rig_glb,
            "no skin: bind the mesh with `mouthpiece bind` first",
        ));
    }
    let nodes = root.nodes.len();
    for (k, joint) in root.skins[0].joints.iter().enumerate() {
        if joint.value() >= nodes {
            return Err(rig_error(
                rig_glb,
                format!(
                    "skin 0: joint {k} is node {}, but the rig has {nodes} nodes",
                    joint.value()
                ),
            ));
        }
    }
    let take = parse_glb(take_bytes).map_err(|p| rig_error(take_glb, p))?;
    let take_root: json::Root = serde_json::from_slice(&take.json)
        .map_err(|e| rig_error(take_glb, format!("glTF JSON: {e}")))?;
    let take_bad = |problem: &str| rig_error(take_glb, problem);
    let mut bin = rig.bin;
    // the skin with the mouth's joints (a rigger's file may have others)
    let mouth_skin = root
        .skins
        .iter()
        .position(|s| {
            s.joints
                .iter()
                .any(|j| root.nodes[j.value()].name.as_deref() == Some("mouth"))
        })
        .unwrap_or(0);
    let joint_by_name = |name: &str| -> Result<json::Index<json::Node>, ExportError> {
        let joints = &root.skins[mouth_skin].joints;
        let found: Vec<_> = joints
            .iter()
            .filter(|j| root.nodes[j.value()].name.as_deref() == Some(name))
            .collect();
        match found.as_slice() {
            [one] => Ok(**one),
            [] => Err(rig_error(
                rig_glb,
                format!(
                    "the take animates point {}, but the rig has no joint of that name",
                    crate::asset::shown(name)
                ),
            )),
            _ => Err(rig_error(
                rig_glb,
                format!("more than one joint is named {}", crate::asset::shown(name)),
            )),
        }
    };
    let mut copied_accessors: std::collections::HashMap<usize, json::Index<json::Accessor>> =
        Default::default();
    let mut channels_out = Vec::new();
    let mut samplers_out = Vec::new();
    let Some(animation) = take_root.animations.first() else {
        return Err(rig_error(
            take_glb,
            "the take has no animation (no point was ever seen)",
        ));
    };
    let mut targets = Vec::new();
    for channel in &animation.channels {
        let name = take_root
            .nodes
            .get(channel.target.node.value())
            .ok_or_else(|| take_bad("a channel animates a node that does not exist"))?
            .name
            .clone()
            .unwrap_or_default();
        // The take's rig nodes a bound mesh has no joints for; the jaw when it has none.
        targets.push(match name.as_str() {
            "blendshapes" | "lip_upper" | "lip_lower" => None,
            "jaw" => joint_by_name(&name).ok(),
            _ => Some(joint_by_name(&name)?),
        });
    }
    let parents = node_parents(&root);
    let rig_jaw = targets
        .iter()
        .flatten()
        .copied()
        .find(|t| root.nodes[t.value()].name.as_deref() == Some("jaw"));
    let jaw_track = match rig_jaw {
        Some(_) => {
            Some(JawTrack::read(&take_root, &take.bin, animation).map_err(|p| take_bad(&p))?)
        }
        None => None,
    };
    let mut copy_accessor = |root: &mut json::Root,
                             bin: &mut Vec<u8>,
                             index: json::Index<json::Accessor>|
     -> Result<json::Index<json::Accessor>, ExportError> {
        if let Some(&done) = copied_accessors.get(&index.value()) {
            return Ok(done);
        }
        let mut accessor = take_root
            .accessors
            .get(index.value())
            .ok_or_else(|| take_bad("a sampler names an accessor that does not exist"))?
            .clone();
        if let Some(view_index) = accessor.buffer_view {
            let view = take_root
                .buffer_views
                .get(view_index.value())
                .ok_or_else(|| take_bad("an accessor names a buffer view that does not exist"))?;
            let start = view.byte_offset.map_or(0, |o| o.0);
            let bytes = start
                .checked_add(view.byte_length.0)
                .and_then(|end| {
                    take.bin
                        .get(usize::try_from(start).ok()?..usize::try_from(end).ok()?)
                })
                .ok_or_else(|| take_bad("a buffer view runs past the binary chunk"))?;
            while !bin.len().is_multiple_of(4) {
                bin.push(0);
            }
            let offset = bin.len();
            bin.extend_from_slice(bytes);
            let mut view = view.clone();
            view.buffer = json::Index::new(0);
            view.byte_offset = Some(USize64(offset as u64));
            accessor.buffer_view = Some(root.push(view));
        }
        let new = root.push(accessor);
        copied_accessors.insert(index.value(), new);
        Ok(new)
    };
    for (channel, target) in animation.channels.iter().zip(targets) {
        let Some(target) = target else { continue };
        let sampler = animation
            .samplers
            .get(channel.sampler.value())
            .ok_or_else(|| take_bad("a channel names a sampler that does not exist"))?;
        let input = copy_accessor(&mut root, &mut bin, sampler.input)?;
        let output = copy_accessor(&mut root, &mut bin, sampler.output)?;
        // A joint placed elsewhere than the take's point (a rigger's own mouth points) keeps
        // the take's motion from its own rest: every key moves by the difference.
        let rest = |n: Option<&json::Node>| n.and_then(|n| n.translation).unwrap_or([0.0; 3]);
        let here = rest(root.nodes.get(target.value()));
        let there = rest(take_root.nodes.get(channel.target.node.value()));
        let on_jaw = rig_jaw.is_some() && parents[target.value()] == rig_jaw.map(|j| j.value());
        let translation = channel.target.path == Valid(json::animation::Property::Translation);
        if let (true, true, Some(jaw), Some(track)) = (on_jaw, translation, rig_jaw, &jaw_track) {
            // A lower-lip joint rides on the jaw: its key, a position in the mouth frame, is
            // taken into the jaw's frame at the same time.
            let jaw_rest = rest(root.nodes.get(jaw.value()));
            let mouth_rest = [0, 1, 2].map(|k| jaw_rest[k] + here[k]);
            let offset = [0, 1, 2].map(|k| mouth_rest[k] - there[k]);
            let jaw_offset = [0, 1, 2].map(|k| jaw_rest[k] - track.rest[k]);
            let times =
                read_f32s(&take_root, &take.bin, sampler.input, 1).map_err(|p| take_bad(&p))?;
            into_jaw(
                &mut root, &mut bin, output, &times, track, offset, jaw_offset,
            )
            .map_err(|p| rig_error(take_glb, p))?;
        } else if translation {
            let offset = [0, 1, 2].map(|k| here[k] - there[k]);
            if offset.iter().any(|&c| c != 0.0) {
                shift_vec3(&mut root, &mut bin, output, offset)
                    .map_err(|p| rig_error(take_glb, p))?;
            }
        }
        let index = json::Index::new(samplers_out.len() as u32);
        samplers_out.push(json::animation::Sampler {
            input,
            output,
            ..sampler.clone()
        });
        channels_out.push(json::animation::Channel {
            sampler: index,
            target: json::animation::Target {
                node: target,
                path: channel.target.path,
                extensions: None,
                extras: Default::default(),
            },
            extensions: None,
            extras: Default::default(),
        });
    }
    let channels = channels_out.len();
    root.push(json::Animation {
        extensions: None,
        extras: Default::default(),
        channels: channels_out,
        name: Some("take".into()),
        samplers: samplers_out,
    });
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    root.buffers[0].byte_length = USize64(bin.len() as u64);
    let json = serde_json::to_vec(&root).map_err(ExportError::Serialize)?;
    Ok(RiggedGlb {
        json,
        bin,
        channels,
    })
}

/// Each node's parent.
fn node_parents(root: &json::Root) -> Vec<Option<usize>> {
    let mut parents = vec![None; root.nodes.len()];
    for (i, n) in root.nodes.iter().enumerate() {
        for c in n.children.iter().flatten() {
            if let Some(p) = parents.get_mut(c.value()) {
                *p = Some(i);
            }
        }
    }
    parents
}

/// A tightly packed `FLOAT` accessor of `width` components from a GLB's binary chunk.
fn read_f32s(
    root: &json::Root,
    bin: &[u8],
    accessor: json::Index<json::Accessor>,
    width: usize,
) -> Result<Vec<f32>, String> {
    use json::accessor::{ComponentType as C, GenericComponentType as G};
    let a = root
        .accessors
        .get(accessor.value())
        .ok_or("an accessor does not exist")?;
    if !matches!(a.component_type, Valid(G(C::F32))) {
        return Err("a key accessor is not FLOAT".into());
    }
    let view = a
        .buffer_view
        .and_then(|v| root.buffer_views.get(v.value()))
        .ok_or("a key accessor has no buffer view")?;
    if view.byte_stride.is_some_and(|s| s.0 != 4 * width) {
        return Err("a key accessor is interleaved".into());
    }
    let start = view.byte_offset.map_or(0, |o| o.0) + a.byte_offset.map_or(0, |o| o.0);
    let end = a
        .count
        .0
        .checked_mul(4 * width as u64)
        .and_then(|n| n.checked_add(start))
        .filter(|&e| e <= view.byte_offset.map_or(0, |o| o.0) + view.byte_length.0)
        .filter(|&e| e <= bin.len() as u64)
        .ok_or("a key accessor runs past its buffer view")?;
    Ok(bin[start as usize..end as usize]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect())
}

/// The take's jaw: its rotation and translation keys, and its node's rest translation.
struct JawTrack {
    times: Vec<f32>,
    rotations: Vec<[f32; 4]>,
    translations: Vec<[f32; 3]>,
    rest: [f32; 3],
}

impl JawTrack {
    fn read(take: &json::Root, bin: &[u8], animation: &json::Animation) -> Result<Self, String> {
        let jaw = take
            .nodes
            .iter()
            .position(|n| n.name.as_deref() == Some("jaw"))
            .ok_or("the take has no jaw")?;
        let keys = |path: json::animation::Property, width: usize| -> Result<_, String> {
            let channel = animation
                .channels
                .iter()
                .find(|c| c.target.node.value() == jaw && c.target.path == Valid(path))
                .ok_or("the take's jaw has no keys")?;
            let sampler = animation
                .samplers
                .get(channel.sampler.value())
                .ok_or("a channel names a sampler that does not exist")?;
            Ok((
                read_f32s(take, bin, sampler.input, 1)?,
                read_f32s(take, bin, sampler.output, width)?,
            ))
        };
        let (times, r) = keys(json::animation::Property::Rotation, 4)?;
        let (t_times, t) = keys(json::animation::Property::Translation, 3)?;
        if times != t_times || r.len() != 4 * times.len() || t.len() != 3 * times.len() {
            return Err("the take's jaw rotation and translation keys do not match".into());
        }
        Ok(Self {
            rotations: r
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            translations: t.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            times,
            rest: take.nodes[jaw].translation.unwrap_or([0.0; 3]),
        })
    }

    /// The jaw at time `t`: its rotation and translation, interpolated between its keys
    /// (linear, the rotation normalised), held before the first and after the last.
    fn at(&self, t: f32) -> (nalgebra::UnitQuaternion<f64>, nalgebra::Vector3<f64>) {
        let n = self.times.len();
        let i = self.times.partition_point(|&k| k <= t);
        let (a, b, f) = match i {
            0 => (0, 0, 0.0),
            i if i >= n => (n - 1, n - 1, 0.0),
            i => {
                let (t0, t1) = (self.times[i - 1], self.times[i]);
                let f = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
                (i - 1, i, f as f64)
            }
        };
        let lerp = |x: f32, y: f32| x as f64 + f * (y as f64 - x as f64);
        let (qa, mut qb) = (self.rotations[a], self.rotations[b]);
        if qa.iter().zip(&qb).map(|(x, y)| x * y).sum::<f32>() < 0.0 {
            qb = qb.map(|c| -c);
        }
        let q: [f64; 4] = std::array::from_fn(|k| lerp(qa[k], qb[k]));
        let rotation = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q[3], q[0], q[1], q[2],
        ));
        let (ta, tb) = (self.translations[a], self.translations[b]);
        let translation =
            nalgebra::Vector3::new(lerp(ta[0], tb[0]), lerp(ta[1], tb[1]), lerp(ta[2], tb[2]));
        (rotation, translation)
    }
}

/// Takes a lower-lip joint's copied keys (mouth-frame positions, moved by `offset`) into the
/// frame of the rig's jaw at each key's time (the take's jaw moved by `jaw_offset`).
fn into_jaw(
    root: &mut json::Root,
    bin: &mut [u8],
    accessor: json::Index<json::Accessor>,
    times: &[f32],
    jaw: &JawTrack,
    offset: [f32; 3],
    jaw_offset: [f32; 3],
) -> Result<(), String> {
    let keys = read_f32s(root, bin, accessor, 3)?;
    if keys.len() != 3 * times.len() {
        return Err("a lip's keys and times differ in number".into());
    }
    let mut out = Vec::with_capacity(keys.len());
    for (k, &t) in times.iter().enumerate() {
        let (r, tr) = jaw.at(t);
        let p = nalgebra::Vector3::from(std::array::from_fn(|c| {
            keys[3 * k + c] as f64 + offset[c] as f64
        }));
        let jaw_at = tr + nalgebra::Vector3::from(jaw_offset.map(f64::from));
        let local = r.inverse() * (p - jaw_at);
        out.extend(local.iter().map(|&c| c as f32));
    }
    let a = &mut root.accessors[accessor.value()];
    let view = &root.buffer_views[a.buffer_view.expect("read above").value()];
    let start = (view.byte_offset.map_or(0, |o| o.0) + a.byte_offset.map_or(0, |o| o.0)) as usize;
    for (i, v) in out.iter().enumerate() {
        bin[start + 4 * i..start + 4 * i + 4].copy_from_slice(&v.to_le_bytes());
    }
    a.min = None;
    a.max = None;
    Ok(())
}

/// Adds `offset` to every element of a copied, tightly packed `VEC3` of `FLOAT` accessor
/// (its bytes are this document's own copy), dropping its bounds.
fn shift_vec3(
    root: &mut json::Root,
    bin: &mut [u8],
    accessor: json::Index<json::Accessor>,
    offset: [f32; 3],
) -> Result<(), String> {
    use json::accessor::{ComponentType as C, GenericComponentType as G, Type};
    let a = &mut root.accessors[accessor.value()];
    if a.type_ != Valid(Type::Vec3) || !matches!(a.component_type, Valid(G(C::F32))) {
        return Err("a translation channel's keys are not VEC3 of FLOAT".into());
    }
    let view = a
        .buffer_view
        .and_then(|v| root.buffer_views.get(v.value()))
        .ok_or("a translation channel's keys have no buffer view")?;
    if view.byte_stride.is_some_and(|s| s.0 != 12) {
        return Err("a translation channel's keys are interleaved".into());
    }
    let start = view.byte_offset.map_or(0, |o| o.0) + a.byte_offset.map_or(0, |o| o.0);
    let end = a
        .count
        .0
        .checked_mul(12)
        .and_then(|n| n.checked_add(start))
        .filter(|&e| e <= view.byte_offset.map_or(0, |o| o.0) + view.byte_length.0)
        .filter(|&e| e <= bin.len() as u64)
        .ok_or("a translation channel's keys run past their buffer view")?;
    for (i, chunk) in bin[start as usize..end as usize]
        .chunks_exact_mut(4)
        .enumerate()
    {
        let v = f32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]) + offset[i % 3];
        chunk.copy_from_slice(&v.to_le_bytes());
    }
    a.min = None;
    a.max = None;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glb_round_trips_with_padding() {
        let mut out = Vec::new();
        write_glb(b"{\"a\":1}", &[1, 2, 3, 4, 5], &mut out).unwrap();
        assert_eq!(out.len() % 4, 0);
        let glb = parse_glb(&out).unwrap();
        assert_eq!(glb.json.trim_ascii_end(), b"{\"a\":1}");
        assert_eq!(&glb.bin[..5], &[1, 2, 3, 4, 5]);
        assert!(parse_glb(b"nope").unwrap_err().contains("magic"));
    }

    fn glb(doc: serde_json::Value) -> Vec<u8> {
        let mut out = Vec::new();
        write_glb(&serde_json::to_vec(&doc).unwrap(), &[0; 4], &mut out).unwrap();
        out
    }

    /// A take GLB animating one node, `P1`.
    fn take() -> Vec<u8> {
        glb(serde_json::json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 4}],
            "bufferViews": [{"buffer": 0, "byteLength": 4}],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 1, "type": "SCALAR"},
                {"bufferView": 0, "componentType": 5126, "count": 1, "type": "SCALAR"}
            ],
            "nodes": [{"name": "P1"}],
            "animations": [{
                "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}],
                "samplers": [{"input": 0, "output": 1}]
            }]
        }))
    }

    fn animate(rig: serde_json::Value) -> Result<RiggedGlb, String> {
        animate_rig_bytes(
            &glb(rig),
            Path::new("rig.glb"),
            &take(),
            Path::new("take.glb"),
        )
        .map_err(|e| e.to_string())
    }

    #[test]
    fn joints_past_the_nodes_are_an_error_not_a_panic() {
        let rig = |joints: serde_json::Value| {
            serde_json::json!({
                "asset": {"version": "2.0"},
                "buffers": [{"byteLength": 4}],
                "nodes": [{"name": "root"}, {"name": "P1"}],
                "skins": [{"joints": joints}]
            })
        };
        let done = animate(rig(serde_json::json!([0, 1]))).unwrap();
        assert_eq!(done.channels, 1);
        for joints in [
            serde_json::json!([0, 7]),
            serde_json::json!([4294967295u64]),
        ] {
            let err = animate(rig(joints)).unwrap_err();
            assert!(
                err.contains("rig.glb") && err.contains("skin 0: joint") && err.contains("2 nodes"),
                "{err}"
            );
        }
    }

    #[test]
    fn rig_images_outside_its_folder_are_refused() {
        let err = animate(serde_json::json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 4}],
            "images": [{"uri": "/etc/passwd"}],
            "nodes": [{"name": "P1"}],
            "skins": [{"joints": [0]}]
        }))
        .unwrap_err();
        assert!(
            err.contains("image 0") && err.contains("/etc/passwd"),
            "{err}"
        );
    }
}
