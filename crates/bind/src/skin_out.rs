//! The bound output: the input glTF document with a skin added, nothing else changed.
//!
//! The document is edited as JSON, so every attribute, material, texture, morph target, node,
//! animation, extension and extra the input had is written back as it was. What changes:
//!
//! - the buffers become the GLB's one binary chunk (each input buffer copied in, its views
//!   moved by its offset there); images named by a URI inside the input's folder are copied
//!   into it too (so the GLB stands on its own);
//! - new nodes: `mouth` (the character's mouth frame) under the parent joint, `jaw` under it
//!   when there is one, and the points `P1` … under `mouth` (lower-lip points under `jaw`);
//!   without a parent joint a new `root` node at the scene's root is the parent;
//! - skins: a face already skinned keeps its skin, extended by the new joints (and their
//!   inverse bind matrices); an unskinned face or part gets a new skin; new `JOINTS_n` and
//!   `WEIGHTS_n` accessors replace the primitive's. glTF ignores a skinned node's own
//!   transform, so an unskinned mesh on a node that has a transform or a parent moves to a
//!   new node at the scene's root (its transform goes into the inverse bind matrices, and
//!   animations of its morph weights follow it); the old node stays where it was, named
//!   `NAME_transform`, with its children.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, UnitQuaternion, Vector3};
use serde_json::{json, Map, Value};

use mouthpiece_export::asset::{self, shown};
use mouthpiece_export::onto_rig::write_glb;
use mouthpiece_export::{MouthRig, PendingFile};

use crate::gltf_read::{read_skin_weights, LoadedMesh, MAX_FILE_BYTES};
use crate::weights::MAX_INFLUENCES;
use crate::BindError;

/// What a vertex's weight goes to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Target {
    /// Mouth point k (0-based).
    Point(usize),
    /// The jaw joint.
    Jaw,
    /// The parent joint (the head): for a vertex of a mesh that already had a skin, its
    /// weights from that skin, scaled.
    Parent,
}

/// How one mesh instance is bound.
#[derive(Clone, Debug)]
pub enum Binding {
    /// Left as it is (a part already skinned, or a node without a mesh).
    Keep,
    /// Follows one joint rigidly (eyes and upper teeth the head, lower teeth and tongue the
    /// jaw).
    Rigid(Target),
    /// The face: one weight list per vertex of each of its primitives, in the order of
    /// [`crate::gltf_read::Instance::primitives`].
    Face(Vec<Vec<Vec<(Target, f64)>>>),
}

/// What the output's rig looks like.
#[derive(Clone, Debug)]
pub struct RigPlan<'a> {
    pub rig: &'a MouthRig,
    /// Mouth frame → the file's frame.
    pub placement: Isometry3<f64>,
    /// The node the mouth hangs under (none: a new `root` node).
    pub parent: Option<usize>,
    /// The jaw's hinge in the mouth frame, when there is a jaw; the points whose joints ride
    /// on it.
    pub jaw: Option<([f64; 3], Vec<usize>)>,
    pub generator: String,
}

/// Below this much weight on the mouth's joints a vertex of an already skinned face keeps
/// its skin's weights exactly.
pub const MOUTH_REGION: f64 = 0.01;

