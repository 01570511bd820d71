//! Appending the take's weight animation to the avatar and writing it out: GLB in, GLB out
//! (the data after the binary chunk's bytes); `.gltf` in, `.gltf` out (the data in one new
//! buffer, a base64 `data:` URI, so no file beside the output is written or overwritten).

use std::path::Path;

use serde_json::{json, Value};

use super::{avatar_error, Avatar, Plan, Source};
use crate::onto_rig::write_glb;
use crate::{ExportError, PendingFile};

/// Most bytes of animation data `--onto` appends (times and weights, 4 bytes each): guards
/// memory (the data, and for `.gltf` its base64 text, are built in memory).
pub const MAX_ADDED_BYTES: u64 = 1024 * 1024 * 1024;

/// What [`Avatar::write_onto`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct OntoSummary {
    pub frames: usize,
    /// `weights` channels (one per animated node).
    pub channels: usize,
    /// Bytes of animation data appended.
    pub bytes: u64,
}

impl Avatar {
    /// Appends one animation named `take`: keys at `times` (seconds, strictly increasing as
    /// f32), each frame's curve values in `values` (`curves` per frame, the [`Plan`]'s curve
    /// indices), and writes the avatar to `out` (GLB when `glb_out`; it must be the avatar's
    /// own format). `out` appears complete or not at all.
    pub fn write_onto(
        mut self,
        plan: &Plan,
        times: &[f32],
        values: &[f32],
        curves: usize,
        out: &Path,
        glb_out: bool,
    ) -> Result<OntoSummary, ExportError> {
        let bad = |problem: String| avatar_error(&self.path, problem);
        if glb_out != self.glb {
            return Err(bad(format!(
                "the avatar is {}, so the output is too: give --out NAME.{}",
                if self.glb { "GLB" } else { ".gltf JSON" },
                if self.glb { "glb" } else { "gltf" }
            )));
        }
        if self.external_files && !same_folder(&self.path, out) {
            return Err(bad(format!(
                "it names buffer or image files by relative URIs, so the output must be written \
                 in the same folder ({}), where they resolve",
                crate::output::parent_dir(&self.path).display()
            )));
        }
        let frames = times.len();
        assert_eq!(
            values.len(),
            frames * curves,
            "one value per curve and frame"
        );
        // Meshes with the same sources share one sampler output.
        let mut outputs: Vec<&[Source]> = Vec::new();
        let mut mesh_output = Vec::new();
        for mesh in &plan.meshes {
            let k = match outputs.iter().position(|o| *o == mesh.sources.as_slice()) {
                Some(k) => k,
                None => {
                    outputs.push(&mesh.sources);
                    outputs.len() - 1
                }
            };
            mesh_output.push(k);
        }
        let weights: u64 = outputs.iter().map(|o| o.len() as u64).sum();
        let bytes = (frames as u64)
            .checked_mul(weights + 1)
            .and_then(|n| n.checked_mul(4))
            .filter(|&b| b <= MAX_ADDED_BYTES)
            .ok_or_else(|| {
                bad(format!(
                    "the animation needs {frames} frames × {} weights of 4 bytes, more than the \
                     {MAX_ADDED_BYTES} bytes --onto appends",
                    weights
                ))
            })?;
        let mut data = Vec::with_capacity(bytes as usize);
        for t in times {
            data.extend_from_slice(&t.to_le_bytes());
        }
        for sources in &outputs {
            for frame in values.chunks_exact(curves.max(1)).take(frames) {
                for source in *sources {
                    let w = match *source {
                        Source::Curve(c) => frame[c],
                        Source::Default(w) => w,
                    };
                    data.extend_from_slice(&w.to_le_bytes());
                }
            }
        }
        // Where the data goes: after the GLB's chunk, as the GLB's first buffer, or a new
        // embedded buffer.
        let buffers = self.doc["buffers"].as_array().map_or(0, Vec::len);
        let glb_chunk = self.glb && buffers > 0 && self.doc["buffers"][0].get("uri").is_none();
        let (buffer, base) = if glb_chunk {
            let bin = self.bin.get_or_insert_with(Vec::new);
            while !bin.len().is_multiple_of(4) {
                bin.push(0);
            }
            let base = bin.len();
            bin.extend_from_slice(&data);
            self.doc["buffers"][0]["byteLength"] = json!(bin.len());
            (0, base)
        } else if self.glb && buffers == 0 {
            self.doc["buffers"] = json!([{ "byteLength": data.len() }]);
            self.bin = Some(data.clone());
            (0, 0)
        } else {
            use base64::Engine as _;
            let uri = format!(
                "data:application/octet-stream;base64,{}",
                base64::engine::general_purpose::STANDARD.encode(&data)
            );
            push(
                &mut self.doc,
                "buffers",
                json!({ "byteLength": data.len(), "uri": uri }),
            );
            (buffers, 0)
        };
        let add_accessor = |doc: &mut Value,
                            offset: usize,
                            count: usize,
                            bounds: Option<(f32, f32)>| {
            let view = push(
                doc,
                "bufferViews",
                json!({ "buffer": buffer, "byteOffset": base + offset, "byteLength": count * 4 }),
            );
            let mut accessor = json!({
                "bufferView": view, "componentType": 5126, "count": count, "type": "SCALAR"
            });
            if let Some((min, max)) = bounds {
                accessor["min"] = json!([min]);
                accessor["max"] = json!([max]);
            }
            push(doc, "accessors", accessor)
        };
        let first = times.first().copied().unwrap_or(0.0);
        let last = times.last().copied().unwrap_or(0.0);
        let input = add_accessor(&mut self.doc, 0, frames, Some((first, last)));
        let mut offset = frames * 4;
        let mut samplers = Vec::new();
        for sources in &outputs {
            let count = frames * sources.len();
            let output = add_accessor(&mut self.doc, offset, count, None);
            offset += count * 4;
            samplers.push(json!({ "input": input, "output": output, "interpolation": "LINEAR" }));
        }
        let mut channels = Vec::new();
        for (mesh, &sampler) in plan.meshes.iter().zip(&mesh_output) {
            for &(node, _) in &self.meshes[mesh.mesh].nodes {
                channels.push(json!({
                    "sampler": sampler,
                    "target": { "node": node, "path": "weights" }
                }));
            }
        }
        let summary = OntoSummary {
            frames,
            channels: channels.len(),
            bytes,
        };
        push(
            &mut self.doc,
            "animations",
            json!({ "name": "take", "samplers": samplers, "channels": channels }),
        );
        let out_err = |cause: std::io::Error| ExportError::write(out, cause);
        let mut pending = PendingFile::create(out).map_err(out_err)?;
        if self.glb {
            let json = serde_json::to_vec(&self.doc).map_err(ExportError::Serialize)?;
            let bin = self.bin.as_deref().unwrap_or_default();
            write_glb(&json, bin, pending.writer()).map_err(out_err)?;
        } else {
            serde_json::to_writer_pretty(pending.writer(), &self.doc)
                .map_err(ExportError::Serialize)?;
        }
        pending.commit().map_err(out_err)?;
        Ok(summary)
    }
}

/// Appends `item` to the array `doc[key]` (made when absent) and returns its index.
fn push(doc: &mut Value, key: &str, item: Value) -> usize {
    let list = doc
        .as_object_mut()
        .expect("checked: the document is an object")
        .entry(key)
        .or_insert_with(|| json!([]));
    let list = list.as_array_mut().expect("checked: an array");
    list.push(item);
    list.len() - 1
}

/// Whether `a` and `b` are in the same folder (compared canonically).
fn same_folder(a: &Path, b: &Path) -> bool {
    let folder = |p: &Path| crate::output::parent_dir(p).canonicalize().ok();
    matches!((folder(a), folder(b)), (Some(x), Some(y)) if x == y)
}
