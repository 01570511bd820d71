//! Appending the take's weight animation to the avatar and writing it out: GLB in, GLB out
//! (the data after the binary chunk's bytes); `.gltf` in, `.gltf` out (the data in one new
//! buffer, a base64 `data:` URI, so no file beside the output is written or overwritten).

use std::io::Write;
use std::path::Path;

use serde_json::{json, Value};

use super::{avatar_error, Avatar, Plan, Source};
use crate::{ExportError, PendingFile};

/// Most bytes of animation data `--onto` appends (times and weights, 4 bytes each). The data
/// is streamed into the output (never held in memory, nor its base64 text); the bound keeps
/// a GLB under its 4 GiB and a `.gltf`'s one data URI to a size viewers load.
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
        // Where the data goes: after the GLB's chunk, as the GLB's first buffer, or a new
        // embedded buffer. It is never built in memory: it is written straight into the
        // output (for `.gltf` through a base64 encoder) once the document is complete.
        let buffers = self.doc["buffers"].as_array().map_or(0, Vec::len);
        let glb_chunk = self.glb && buffers > 0 && self.doc["buffers"][0].get("uri").is_none();
        let (buffer, base) = if glb_chunk {
            let head = self.bin.as_ref().map_or(0, Vec::len);
            let base = head.next_multiple_of(4);
            self.doc["buffers"][0]["byteLength"] = json!(base as u64 + bytes);
            (0, base)
        } else if self.glb && buffers == 0 {
            self.doc["buffers"] = json!([{ "byteLength": bytes }]);
            self.bin = None;
            (0, 0)
        } else {
            push(
                &mut self.doc,
                "buffers",
                json!({ "byteLength": bytes, "uri": DATA_PLACEHOLDER }),
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
        let data = |w: &mut dyn Write| -> std::io::Result<()> {
            for t in times {
                w.write_all(&t.to_le_bytes())?;
            }
            for sources in &outputs {
                for frame in values.chunks_exact(curves.max(1)).take(frames) {
                    for source in *sources {
                        let w_value = match *source {
                            Source::Curve(c) => frame[c],
                            Source::Default(w) => w,
                        };
                        w.write_all(&w_value.to_le_bytes())?;
                    }
                }
            }
            Ok(())
        };
        let mut pending = PendingFile::create(out).map_err(out_err)?;
        if self.glb {
            let json = serde_json::to_vec(&self.doc).map_err(ExportError::Serialize)?;
            let head = self.bin.as_deref().unwrap_or_default();
            write_glb_appended(&json, head, base, bytes, data, pending.writer())
                .map_err(out_err)?;
        } else {
            let text = serde_json::to_vec_pretty(&self.doc).map_err(ExportError::Serialize)?;
            let (before, after) =
                split_once(&text, DATA_PLACEHOLDER.as_bytes()).ok_or_else(|| {
                    bad("its JSON already holds mouthpiece's buffer placeholder".into())
                })?;
            let w = pending.writer();
            w.write_all(before).map_err(out_err)?;
            w.write_all(DATA_URI_PREFIX.as_bytes()).map_err(out_err)?;
            let w = {
                let mut encoder = base64::write::EncoderWriter::new(
                    w,
                    &base64::engine::general_purpose::STANDARD,
                );
                data(&mut encoder).map_err(out_err)?;
                encoder.finish().map_err(out_err)?
            };
            w.write_all(after).map_err(out_err)?;
        }
        pending.commit().map_err(out_err)?;
        Ok(summary)
    }
}

/// The `.gltf` output's new buffer URI while the document is serialised; replaced by the
/// data URI as the file is written. An avatar holding this text anywhere is refused.
const DATA_PLACEHOLDER: &str = "mouthpiece-onto-data-7f3a1c9e";

/// The start of the `.gltf` output's data URI (then the base64 data).
const DATA_URI_PREFIX: &str = "data:application/octet-stream;base64,";

/// `text` around the one occurrence of `needle`; `None` when it is missing or not alone.
fn split_once<'a>(text: &'a [u8], needle: &[u8]) -> Option<(&'a [u8], &'a [u8])> {
    let mut found = text
        .windows(needle.len())
        .enumerate()
        .filter(|(_, w)| *w == needle);
    let (at, _) = found.next()?;
    found
        .next()
        .is_none()
        .then_some((&text[..at], &text[at + needle.len()..]))
}

/// A GLB whose binary chunk is `head`, zeros up to `base`, then `bytes` bytes written by
/// `data` (a multiple of 4: floats), without holding those in memory.
fn write_glb_appended(
    json: &[u8],
    head: &[u8],
    base: usize,
    bytes: u64,
    data: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
    out: &mut dyn Write,
) -> std::io::Result<()> {
    let json_pad = (4 - json.len() % 4) % 4;
    let json_len = (json.len() + json_pad) as u64;
    let bin_len = base as u64 + bytes;
    let total = u32::try_from(12 + 8 + json_len + 8 + bin_len)
        .map_err(|_| std::io::Error::other("more than GLB's 4 GiB limit"))?;
    out.write_all(b"glTF")?;
    out.write_all(&2u32.to_le_bytes())?;
    out.write_all(&total.to_le_bytes())?;
    out.write_all(&(json_len as u32).to_le_bytes())?;
    out.write_all(b"JSON")?;
    out.write_all(json)?;
    out.write_all(&b"   "[..json_pad])?;
    out.write_all(&(bin_len as u32).to_le_bytes())?;
    out.write_all(b"BIN\0")?;
    out.write_all(head)?;
    out.write_all(&[0u8; 3][..base - head.len()])?;
    let mut counted = Counted { out, n: 0 };
    data(&mut counted)?;
    if counted.n != bytes {
        return Err(std::io::Error::other(format!(
            "wrote {} bytes of animation, planned {bytes}",
            counted.n
        )));
    }
    Ok(())
}

/// Counts the bytes written through it.
struct Counted<'a> {
    out: &'a mut dyn Write,
    n: u64,
}

impl Write for Counted<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.out.write(buf)?;
        self.n += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
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
