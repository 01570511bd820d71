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
    let joint_by_name = |name: &str| -> Result<json::Index<json::Node>, ExportError> {
        let joints = &root.skins[0].joints;
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
        targets.push(joint_by_name(&name)?);
    }
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
        let offset = [0, 1, 2].map(|k| here[k] - there[k]);
        if offset.iter().any(|&c| c != 0.0) {
            shift_vec3(&mut root, &mut bin, output, offset)
                .map_err(|p| rig_error(take_glb, p))?;
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
                path: Valid(json::animation::Property::Translation),
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
    for (i, chunk) in bin[start as usize..end as usize].chunks_exact_mut(4).enumerate() {
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