/// Writes the bound GLB: `bindings` has one entry per instance of `loaded`.
pub fn write_bound(
    out: &Path,
    loaded: &LoadedMesh,
    plan: &RigPlan,
    bindings: &[Binding],
) -> Result<(), BindError> {
    let mut doc = loaded.document.json.clone();
    let mut bin = gather_buffers(&mut doc, loaded)?;
    let mut ed = Editor {
        doc: &mut doc,
        bin: &mut bin,
    };
    let scene = ed.default_scene();
    // the joints
    let parent = match plan.parent {
        Some(p) => p,
        None => {
            let root = ed.push("nodes", json!({"name": "root"}));
            ed.scene_roots(scene).push(json!(root));
            root
        }
    };
    let parent_world = world_of(&loaded.document, ed.doc, parent);
    let mouth_world = plan.placement.to_homogeneous();
    let (mouth_local, mouth_world) = trs(&(inverse(&parent_world) * mouth_world));
    let mouth = ed.push("nodes", with_trs(json!({"name": "mouth"}), &mouth_local));
    ed.add_child(parent, mouth);
    let mouth_world = parent_world * mouth_world;
    let mut worlds: HashMap<Target, Matrix4<f64>> = HashMap::new();
    let mut nodes: HashMap<Target, usize> = HashMap::new();
    nodes.insert(Target::Parent, parent);
    worlds.insert(Target::Parent, parent_world);
    let mut jaw_world = mouth_world;
    if let Some((hinge, _)) = &plan.jaw {
        let local = Matrix4::new_translation(&Vector3::from(*hinge));
        let (local, m) = trs(&local);
        let jaw = ed.push("nodes", with_trs(json!({"name": "jaw"}), &local));
        ed.add_child(mouth, jaw);
        jaw_world = mouth_world * m;
        nodes.insert(Target::Jaw, jaw);
        worlds.insert(Target::Jaw, jaw_world);
    }
    let on_jaw = |k: usize| plan.jaw.as_ref().is_some_and(|(_, pts)| pts.contains(&k));
    for (k, p) in plan.rig.points().iter().enumerate() {
        let (holder, holder_world, rest) = match &plan.jaw {
            Some((hinge, _)) if on_jaw(k) => (
                nodes[&Target::Jaw],
                jaw_world,
                [
                    p.rest[0] - hinge[0],
                    p.rest[1] - hinge[1],
                    p.rest[2] - hinge[2],
                ],
            ),
            _ => (mouth, mouth_world, p.rest),
        };
        let (local, m) = trs(&Matrix4::new_translation(&Vector3::from(rest)));
        let node = ed.push("nodes", with_trs(json!({ "name": p.name }), &local));
        ed.add_child(holder, node);
        nodes.insert(Target::Point(k), node);
        worlds.insert(Target::Point(k), holder_world * m);
    }
    let mut new_joints: Vec<Target> = Vec::new();
    if plan.jaw.is_some() {
        new_joints.push(Target::Jaw);
    }
    new_joints.extend((0..plan.rig.points().len()).map(Target::Point));
    let mouth_joint_nodes: Vec<usize> = std::iter::once(mouth)
        .chain(new_joints.iter().map(|t| nodes[t]))
        .collect();
    let mouth_joint_worlds: Vec<Matrix4<f64>> = std::iter::once(mouth_world)
        .chain(new_joints.iter().map(|t| worlds[t]))
        .collect();

    // each instance
    let root = &loaded.document.root;
    let mut extended: HashMap<usize, usize> = HashMap::new(); // skin → its first new joint
    let mut mesh_users: HashMap<usize, usize> = HashMap::new();
    for node in &root.nodes {
        if let Some(m) = node.mesh {
            *mesh_users.entry(m.value()).or_default() += 1;
        }
    }
    for (instance, binding) in loaded.instances.iter().zip(bindings) {
        let Some(node) = instance.node else { continue };
        let rows: Vec<Vec<Vec<(usize, f64)>>>;
        let skin_joints: usize;
        let mut skin_index = None;
        match (binding, instance.skin) {
            (Binding::Keep, _) | (Binding::Rigid(_), Some(_)) => continue,
            (Binding::Rigid(target), None) => {
                let skin = ed.new_skin(&[nodes[target]], &[worlds[target]], &instance.bind)?;
                skin_index = Some(skin);
                skin_joints = 1;
                rows = instance
                    .primitives
                    .iter()
                    .map(|&(_, _, count)| vec![vec![(0, 1.0)]; count as usize])
                    .collect();
            }
            (Binding::Face(face), None) => {
                let mut joints = vec![parent];
                joints.extend(&mouth_joint_nodes);
                let mut jw = vec![parent_world];
                jw.extend(&mouth_joint_worlds);
                let skin = ed.new_skin(&joints, &jw, &instance.bind)?;
                skin_index = Some(skin);
                skin_joints = joints.len();
                let column = |t: &Target| match t {
                    Target::Parent => 0,
                    t => 2 + new_joints.iter().position(|n| n == t).unwrap_or(0),
                };
                rows = face
                    .iter()
                    .map(|prim| {
                        prim.iter()
                            .map(|row| row.iter().map(|(t, w)| (column(t), *w)).collect())
                            .collect()
                    })
                    .collect();
            }
            (Binding::Face(face), Some(skin)) => {
                // the parent joins the skin too when it is not one of its joints
                let parent_column = root.skins[skin]
                    .joints
                    .iter()
                    .position(|j| j.value() == parent);
                let mut add_nodes = Vec::new();
                let mut add_worlds = Vec::new();
                if parent_column.is_none() {
                    add_nodes.push(parent);
                    add_worlds.push(parent_world);
                }
                add_nodes.extend(&mouth_joint_nodes);
                add_worlds.extend(&mouth_joint_worlds);
                let first = match extended.get(&skin) {
                    Some(&f) => f,
                    None => {
                        let f =
                            ed.extend_skin(loaded, skin, &add_nodes, &add_worlds, &instance.bind)?;
                        extended.insert(skin, f);
                        f
                    }
                };
                skin_joints = first + add_nodes.len();
                // columns: the parent (old or first added), mouth, then the new joints
                let (parent_at, mouth_at) = match parent_column {
                    Some(c) => (c, first),
                    None => (first, first + 1),
                };
                let column = |t: &Target| match t {
                    Target::Parent => parent_at,
                    t => mouth_at + 1 + new_joints.iter().position(|n| n == t).unwrap_or(0),
                };
                let mesh = &root.meshes[instance.mesh];
                let mut all = Vec::new();
                for ((p, _, count), prim_rows) in instance.primitives.iter().zip(face) {
                    let existing = read_skin_weights(
                        root,
                        &loaded.document.buffers,
                        &mesh.primitives[*p],
                        *count as usize,
                    )
                    .map_err(|e| ed_error(loaded, instance, *p, e))?;
                    all.push(
                        prim_rows
                            .iter()
                            .zip(existing)
                            .map(|(row, old)| merge_existing(row, &old, &column))
                            .collect(),
                    );
                }
                rows = all;
            }
        }
        // the node that carries the skin, and its mesh (a copy when others share it)
        let mesh_index = if mesh_users[&instance.mesh] > 1 {
            let copy = ed.doc["meshes"][instance.mesh].clone();
            ed.push("meshes", copy)
        } else {
            instance.mesh
        };
        let holder = match (
            skin_index,
            needs_moving(ed.doc, &loaded.document.parents, node),
        ) {
            (Some(_), true) => ed.move_mesh(node, scene),
            _ => node,
        };
        ed.doc["nodes"][holder]["mesh"] = json!(mesh_index);
        if let Some(skin) = skin_index {
            ed.doc["nodes"][holder]["skin"] = json!(skin);
        }
        for ((p, _, _), prim_rows) in instance.primitives.iter().zip(&rows) {
            ed.write_weights(mesh_index, *p, prim_rows, skin_joints);
        }
    }
    // buffers: the one binary chunk
    while !ed.bin.len().is_multiple_of(4) {
        ed.bin.push(0);
    }
    let len = ed.bin.len();
    doc["buffers"] = json!([{ "byteLength": len }]);
    if len as u64 > MAX_FILE_BYTES + (64 << 20) {
        return Err(BindError::Write {
            path: out.to_path_buf(),
            cause: std::io::Error::other("the output would be larger than GLB allows"),
        });
    }
    let text = serde_json::to_vec(&doc).map_err(|e| BindError::Write {
        path: out.to_path_buf(),
        cause: std::io::Error::other(e),
    })?;
    let err = |cause| BindError::Write {
        path: out.to_path_buf(),
        cause,
    };
    let mut pending = PendingFile::create(out).map_err(err)?;
    write_glb(&text, &bin, &mut pending).map_err(err)?;
    pending.commit().map_err(err)
}

