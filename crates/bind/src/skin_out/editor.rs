//! Appending to the document and its binary chunk: the buffers gathered into one chunk,
//! accessors, skins and their inverse bind matrices, `JOINTS_n`/`WEIGHTS_n`, and a mesh moved
//! to a node of its own.

use nalgebra::Matrix4;
use serde_json::{json, Map, Value};

use mouthpiece_export::asset::{self, shown};

use super::influences;
use super::joints::inverse;
use crate::gltf_read::{LoadedMesh, MAX_FILE_BYTES};
use crate::weights::MAX_INFLUENCES;
use crate::BindError;

/// The input's buffers as one binary chunk (each 8-byte aligned), the views moved to it, and
/// images named by URI inside the input's folder copied in.
pub(super) fn gather_buffers(doc: &mut Value, loaded: &LoadedMesh) -> Result<Vec<u8>, BindError> {
    let d = &loaded.document;
    let mut bin = Vec::new();
    let mut starts = Vec::new();
    for b in &d.buffers {
        while !bin.len().is_multiple_of(8) {
            bin.push(0);
        }
        starts.push(bin.len() as u64);
        bin.extend_from_slice(b);
    }
    if let Some(views) = doc.get_mut("bufferViews").and_then(Value::as_array_mut) {
        for view in views {
            let b = view["buffer"].as_u64().unwrap_or(0) as usize;
            let offset = view["byteOffset"].as_u64().unwrap_or(0);
            view["buffer"] = json!(0);
            view["byteOffset"] = json!(offset + starts.get(b).copied().unwrap_or(0));
        }
    }
    let count = doc["images"].as_array().map_or(0, Vec::len);
    for i in 0..count {
        let Some(uri) = doc["images"][i]["uri"].as_str().map(str::to_owned) else {
            continue;
        };
        if uri.starts_with("data:") {
            continue;
        }
        // The reader refused URIs leading outside the folder; a missing image stays named.
        let Ok(file) = asset::resolve_inside(&d.folder, &uri) else {
            continue;
        };
        let room = (MAX_FILE_BYTES).saturating_sub(bin.len() as u64);
        let bytes = asset::read_bounded(&file, room).map_err(|cause| BindError::BadMesh {
            path: d.folder.join(&uri),
            problem: format!("image {i} (`{}`): {cause}", shown(&uri)),
        })?;
        let mime = if bytes.starts_with(b"\x89PNG") {
            "image/png"
        } else if bytes.starts_with(&[0xFF, 0xD8]) {
            "image/jpeg"
        } else if bytes.get(8..12) == Some(b"WEBP") {
            "image/webp"
        } else {
            // not a format a GLB can carry as it is: keep the URI
            continue;
        };
        while !bin.len().is_multiple_of(8) {
            bin.push(0);
        }
        let offset = bin.len();
        bin.extend_from_slice(&bytes);
        let views = doc["bufferViews"].as_array().map_or(0, Vec::len);
        if doc.get("bufferViews").is_none() {
            doc["bufferViews"] = json!([]);
        }
        doc["bufferViews"].as_array_mut().unwrap().push(json!({
            "buffer": 0, "byteOffset": offset, "byteLength": bytes.len()
        }));
        let image = doc["images"][i].as_object_mut().unwrap();
        image.remove("uri");
        image.insert("bufferView".into(), json!(views));
        image.insert("mimeType".into(), json!(mime));
    }
    Ok(bin)
}

/// Appends to the document and its binary chunk.
pub(super) struct Editor<'a> {
    pub doc: &'a mut Value,
    pub bin: &'a mut Vec<u8>,
}

