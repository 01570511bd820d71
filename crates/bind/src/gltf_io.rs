//! Reading a mesh from glTF/GLB ([`crate::gltf_read`], re-exported here), and writing the
//! bound, skinned glTF.

use std::path::Path;

use gltf_json as json;
use json::validation::{Checked::Valid, USize64};
use nalgebra::{Isometry3, Translation3};

use mouthpiece_export::onto_rig::write_glb;
use mouthpiece_export::{MouthRig, PendingFile};

pub use crate::gltf_read::{
    read_mesh, read_mesh_bytes, weld, LoadedMesh, MAX_COORDINATE, MAX_FILE_BYTES, MAX_INSTANCES,
    MAX_TRIANGLES,
};
use crate::mesh::Mesh;
use crate::weights::{Weights, JOINTS, MAX_INFLUENCES, ROOT};
use crate::BindError;

/// The joints of a bound mesh, in skin order: `root`, `mouth`, then the points.
pub fn joint_names(rig: &MouthRig) -> Vec<String> {
    let mut names = vec!["root".to_owned(), "mouth".to_owned()];
    names.extend(rig.names());
    names
}

/// Skin column of a weight column (points, then root) → glTF joint index.
fn skin_joint(column: usize) -> u8 {
    if column == ROOT {
        0
    } else {
        (column + 2) as u8
    }
}

/// One vertex's four (joint, weight) pairs as glTF stores them: weights in f32 summing to 1
/// (the rounding residue goes to the largest), unused slots joint 0 with weight 0.
pub fn vertex_influences(row: &[f64; JOINTS]) -> ([u8; 4], [f32; 4]) {
    let mut order: Vec<usize> = (0..JOINTS).filter(|&j| row[j] > 0.0).collect();
    order.sort_by(|&a, &b| row[b].total_cmp(&row[a]).then(a.cmp(&b)));
    order.truncate(MAX_INFLUENCES);
    let mut joints = [0u8; 4];
    let mut weights = [0f32; 4];
    for (slot, &j) in order.iter().enumerate() {
        joints[slot] = skin_joint(j);
        weights[slot] = row[j] as f32;
    }
    let sum: f32 = weights.iter().sum();
    if sum > 0.0 {
        for w in &mut weights {
            *w /= sum;
        }
        let residue = 1.0 - weights.iter().sum::<f32>();
        weights[0] += residue;
    } else {
        weights[0] = 1.0;
    }
    (joints, weights)
}