fn ed_error(
    loaded: &LoadedMesh,
    instance: &crate::gltf_read::Instance,
    primitive: usize,
    problem: String,
) -> BindError {
    BindError::Geometry(format!(
        "{} primitive {primitive}: its skin weights: {problem}",
        instance.describe(&loaded.document.root)
    ))
}

/// A face vertex's weights on a skin it already had: the mouth's joints as bound, the rest
/// (the parent's share) spread over the vertex's old weights; a vertex with less than
/// [`MOUTH_REGION`] on the mouth keeps its old weights exactly.
fn merge_existing(
    row: &[(Target, f64)],
    old: &[(u16, f64)],
    column: &impl Fn(&Target) -> usize,
) -> Vec<(usize, f64)> {
    let old_sum: f64 = old.iter().map(|(_, w)| w).sum();
    let mouth: f64 = row
        .iter()
        .filter(|(t, _)| *t != Target::Parent)
        .map(|(_, w)| w)
        .sum();
    if old_sum <= 0.0 {
        return row.iter().map(|(t, w)| (column(t), *w)).collect();
    }
    if mouth < MOUTH_REGION {
        return old.iter().map(|&(j, w)| (j as usize, w)).collect();
    }
    let mut out = Vec::new();
    for (t, w) in row {
        match t {
            Target::Parent => out.extend(old.iter().map(|&(j, o)| (j as usize, w * o / old_sum))),
            t => out.push((column(t), *w)),
        }
    }
    out
}

