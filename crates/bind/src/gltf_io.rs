//! Reading a mesh from glTF/GLB (`crate::gltf_read`, re-exported here), and writing an
//! unskinned one (the bound output is [`crate::skin_out`]'s).

use std::path::Path;

use gltf_json as json;
use json::validation::{Checked::Valid, USize64};

use mouthpiece_export::onto_rig::write_glb;
use mouthpiece_export::PendingFile;

pub use crate::gltf_read::{
    read_mesh, read_mesh_bytes, weld, LoadedMesh, MAX_COORDINATE, MAX_FILE_BYTES, MAX_INSTANCES,
    MAX_SKIN_JOINTS, MAX_TRIANGLES,
};
use crate::mesh::Mesh;
use crate::BindError;

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