/// Writes the mesh (original vertices, model frame) skinned to the rig's joints with
/// `weights` (one row per original vertex) as a GLB; `placement` puts the mouth frame in
/// the file's coordinates.
pub fn write_skinned_glb(
    out: &Path,
    mesh: &Mesh,
    normals: &[[f64; 3]],
    weights: &Weights,
    rig: &MouthRig,
    placement: &Isometry3<f64>,
    generator: &str,
) -> Result<(), BindError> {
    let n = mesh.len();
    let mut bin: Vec<u8> = Vec::new();
    let mut root = json::Root {
        asset: json::Asset {
            generator: Some(generator.to_owned()),
            ..Default::default()
        },
        ..Default::default()
    };
    let buffer = json::Index::<json::Buffer>::new(0);
    let view = |root: &mut json::Root,
                bin: &mut Vec<u8>,
                bytes: Vec<u8>,
                target: Option<json::buffer::Target>| {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let offset = bin.len();
        let len = bytes.len();
        bin.extend(bytes);
        root.push(json::buffer::View {
            buffer,
            byte_length: USize64(len as u64),
            byte_offset: Some(USize64(offset as u64)),
            byte_stride: None,
            extensions: None,
            extras: Default::default(),
            name: None,
            target: target.map(Valid),
        })
    };
    let accessor =
        |view, count: usize, ty, ct, bounds: Option<(json::Value, json::Value)>| json::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64(count as u64),
            component_type: Valid(json::accessor::GenericComponentType(ct)),
            extensions: None,
            extras: Default::default(),
            type_: Valid(ty),
            min: bounds.as_ref().map(|b| b.0.clone()),
            max: bounds.map(|b| b.1),
            name: None,
            normalized: false,
            sparse: None,
        };
    use json::accessor::{ComponentType as C, Type as T};
    let f32s = |v: &mut Vec<u8>, x: f32| v.extend_from_slice(&x.to_le_bytes());
    // positions
    let mut bytes = Vec::with_capacity(12 * n);
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &mesh.positions {
        for k in 0..3 {
            let c = p[k] as f32;
            lo[k] = lo[k].min(c);
            hi[k] = hi[k].max(c);
            f32s(&mut bytes, c);
        }
    }
    let v = view(
        &mut root,
        &mut bin,
        bytes,
        Some(json::buffer::Target::ArrayBuffer),
    );
    let positions = root.push(accessor(
        v,
        n,
        T::Vec3,
        C::F32,
        Some((
            json::Value::from(lo.to_vec()),
            json::Value::from(hi.to_vec()),
        )),
    ));
    let mut bytes = Vec::with_capacity(12 * n);
    for nrm in normals {
        let len = (nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]).sqrt();
        let unit = if len > 0.0 {
            nrm.map(|c| c / len)
        } else {
            [0.0, 0.0, 1.0]
        };
        let unit = unit.map(|c| c as f32);
        let l32 = (unit[0] * unit[0] + unit[1] * unit[1] + unit[2] * unit[2]).sqrt();
        for c in unit {
            f32s(&mut bytes, c / l32);
        }
    }
    let v = view(
        &mut root,
        &mut bin,
        bytes,
        Some(json::buffer::Target::ArrayBuffer),
    );
    let normals_acc = root.push(accessor(v, n, T::Vec3, C::F32, None));
    let mut joint_bytes = Vec::with_capacity(4 * n);
    let mut weight_bytes = Vec::with_capacity(16 * n);
    for row in &weights.rows {
        let (j, w) = vertex_influences(row);
        joint_bytes.extend_from_slice(&j);
        for x in w {
            f32s(&mut weight_bytes, x);
        }
    }
    let v = view(
        &mut root,
        &mut bin,
        joint_bytes,
        Some(json::buffer::Target::ArrayBuffer),
    );
    let joints_acc = root.push(accessor(v, n, T::Vec4, C::U8, None));
    let v = view(
        &mut root,
        &mut bin,
        weight_bytes,
        Some(json::buffer::Target::ArrayBuffer),
    );
    let weights_acc = root.push(accessor(v, n, T::Vec4, C::F32, None));
    let mut bytes = Vec::with_capacity(12 * mesh.triangles.len());
    for t in &mesh.triangles {
        for &i in t {
            bytes.extend_from_slice(&i.to_le_bytes());
        }
    }
    let v = view(
        &mut root,
        &mut bin,
        bytes,
        Some(json::buffer::Target::ElementArrayBuffer),
    );
    let indices = root.push(accessor(
        v,
        3 * mesh.triangles.len(),
        T::Scalar,
        C::U32,
        None,
    ));

    // joints: root (identity) → mouth (placement) → points (rest, mouth frame)
    let point_nodes: Vec<json::Index<json::Node>> = rig
        .points()
        .iter()
        .map(|p| {
            root.push(json::Node {
                name: Some(p.name.clone()),
                translation: Some(p.rest.map(|c| c as f32)),
                ..Default::default()
            })
        })
        .collect();
    let q = placement.rotation.coords.map(|c| c as f32).normalize();
    let t = placement.translation.vector.map(|c| c as f32);
    let mouth = root.push(json::Node {
        name: Some("mouth".into()),
        translation: (t.norm() > 0.0).then(|| t.into()),
        rotation: (q.w.abs() < 1.0).then(|| json::scene::UnitQuaternion([q.x, q.y, q.z, q.w])),
        children: Some(point_nodes.clone()),
        ..Default::default()
    });
    let root_joint = root.push(json::Node {
        name: Some("root".into()),
        children: Some(vec![mouth]),
        ..Default::default()
    });
    // inverse bind matrices, from the same f32 TRS the nodes carry
    let q64 = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        q.w as f64, q.x as f64, q.y as f64, q.z as f64,
    ));
    let mouth_world = Isometry3::from_parts(Translation3::from(t.map(|c| c as f64)), q64);
    let mut worlds = vec![Isometry3::identity(), mouth_world];
    for p in rig.points() {
        let rest = p.rest.map(|c| c as f32 as f64);
        worlds.push(mouth_world * Translation3::new(rest[0], rest[1], rest[2]));
    }
    let mut bytes = Vec::with_capacity(64 * worlds.len());
    for w in &worlds {
        let inv = w.inverse().to_homogeneous();
        for c in inv.as_slice() {
            f32s(&mut bytes, *c as f32);
        }
    }
    let v = view(&mut root, &mut bin, bytes, None);
    let ibm = root.push(accessor(v, worlds.len(), T::Mat4, C::F32, None));
    let mut joints = vec![root_joint, mouth];
    joints.extend(point_nodes);
    let skin = root.push(json::Skin {
        extensions: None,
        extras: Default::default(),
        inverse_bind_matrices: Some(ibm),
        joints,
        name: Some(format!("{} mouth", rig.character().unwrap_or("character"))),
        skeleton: Some(root_joint),
    });
    let mesh_index = root.push(json::Mesh {
        extensions: None,
        extras: Default::default(),
        name: Some("head".into()),
        primitives: vec![json::mesh::Primitive {
            attributes: [
                (Valid(json::mesh::Semantic::Positions), positions),
                (Valid(json::mesh::Semantic::Normals), normals_acc),
                (Valid(json::mesh::Semantic::Joints(0)), joints_acc),
                (Valid(json::mesh::Semantic::Weights(0)), weights_acc),
            ]
            .into(),
            extensions: None,
            extras: Default::default(),
            indices: Some(indices),
            material: None,
            mode: Valid(json::mesh::Mode::Triangles),
            targets: None,
        }],
        weights: None,
    });
    let mesh_node = root.push(json::Node {
        name: Some("head".into()),
        mesh: Some(mesh_index),
        skin: Some(skin),
        ..Default::default()
    });
    let scene = root.push(json::Scene {
        extensions: None,
        extras: Default::default(),
        name: Some(rig.character().unwrap_or("character").to_owned()),
        nodes: vec![root_joint, mesh_node],
    });
    root.scene = Some(scene);
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    root.push(json::Buffer {
        byte_length: USize64(bin.len() as u64),
        extensions: None,
        extras: Default::default(),
        name: None,
        uri: None,
    });
    write_document(out, &root, &bin)
}

