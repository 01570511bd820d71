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

mod editor;
mod joints;

use std::collections::HashMap;
use std::path::Path;

use nalgebra::Isometry3;
use serde_json::{json, Value};

use mouthpiece_export::onto_rig::write_glb;
use mouthpiece_export::{MouthRig, PendingFile};

use crate::gltf_read::{read_skin_weights, LoadedMesh, MAX_FILE_BYTES};
use crate::BindError;
use editor::{gather_buffers, Editor};
use joints::{add_joints, Joints};

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
    /// `crate::gltf_read::Instance::primitives`.
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
    let Joints {
        parent,
        parent_world,
        nodes,
        worlds,
        new_joints,
        mouth_joint_nodes,
        mouth_joint_worlds,
    } = add_joints(&mut ed, loaded, plan, scene);

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
