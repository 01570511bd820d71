//! The joint hierarchy the bound file gains: `mouth` under the parent joint, `jaw` under it
//! at the hinge, the points under `mouth` (or `jaw` for the lower lip), and the local
//! transforms glTF writes for them.

use std::collections::HashMap;

use nalgebra::{Matrix3, Matrix4, Rotation3, UnitQuaternion, Vector3};
use serde_json::{json, Value};

use super::editor::Editor;
use super::{RigPlan, Target};
use crate::gltf_read::LoadedMesh;

/// The joints added for the mouth, with their nodes and rest world transforms.
pub(super) struct Joints {
    /// The node the mouth hangs under.
    pub parent: usize,
    pub parent_world: Matrix4<f64>,
    /// Each target's node and rest world transform.
    pub nodes: HashMap<Target, usize>,
    pub worlds: HashMap<Target, Matrix4<f64>>,
    /// The skin's new joints after `mouth`: the jaw (when there is one), then the points.
    pub new_joints: Vec<Target>,
    /// `mouth` then [`Self::new_joints`]: nodes and rest worlds.
    pub mouth_joint_nodes: Vec<usize>,
    pub mouth_joint_worlds: Vec<Matrix4<f64>>,
}

/// Adds `mouth`, `jaw` and the points (and a `root` when there is no parent) to the document.
pub(super) fn add_joints(
    ed: &mut Editor,
    loaded: &LoadedMesh,
    plan: &RigPlan,
    scene: usize,
) -> Joints {
    let parent = match plan.parent {
        Some(p) => p,
        None => {
            let root = ed.push("nodes", json!({"name": "root"}));
            ed.scene_roots(scene).push(json!(root));
            root
        }
    };
    let parent_world = world_of(&loaded.document, parent);
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
    Joints {
        parent,
        parent_world,
        nodes,
        worlds,
        new_joints,
        mouth_joint_nodes,
        mouth_joint_worlds,
    }
}

/// A node's world transform at rest in the edited document: the input's, or for a node
/// added here, its parents' times its own.
fn world_of(d: &crate::gltf_read::Document, node: usize) -> Matrix4<f64> {
    d.worlds
        .get(node)
        .copied()
        .unwrap_or_else(Matrix4::identity)
}

pub(super) fn inverse(m: &Matrix4<f64>) -> Matrix4<f64> {
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