impl Editor<'_> {
    fn array(&mut self, key: &str) -> &mut Vec<Value> {
        if !self.doc[key].is_array() {
            self.doc[key] = json!([]);
        }
        self.doc[key].as_array_mut().unwrap()
    }

    pub(super) fn push(&mut self, key: &str, v: Value) -> usize {
        let a = self.array(key);
        a.push(v);
        a.len() - 1
    }

    pub(super) fn default_scene(&mut self) -> usize {
        let scene = self.doc["scene"].as_u64().unwrap_or(0) as usize;
        if self.array("scenes").is_empty() {
            self.push("scenes", json!({"nodes": []}));
            self.doc["scene"] = json!(0);
            return 0;
        }
        scene
    }

    pub(super) fn scene_roots(&mut self, scene: usize) -> &mut Vec<Value> {
        let s = &mut self.doc["scenes"][scene];
        if !s["nodes"].is_array() {
            s["nodes"] = json!([]);
        }
        s["nodes"].as_array_mut().unwrap()
    }

    pub(super) fn add_child(&mut self, parent: usize, child: usize) {
        let p = &mut self.doc["nodes"][parent];
        if !p["children"].is_array() {
            p["children"] = json!([]);
        }
        p["children"].as_array_mut().unwrap().push(json!(child));
    }

    /// Bytes in a new view (4-aligned); returns the view.
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        let mut v = json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.push("bufferViews", v)
    }

    fn accessor(
        &mut self,
        bytes: &[u8],
        count: usize,
        ty: &str,
        ct: u32,
        target: Option<u32>,
    ) -> usize {
        let view = self.view(bytes, target);
        self.push(
            "accessors",
            json!({"bufferView": view, "count": count, "type": ty, "componentType": ct}),
        )
    }

    fn matrices(&mut self, ms: &[Matrix4<f64>]) -> usize {
        let mut bytes = Vec::with_capacity(64 * ms.len());
        for m in ms {
            let mut m = *m;
            // an affine matrix's last row is exactly (0, 0, 0, 1)
            m[(3, 0)] = 0.0;
            m[(3, 1)] = 0.0;
            m[(3, 2)] = 0.0;
            m[(3, 3)] = 1.0;
            for c in m.as_slice() {
                bytes.extend_from_slice(&(*c as f32).to_le_bytes());
            }
        }
        self.accessor(&bytes, ms.len(), "MAT4", 5126, None)
    }

    /// A new skin over `joints` (their rest worlds given), for a mesh whose bind is `bind`.
    pub(super) fn new_skin(
        &mut self,
        joints: &[usize],
        worlds: &[Matrix4<f64>],
        bind: &Matrix4<f64>,
    ) -> Result<usize, BindError> {
        let ibm: Vec<Matrix4<f64>> = worlds.iter().map(|w| inverse(w) * bind).collect();
        let acc = self.matrices(&ibm);
        Ok(self.push(
            "skins",
            json!({"joints": joints, "inverseBindMatrices": acc}),
        ))
    }

    /// Appends the mouth's joints to an existing skin; returns the index of the first.
    pub(super) fn extend_skin(
        &mut self,
        loaded: &LoadedMesh,
        skin: usize,
        joints: &[usize],
        worlds: &[Matrix4<f64>],
        bind: &Matrix4<f64>,
    ) -> Result<usize, BindError> {
        let s = &loaded.document.root.skins[skin];
        let first = s.joints.len();
        let mut ibm = match s.inverse_bind_matrices {
            Some(a) => crate::gltf_read::inverse_bind_matrices(
                &loaded.document.root,
                &loaded.document.buffers,
                a.value(),
                first,
            )
            .map_err(|e| BindError::Geometry(format!("skin {skin}: {e}")))?,
            None => vec![Matrix4::identity(); first],
        };
        ibm.truncate(first);
        ibm.extend(worlds.iter().map(|w| inverse(w) * bind));
        let acc = self.matrices(&ibm);
        let skin_json = &mut self.doc["skins"][skin];
        skin_json["inverseBindMatrices"] = json!(acc);
        let list = skin_json["joints"].as_array_mut().unwrap();
        list.extend(joints.iter().map(|j| json!(j)));
        Ok(first)
    }

    /// Moves `node`'s mesh (and morph weights, and their animation) to a new node at the
    /// scene's root; the old node keeps its place, transform and children.
    pub(super) fn move_mesh(&mut self, node: usize, scene: usize) -> usize {
        let old = self.doc["nodes"][node].as_object_mut().unwrap();
        let name = old.get("name").and_then(Value::as_str).map(str::to_owned);
        let mut moved = Map::new();
        for key in ["mesh", "weights"] {
            if let Some(v) = old.remove(key) {
                moved.insert(key.into(), v);
            }
        }
        if let Some(name) = &name {
            old.insert("name".into(), json!(format!("{name}_transform")));
            moved.insert("name".into(), json!(name));
        }
        let new = self.push("nodes", Value::Object(moved));
        self.scene_roots(scene).push(json!(new));
        if let Some(anims) = self.doc["animations"].as_array_mut() {
            for a in anims {
                for c in a["channels"].as_array_mut().into_iter().flatten() {
                    let t = &mut c["target"];
                    if t["node"].as_u64() == Some(node as u64) && t["path"] == "weights" {
                        t["node"] = json!(new);
                    }
                }
            }
        }
        new
    }

    /// New `JOINTS_n`/`WEIGHTS_n` for one primitive (as many sets as the rows need).
    pub(super) fn write_weights(
        &mut self,
        mesh: usize,
        primitive: usize,
        rows: &[Vec<(usize, f64)>],
        joints: usize,
    ) {
        let old_sets = (0..8)
            .take_while(|s| {
                self.doc["meshes"][mesh]["primitives"][primitive]["attributes"]
                    .get(format!("JOINTS_{s}"))
                    .is_some()
            })
            .count();
        let sets = old_sets.max(1);
        let wide = joints > 256;
        let slots: Vec<Vec<(usize, f32)>> = rows
            .iter()
            .map(|r| influences(r, MAX_INFLUENCES * sets))
            .collect();
        let attributes = &mut self.doc["meshes"][mesh]["primitives"][primitive]["attributes"];
        if let Some(a) = attributes.as_object_mut() {
            a.retain(|k, _| !(k.starts_with("JOINTS_") || k.starts_with("WEIGHTS_")));
        }
        for set in 0..sets {
            let mut jb = Vec::new();
            let mut wb = Vec::new();
            for row in &slots {
                for k in 0..4 {
                    let (j, w) = row.get(set * 4 + k).copied().unwrap_or((0, 0.0));
                    if wide {
                        jb.extend_from_slice(&(j as u16).to_le_bytes());
                    } else {
                        jb.push(j as u8);
                    }
                    wb.extend_from_slice(&w.to_le_bytes());
                }
            }
            let ct = if wide { 5123 } else { 5121 };
            let ja = self.accessor(&jb, rows.len(), "VEC4", ct, Some(34962));
            let wa = self.accessor(&wb, rows.len(), "VEC4", 5126, Some(34962));
            let attributes = &mut self.doc["meshes"][mesh]["primitives"][primitive]["attributes"];
            attributes[format!("JOINTS_{set}")] = json!(ja);
            attributes[format!("WEIGHTS_{set}")] = json!(wa);
        }
    }
}