/// Writes an unskinned mesh as GLB (the shipped character heads).
pub fn write_plain_glb(out: &Path, mesh: &Mesh, name: &str) -> Result<(), BindError> {
    let mut root = json::Root::default();
    root.asset.generator = Some("mouthpiece bind head".into());
    let mut bin = Vec::new();
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &mesh.positions {
        for k in 0..3 {
            let c = p[k] as f32;
            lo[k] = lo[k].min(c);
            hi[k] = hi[k].max(c);
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    let pos_len = bin.len();
    for t in &mesh.triangles {
        for &i in t {
            bin.extend_from_slice(&i.to_le_bytes());
        }
    }
    let buffer = root.push(json::Buffer {
        byte_length: USize64(bin.len() as u64),
        extensions: None,
        extras: Default::default(),
        name: None,
        uri: None,
    });
    let mk_view = |offset: usize, len: usize, target| json::buffer::View {
        buffer,
        byte_length: USize64(len as u64),
        byte_offset: Some(USize64(offset as u64)),
        byte_stride: None,
        extensions: None,
        extras: Default::default(),
        name: None,
        target: Some(Valid(target)),
    };
    let pv = root.push(mk_view(0, pos_len, json::buffer::Target::ArrayBuffer));
    let iv = root.push(mk_view(
        pos_len,
        bin.len() - pos_len,
        json::buffer::Target::ElementArrayBuffer,
    ));
    use json::accessor::{ComponentType as C, GenericComponentType as G, Type as T};
    let pa = root.push(json::Accessor {
        buffer_view: Some(pv),
        byte_offset: None,
        count: USize64(mesh.len() as u64),
        component_type: Valid(G(C::F32)),
        extensions: None,
        extras: Default::default(),
        type_: Valid(T::Vec3),
        min: Some(json::Value::from(lo.to_vec())),
        max: Some(json::Value::from(hi.to_vec())),
        name: None,
        normalized: false,
        sparse: None,
    });
    let ia = root.push(json::Accessor {
        buffer_view: Some(iv),
        byte_offset: None,
        count: USize64(3 * mesh.triangles.len() as u64),
        component_type: Valid(G(C::U32)),
        extensions: None,
        extras: Default::default(),
        type_: Valid(T::Scalar),
        min: None,
        max: None,
        name: None,
        normalized: false,
        sparse: None,
    });
    let m = root.push(json::Mesh {
        extensions: None,
        extras: Default::default(),
        name: Some(name.to_owned()),
        primitives: vec![json::mesh::Primitive {
            attributes: [(Valid(json::mesh::Semantic::Positions), pa)].into(),
            extensions: None,
            extras: Default::default(),
            indices: Some(ia),
            material: None,
            mode: Valid(json::mesh::Mode::Triangles),
            targets: None,
        }],
        weights: None,
    });
    let node = root.push(json::Node {
        name: Some(name.to_owned()),
        mesh: Some(m),
        ..Default::default()
    });
    let scene = root.push(json::Scene {
        extensions: None,
        extras: Default::default(),
        name: Some(name.to_owned()),
        nodes: vec![node],
    });
    root.scene = Some(scene);
    write_document(out, &root, &bin)
}

/// Serialises `root` and writes it with its binary chunk as one GLB file, replacing `out`
/// only once the whole file is written.
fn write_document(out: &Path, root: &json::Root, bin: &[u8]) -> Result<(), BindError> {
    let err = |cause| BindError::Write {
        path: out.to_path_buf(),
        cause,
    };
    let text = serde_json::to_vec(root).map_err(|e| err(std::io::Error::other(e)))?;
    let mut pending = PendingFile::create(out).map_err(err)?;
    write_glb(&text, bin, &mut pending).map_err(err)?;
    pending.commit().map_err(err)
}