/// Sums duplicate joints, keeps the `k` largest, normalises in f32 (the residue to the
/// largest): the (joint, weight) slots of one vertex.
pub fn influences(row: &[(usize, f64)], k: usize) -> Vec<(usize, f32)> {
    let mut merged: Vec<(usize, f64)> = Vec::new();
    for &(j, w) in row {
        if w.is_nan() || w <= 0.0 {
            continue;
        }
        match merged.iter_mut().find(|(m, _)| *m == j) {
            Some(m) => m.1 += w,
            None => merged.push((j, w)),
        }
    }
    merged.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    merged.truncate(k);
    let sum: f64 = merged.iter().map(|m| m.1).sum();
    if merged.is_empty() || sum <= 0.0 {
        return vec![(0, 1.0)];
    }
    let mut out: Vec<(usize, f32)> = merged.iter().map(|&(j, w)| (j, (w / sum) as f32)).collect();
    let residue = 1.0 - out.iter().map(|m| m.1).sum::<f32>();
    out[0].1 += residue;
    out
}

/// True when glTF would ignore part of the node's placement once skinned: it has a parent
/// or a transform of its own.
fn needs_moving(doc: &Value, parents: &[Option<usize>], node: usize) -> bool {
    let n = &doc["nodes"][node];
    let identity = |key: &str, id: &[f64]| match n.get(key) {
        None => true,
        Some(v) => v
            .as_array()
            .is_some_and(|a| a.iter().zip(id).all(|(x, y)| x.as_f64() == Some(*y))),
    };
    parents.get(node).copied().flatten().is_some()
        || !identity("translation", &[0.0; 3])
        || !identity("rotation", &[0.0, 0.0, 0.0, 1.0])
        || !identity("scale", &[1.0; 3])
        || !identity(
            "matrix",
            &[
                1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
            ],
        )
}

/// The input's buffers as one binary chunk (each 8-byte aligned), the views moved to it, and
/// images named by URI inside the input's folder copied in.
fn gather_buffers(doc: &mut Value, loaded: &LoadedMesh) -> Result<Vec<u8>, BindError> {
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

/// A node's world transform at rest in the edited document: the input's, or for a node
/// added here, its parents' times its own.
fn world_of(d: &crate::gltf_read::Document, _doc: &Value, node: usize) -> Matrix4<f64> {
    d.worlds
        .get(node)
        .copied()
        .unwrap_or_else(Matrix4::identity)
}

fn inverse(m: &Matrix4<f64>) -> Matrix4<f64> {
    m.try_inverse().unwrap_or_else(Matrix4::identity)
}

/// A node's translation, rotation (x, y, z, w) and scale as glTF writes them.
type Trs = ([f32; 3], [f32; 4], [f32; 3]);

/// A node's local TRS (f32, as written) for a matrix, and the matrix those f32 numbers make.
/// The rotation is the matrix's nearest; a shear (a parent scaled unevenly and turned) is
/// dropped.
fn trs(m: &Matrix4<f64>) -> (Trs, Matrix4<f64>) {
    let a: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into();
    let scale = Vector3::new(a.column(0).norm(), a.column(1).norm(), a.column(2).norm());
    let r = Matrix3::from_columns(&[
        a.column(0) / scale.x,
        a.column(1) / scale.y,
        a.column(2) / scale.z,
    ]);
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
    let t = [m[(0, 3)], m[(1, 3)], m[(2, 3)]].map(|c| c as f32);
    let q32 = [q.i, q.j, q.k, q.w].map(|c| c as f32);
    let s = [scale.x, scale.y, scale.z].map(|c| c as f32);
    let qn = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        q32[3] as f64,
        q32[0] as f64,
        q32[1] as f64,
        q32[2] as f64,
    ));
    let made = Matrix4::new_translation(&Vector3::from(t.map(f64::from)))
        * qn.to_homogeneous()
        * Matrix4::new_nonuniform_scaling(&Vector3::from(s.map(f64::from)));
    ((t, q32, s), made)
}

fn with_trs(mut node: Value, (t, q, s): &Trs) -> Value {
    let o = node.as_object_mut().unwrap();
    if t.iter().any(|&c| c != 0.0) {
        o.insert("translation".into(), json!(t));
    }
    if q[3].abs() < 1.0 {
        let n = q.iter().map(|c| c * c).sum::<f32>().sqrt();
        o.insert("rotation".into(), json!(q.map(|c| c / n)));
    }
    if s.iter().any(|&c| (c - 1.0).abs() > 1e-6) {
        o.insert("scale".into(), json!(s));
    }
    node
}

/// Appends to the document and its binary chunk.
struct Editor<'a> {
    doc: &'a mut Value,
    bin: &'a mut Vec<u8>,
}

impl Editor<'_> {
    fn array(&mut self, key: &str) -> &mut Vec<Value> {
        if !self.doc[key].is_array() {
            self.doc[key] = json!([]);
        }
        self.doc[key].as_array_mut().unwrap()
    }

    fn push(&mut self, key: &str, v: Value) -> usize {
        let a = self.array(key);
        a.push(v);
        a.len() - 1
    }

    fn default_scene(&mut self) -> usize {
        let scene = self.doc["scene"].as_u64().unwrap_or(0) as usize;
        if self.array("scenes").is_empty() {
            self.push("scenes", json!({"nodes": []}));
            self.doc["scene"] = json!(0);
            return 0;
        }
        scene
    }

    fn scene_roots(&mut self, scene: usize) -> &mut Vec<Value> {
        let s = &mut self.doc["scenes"][scene];
        if !s["nodes"].is_array() {
            s["nodes"] = json!([]);
        }
        s["nodes"].as_array_mut().unwrap()
    }

    fn add_child(&mut self, parent: usize, child: usize) {
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
    fn new_skin(
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
    fn extend_skin(
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
    fn move_mesh(&mut self, node: usize, scene: usize) -> usize {
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
    fn write_weights(
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
