//! Reading a mesh from glTF/GLB, treating the file as hostile: every count, offset and
//! stride is checked against the bytes really there and against the caps below before
//! anything is allocated, buffers are read only from `data:` URIs, the GLB's binary chunk or
//! files inside the asset's own folder ([`mouthpiece_export::asset`]), and numbers that are
//! not finite or absurdly large are refused with the accessor that holds them.

use std::collections::HashMap;
use std::path::Path;

use serde::Deserialize as _;

use gltf_json as json;
use json::validation::Checked::Valid;
use nalgebra::{Matrix4, Point3};

use mouthpiece_export::asset::{self, shown};
use mouthpiece_export::onto_rig::parse_glb;

use crate::gltf_skin::skin_bind;
pub use crate::gltf_skin::{inverse_bind_matrices, read_skin_weights, MAX_SKIN_JOINTS};
use crate::mesh::{Mesh, MAX_VERTICES};
use crate::BindError;

/// Largest mesh file accepted, and largest total of the buffers it names (a mouth's head is
/// far smaller; this guards memory).
pub const MAX_FILE_BYTES: u64 = 256 * 1024 * 1024;
/// Most triangles read from one file (all primitives of all instances).
pub const MAX_TRIANGLES: usize = 2 * MAX_VERTICES;
/// Most mesh instances (nodes with a mesh) in the scene.
pub const MAX_INSTANCES: usize = 10_000;
/// Largest coordinate accepted, in the file's units, as stored and after the nodes'
/// transforms: a head in millimetres is a few hundred; beyond this, sums and squares in the
/// binders lose all precision or overflow.
pub const MAX_COORDINATE: f64 = 1e6;

/// A mesh as read: the triangles as they are in the file, and the same surface with
/// vertices at identical positions merged (files split vertices along UV seams and hard
/// edges; the binders need the connected surface).
#[derive(Clone, Debug)]
pub struct LoadedMesh {
    /// The file's vertices (all primitives of all mesh nodes, in the scene's frame).
    pub original: Mesh,
    /// Vertices at identical positions merged.
    pub welded: Mesh,
    /// For each original vertex, its welded vertex.
    pub to_welded: Vec<u32>,
    /// For each welded triangle, the original triangle it comes from.
    pub welded_from: Vec<u32>,
    /// Where the original triangles come from, in order: (first triangle, description such
    /// as `mesh 0 primitive 1 (node 3)`).
    pub parts: Vec<(u32, String)>,
    /// Each mesh instance read, in scene order, with its primitives' vertex ranges.
    pub instances: Vec<Instance>,
    /// The document as read, for the output to edit.
    pub document: Document,
}

/// The file's glTF document and buffers, kept so the bound output is the input with a skin
/// added ([`crate::skin_out`]).
#[derive(Clone, Debug)]
pub struct Document {
    /// The JSON as read (every extension and extra, typed or not).
    pub json: serde_json::Value,
    /// The same, typed.
    pub root: json::Root,
    /// Each buffer's bytes (its `byteLength` of them).
    pub buffers: Vec<Vec<u8>>,
    /// The file's folder (images named by URI are looked up there).
    pub folder: std::path::PathBuf,
    /// Each node's world transform at rest (nodes outside the default scene: their own).
    pub worlds: Vec<Matrix4<f64>>,
    /// Each node's parent.
    pub parents: Vec<Option<usize>>,
}

/// One node with a mesh, as read.
#[derive(Clone, Debug)]
pub struct Instance {
    /// The node (none when the file has no scene and its meshes are read on their own).
    pub node: Option<usize>,
    pub mesh: usize,
    /// The node's skin, when it has one.
    pub skin: Option<usize>,
    /// Mesh coordinates → the file's frame at rest: the node's world transform, or for a
    /// skinned node its skin's bind (a joint's world transform times its inverse bind matrix;
    /// glTF ignores a skinned node's own transform).
    pub bind: Matrix4<f64>,
    /// Its triangle primitives: (primitive index, first vertex, vertex count) in
    /// [`LoadedMesh::original`].
    pub primitives: Vec<(usize, u32, u32)>,
}

impl Instance {
    /// The node's or mesh's name, for messages and `--face-mesh`.
    pub fn names(&self, root: &json::Root) -> (Option<String>, Option<String>) {
        let node = self
            .node
            .and_then(|n| root.nodes.get(n))
            .and_then(|n| n.name.clone());
        let mesh = root.meshes.get(self.mesh).and_then(|m| m.name.clone());
        (node, mesh)
    }

    /// `mesh 2 "Head" (node 5 "Head")`.
    pub fn describe(&self, root: &json::Root) -> String {
        let (node, mesh) = self.names(root);
        let quoted = |n: Option<String>| n.map_or(String::new(), |n| format!(" \"{}\"", shown(&n)));
        match self.node {
            Some(i) => format!(
                "mesh {}{} (node {i}{})",
                self.mesh,
                quoted(mesh),
                quoted(node)
            ),
            None => format!("mesh {}{}", self.mesh, quoted(mesh)),
        }
    }
}

impl LoadedMesh {
    /// Where welded triangle `t` comes from in the file: `mesh m primitive p (node n),
    /// triangle k`.
    pub fn triangle_source(&self, t: usize) -> Option<String> {
        let original = *self.welded_from.get(t)?;
        let part = self.parts.partition_point(|(first, _)| *first <= original);
        let (first, name) = self.parts.get(part.checked_sub(1)?)?;
        Some(format!("{name}, triangle {}", original - first))
    }

    /// [`Mesh::check`] of the welded surface, the error naming `path` and where in the
    /// file the triangle at fault comes from.
    pub fn check(&self, path: &Path) -> Result<(), BindError> {
        self.welded.check().map_err(|(triangle, problem)| {
            let at = triangle
                .and_then(|t| self.triangle_source(t))
                .map_or(String::new(), |s| format!(" ({s})"));
            BindError::BadMesh {
                path: path.to_path_buf(),
                problem: format!("the mesh cannot be bound: {problem}{at}"),
            }
        })
    }
}

/// Reads every triangle primitive of the default scene (or of all meshes when there is no
/// scene), placed by its node's world transform. The file is read up to
/// [`MAX_FILE_BYTES`].
pub fn read_mesh(path: &Path) -> Result<LoadedMesh, BindError> {
    let bytes = asset::read_bounded(path, MAX_FILE_BYTES).map_err(|cause| {
        if cause.kind() == std::io::ErrorKind::InvalidData {
            BindError::TooLarge {
                path: path.to_path_buf(),
                limit: MAX_FILE_BYTES,
            }
        } else {
            BindError::Read {
                path: path.to_path_buf(),
                cause,
            }
        }
    })?;
    read_mesh_bytes(&bytes, path)
}

/// [`read_mesh`] on a file's bytes; `path` names it in errors, and buffer files are looked
/// up in its folder.
pub fn read_mesh_bytes(bytes: &[u8], path: &Path) -> Result<LoadedMesh, BindError> {
    let not_gltf = |problem: String| BindError::NotGltf {
        path: path.to_path_buf(),
        problem,
    };
    let bad = |problem: String| BindError::BadMesh {
        path: path.to_path_buf(),
        problem,
    };
    let (json_bytes, glb_bin) = if bytes.starts_with(b"glTF") {
        let glb = parse_glb(bytes).map_err(not_gltf)?;
        (glb.json, Some(glb.bin))
    } else {
        (bytes.to_vec(), None)
    };
    let value: serde_json::Value =
        serde_json::from_slice(&json_bytes).map_err(|e| not_gltf(format!("JSON: {e}")))?;
    let root: json::Root =
        json::Root::deserialize(&value).map_err(|e| not_gltf(format!("JSON: {e}")))?;
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let buffers = read_buffers(&root, glb_bin, folder).map_err(&bad)?;
    for (i, image) in root.images.iter().enumerate() {
        if let Some(uri) = image.uri.as_deref().filter(|u| !u.starts_with("data:")) {
            asset::check_inside(folder, uri)
                .map_err(|why| bad(format!("image {i}: URI `{}` {why}", shown(uri))))?;
        }
    }
    let mut out = Collect::default();
    let scene = scene_instances(&root).map_err(&bad)?;
    let mut worlds: Vec<Matrix4<f64>> = Vec::with_capacity(root.nodes.len());
    for (i, node) in root.nodes.iter().enumerate() {
        worlds.push(node_matrix(node, i).map_err(&bad)?);
    }
    let mut parents = vec![None; root.nodes.len()];
    for (i, node) in root.nodes.iter().enumerate() {
        for child in node.children.iter().flatten() {
            if let Some(p) = parents.get_mut(child.value()) {
                *p = Some(i);
            }
        }
    }
    for (index, world) in &scene {
        worlds[*index] = *world;
    }
    for (node_index, world) in scene {
        let node = &root.nodes[node_index];
        let Some(mesh) = node.mesh else { continue };
        let skin = node.skin.map(|s| s.value());
        let bind = match skin {
            Some(s) => skin_bind(&root, &buffers, s, &worlds)
                .map_err(|e| bad(format!("node {node_index}: skin {s}: {e}")))?,
            None => world,
        };
        out.instances += 1;
        if out.instances > MAX_INSTANCES {
            return Err(bad(format!(
                "more than {MAX_INSTANCES} mesh instances in the scene (node {node_index} is one \
                 too many)"
            )));
        }
        read_primitives(
            &root,
            &buffers,
            mesh.value(),
            Some(node_index),
            &bind,
            &mut out,
        )
        .map_err(&bad)?;
        out.records.push(Instance {
            node: Some(node_index),
            mesh: mesh.value(),
            skin,
            bind,
            primitives: std::mem::take(&mut out.pending),
        });
    }
    if out.instances == 0 {
        for m in 0..root.meshes.len() {
            read_primitives(&root, &buffers, m, None, &Matrix4::identity(), &mut out)
                .map_err(&bad)?;
            out.records.push(Instance {
                node: None,
                mesh: m,
                skin: None,
                bind: Matrix4::identity(),
                primitives: std::mem::take(&mut out.pending),
            });
        }
    }
    if out.triangles.is_empty() {
        return Err(bad(format!(
            "the mesh has no triangles ({} mesh instance(s), {} triangle primitive(s) in the \
             scene)",
            out.instances, out.primitives
        )));
    }
    let original = Mesh {
        positions: out.positions,
        triangles: out.triangles,
    };
    let (welded, to_welded, welded_from) = weld_traced(&original);
    Ok(LoadedMesh {
        original,
        welded,
        to_welded,
        welded_from,
        parts: out.parts,
        instances: out.records,
        document: Document {
            json: value,
            root,
            buffers,
            folder: folder.to_path_buf(),
            worlds,
            parents,
        },
    })
}

/// Each buffer's bytes: the GLB's binary chunk, a `data:` URI, or a file inside `folder`.
fn read_buffers(
    root: &json::Root,
    glb_bin: Option<Vec<u8>>,
    folder: &Path,
) -> Result<Vec<Vec<u8>>, String> {
    let mut buffers = Vec::new();
    let mut total = 0u64;
    let mut glb_bin = glb_bin;
    for (i, buffer) in root.buffers.iter().enumerate() {
        let data = match &buffer.uri {
            None if i == 0 => glb_bin
                .take()
                .ok_or_else(|| format!("buffer {i} has no URI and the file is not GLB"))?,
            None => {
                return Err(format!(
                    "buffer {i} has no URI (only buffer 0 may be GLB's)"
                ))
            }
            Some(uri) if uri.starts_with("data:") => {
                let (_, b64) = uri.split_once(";base64,").ok_or_else(|| {
                    format!("buffer {i}: data URI `{}` is not base64", shown(uri))
                })?;
                use base64::Engine as _;
                base64::engine::general_purpose::STANDARD
                    .decode(b64)
                    .map_err(|e| format!("buffer {i}: base64: {e}"))?
            }
            Some(uri) => {
                let file = asset::resolve_inside(folder, uri).map_err(|why| {
                    format!("buffer {i}: URI `{}` {why}; nothing was read", shown(uri))
                })?;
                asset::read_bounded(&file, MAX_FILE_BYTES - total)
                    .map_err(|e| format!("buffer {i}: reading {}: {e}", file.display()))?
            }
        };
        total += data.len() as u64;
        if total > MAX_FILE_BYTES {
            return Err(format!(
                "buffer {i}: the buffers hold more than {MAX_FILE_BYTES} bytes in all"
            ));
        }
        if (data.len() as u64) < buffer.byte_length.0 {
            return Err(format!(
                "buffer {i} has {} bytes, its byteLength says {}",
                data.len(),
                buffer.byte_length.0
            ));
        }
        buffers.push(data);
    }
    Ok(buffers)
}

/// The default scene's nodes (the first scene when none is named default; none when the file
/// has no scene) with their world transforms, each node once: a node reached twice (a cycle,
/// a second parent, a root listed twice) is an error, so the walk is bounded by the nodes.
fn scene_instances(root: &json::Root) -> Result<Vec<(usize, Matrix4<f64>)>, String> {
    let scene = match root.scene.map(|s| s.value()) {
        Some(s) => Some(s),
        None if !root.scenes.is_empty() => Some(0),
        None => None,
    };
    let Some(scene) = scene else {
        return Ok(Vec::new());
    };
    let roots = &root
        .scenes
        .get(scene)
        .ok_or_else(|| format!("the default scene {scene} does not exist"))?
        .nodes;
    let mut seen = vec![false; root.nodes.len()];
    let mut out = Vec::new();
    let mut visit: Vec<(usize, Matrix4<f64>)> = roots
        .iter()
        .rev()
        .map(|n| (n.value(), Matrix4::identity()))
        .collect();
    while let Some((index, parent)) = visit.pop() {
        let node = root
            .nodes
            .get(index)
            .ok_or_else(|| format!("node {index} does not exist"))?;
        if std::mem::replace(&mut seen[index], true) {
            return Err(format!(
                "node {index} is reached twice from the scene (a cycle in the node \
                 hierarchy, a node with two parents, or a root listed twice)"
            ));
        }
        let world = parent * node_matrix(node, index)?;
        if world.iter().any(|c| !c.is_finite()) {
            return Err(format!("node {index}: its world transform is not finite"));
        }
        out.push((index, world));
        for child in node.children.iter().flatten().rev() {
            visit.push((child.value(), world));
        }
    }
    Ok(out)
}

fn node_matrix(node: &json::Node, index: usize) -> Result<Matrix4<f64>, String> {
    let finite = |v: &[f32]| v.iter().all(|c| c.is_finite());
    let numbers_ok = node.matrix.is_none_or(|m| finite(&m))
        && node.translation.is_none_or(|t| finite(&t))
        && node.rotation.is_none_or(|r| finite(&r.0))
        && node.scale.is_none_or(|s| finite(&s));
    if !numbers_ok {
        return Err(format!("node {index}: a transform number is not finite"));
    }
    if let Some(m) = node.matrix {
        return Ok(Matrix4::from_column_slice(&m.map(f64::from)));
    }
    let t = node.translation.unwrap_or([0.0; 3]).map(f64::from);
    let r = node
        .rotation
        .map_or([0.0, 0.0, 0.0, 1.0], |q| q.0)
        .map(f64::from);
    let s = node.scale.unwrap_or([1.0; 3]).map(f64::from);
    let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        r[3], r[0], r[1], r[2],
    ));
    Ok(Matrix4::new_translation(&nalgebra::Vector3::from(t))
        * q.to_homogeneous()
        * Matrix4::new_nonuniform_scaling(&nalgebra::Vector3::from(s)))
}

/// What the primitives read so far add up to.
#[derive(Default)]
struct Collect {
    positions: Vec<[f64; 3]>,
    triangles: Vec<[u32; 3]>,
    parts: Vec<(u32, String)>,
    instances: usize,
    primitives: usize,
    records: Vec<Instance>,
    /// The current instance's primitives.
    pending: Vec<(usize, u32, u32)>,
}

fn read_primitives(
    root: &json::Root,
    buffers: &[Vec<u8>],
    mesh: usize,
    node: Option<usize>,
    world: &Matrix4<f64>,
    out: &mut Collect,
) -> Result<(), String> {
    let m = root
        .meshes
        .get(mesh)
        .ok_or(format!("mesh {mesh} does not exist"))?;
    for (p, prim) in m.primitives.iter().enumerate() {
        let here = match node {
            Some(n) => format!("mesh {mesh} primitive {p} (node {n})"),
            None => format!("mesh {mesh} primitive {p}"),
        };
        match prim.mode {
            Valid(json::mesh::Mode::Triangles) => {}
            _ => continue,
        }
        out.primitives += 1;
        let pos = prim
            .attributes
            .get(&Valid(json::mesh::Semantic::Positions))
            .ok_or(format!("{here} has no POSITION"))?
            .value();
        let vertex_room = MAX_VERTICES - out.positions.len();
        let values = read_accessor(root, buffers, pos, Use::Positions, vertex_room)
            .map_err(|e| format!("{here}: POSITION accessor {pos}: {e}"))?;
        let base = out.positions.len() as u32;
        let count = values.len() / 3;
        for (v, c) in values.chunks_exact(3).enumerate() {
            let q = world.transform_point(&Point3::new(c[0], c[1], c[2]));
            if ![q.x, q.y, q.z].iter().all(|c| c.abs() <= MAX_COORDINATE) {
                return Err(format!(
                    "{here}: vertex {v} lands at [{}, {}, {}] after the node transforms, \
                     beyond ±{MAX_COORDINATE} (wrong units or transform?)",
                    q.x, q.y, q.z
                ));
            }
            out.positions.push([q.x, q.y, q.z]);
        }
        let index_room = 3 * (MAX_TRIANGLES - out.triangles.len());
        let indices: Vec<u32> = match prim.indices {
            Some(i) => read_accessor(root, buffers, i.value(), Use::Indices, index_room)
                .map_err(|e| format!("{here}: indices accessor {}: {e}", i.value()))?
                .into_iter()
                .map(|v| v as u32)
                .collect(),
            None if count <= index_room => (0..count as u32).collect(),
            None => {
                return Err(format!(
                    "{here}: more than {MAX_TRIANGLES} triangles in the file"
                ))
            }
        };
        if !indices.len().is_multiple_of(3) {
            return Err(format!(
                "{here}: {} indices is not a whole number of triangles",
                indices.len()
            ));
        }
        out.parts.push((out.triangles.len() as u32, here.clone()));
        out.pending.push((p, base, count as u32));
        for (k, t) in indices.chunks_exact(3).enumerate() {
            if let Some(&bad) = t.iter().find(|&&i| i as usize >= count) {
                return Err(format!(
                    "{here}: triangle {k} names vertex {bad}, past its {count} vertices"
                ));
            }
            out.triangles.push([base + t[0], base + t[1], base + t[2]]);
        }
    }
    Ok(())
}

/// What an accessor is read as: positions must be `VEC3` of `FLOAT`, indices `SCALAR` of
/// an unsigned integer type (glTF 2.0 §3.7.2.1, §3.7.2.2).
#[derive(Clone, Copy, PartialEq)]
pub(crate) enum Use {
    Positions,
    Indices,
    /// `MAT4` of `FLOAT` (inverse bind matrices).
    Matrices,
    /// `VEC4` of `UNSIGNED_BYTE` or `UNSIGNED_SHORT` (`JOINTS_n`).
    Joints,
    /// `VEC4` of `FLOAT` or normalised `UNSIGNED_BYTE`/`UNSIGNED_SHORT` (`WEIGHTS_n`).
    Weights,
}

/// An accessor's components as f64, checked before anything is allocated: the element count
/// at most `room` (positions: vertices; indices: indices), offsets, stride and count inside
/// the buffer view and the view inside its buffer's bytes (all in checked arithmetic), and
/// positions finite and within ±[`MAX_COORDINATE`].
pub(crate) fn read_accessor(
    root: &json::Root,
    buffers: &[Vec<u8>],
    index: usize,
    usage: Use,
    room: usize,
) -> Result<Vec<f64>, String> {
    use json::accessor::{ComponentType as C, GenericComponentType as G, Type};
    let a = root.accessors.get(index).ok_or("does not exist")?;
    let (components, kind) = match (usage, a.type_, a.component_type) {
        (Use::Positions, Valid(Type::Vec3), Valid(G(C::F32))) => (3, C::F32),
        (Use::Indices, Valid(Type::Scalar), Valid(G(c @ (C::U8 | C::U16 | C::U32)))) => (1, c),
        (Use::Matrices, Valid(Type::Mat4), Valid(G(C::F32))) => (16, C::F32),
        (Use::Joints, Valid(Type::Vec4), Valid(G(c @ (C::U8 | C::U16)))) => (4, c),
        (Use::Weights, Valid(Type::Vec4), Valid(G(C::F32))) => (4, C::F32),
        (Use::Weights, Valid(Type::Vec4), Valid(G(c @ (C::U8 | C::U16)))) if a.normalized => (4, c),
        (Use::Matrices, ..) => return Err("must be MAT4 of FLOAT".into()),
        (Use::Joints, ..) => return Err("must be VEC4 of UNSIGNED_BYTE or UNSIGNED_SHORT".into()),
        (Use::Weights, ..) => {
            return Err("must be VEC4 of FLOAT or normalised UNSIGNED_BYTE/UNSIGNED_SHORT".into())
        }
        (Use::Positions, ..) => return Err("POSITION must be VEC3 of FLOAT (5126)".into()),
        (Use::Indices, ..) => {
            return Err(
                "indices must be SCALAR of UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT".into(),
            )
        }
    };
    let size: u64 = match kind {
        C::U8 | C::I8 => 1,
        C::U16 | C::I16 => 2,
        C::U32 | C::F32 => 4,
    };
    let count = a.count.0;
    if count > room as u64 {
        return Err(match usage {
            Use::Positions => {
                format!("claims {count} vertices; a mesh may have at most {MAX_VERTICES} in all")
            }
            Use::Indices => format!(
                "claims {count} indices; a mesh may have at most {MAX_TRIANGLES} triangles in all"
            ),
            _ => format!("claims {count} elements, more than the {room} expected"),
        });
    }
    if a.sparse.is_some() {
        return Err("is sparse (not supported)".into());
    }
    let view_index = a
        .buffer_view
        .ok_or("has no bufferView (all zeros: not a mesh)")?
        .value();
    let view = root
        .buffer_views
        .get(view_index)
        .ok_or(format!("buffer view {view_index} does not exist"))?;
    let data = buffers
        .get(view.buffer.value())
        .ok_or(format!("buffer {} does not exist", view.buffer.value()))?;
    let element = size * components as u64;
    let stride = match view.byte_stride {
        None => element,
        Some(s) if (element..=252).contains(&(s.0 as u64)) => s.0 as u64,
        Some(s) => {
            return Err(format!(
                "buffer view {view_index}: byteStride {} is not between the element's {element} \
                 bytes and 252",
                s.0
            ))
        }
    };
    let view_start = view.byte_offset.map_or(0, |o| o.0);
    let view_end = view_start
        .checked_add(view.byte_length.0)
        .filter(|&end| end <= data.len() as u64)
        .ok_or(format!(
            "buffer view {view_index} (offset {view_start}, length {}) runs past its buffer's {} \
             bytes",
            view.byte_length.0,
            data.len()
        ))?;
    let start = a.byte_offset.map_or(0, |o| o.0);
    let end = match count {
        0 => Some(start),
        n => (n - 1)
            .checked_mul(stride)
            .and_then(|b| b.checked_add(start))
            .and_then(|b| b.checked_add(element)),
    }
    .and_then(|e| e.checked_add(view_start))
    .filter(|&e| e <= view_end)
    .ok_or(format!(
        "{count} elements of {element} bytes every {stride} from offset {start}: runs past \
         buffer view {view_index}'s {} bytes",
        view.byte_length.0
    ))?;
    debug_assert!(end <= data.len() as u64);
    // From here every element lies inside `data`, and count ≤ room.
    let (count, stride, size) = (count as usize, stride as usize, size as usize);
    let base = (view_start + start) as usize;
    let mut out = Vec::with_capacity(count * components);
    for e in 0..count {
        for c in 0..components {
            let at = base + e * stride + c * size;
            let b = &data[at..at + size];
            let v = match kind {
                C::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                C::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                C::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
                _ => b[0] as f64,
            };
            let v = match (usage, kind) {
                (Use::Weights, C::U8) => v / 255.0,
                (Use::Weights, C::U16) => v / 65535.0,
                _ => v,
            };
            // NaN fails every comparison: `is_finite` first says so plainly.
            let checked = matches!(usage, Use::Positions | Use::Matrices | Use::Weights);
            if checked && (!v.is_finite() || v.abs() > MAX_COORDINATE) {
                return Err(format!(
                    "element {e} holds {v}: not a finite number within ±{MAX_COORDINATE} \
                     (wrong units?)"
                ));
            }
            out.push(v);
        }
    }
    Ok(out)
}

/// Merges vertices with bit-identical positions; drops triangles that collapse.
pub fn weld(mesh: &Mesh) -> (Mesh, Vec<u32>) {
    let (welded, to_welded, _) = weld_traced(mesh);
    (welded, to_welded)
}

/// [`weld`], and for each welded triangle the original triangle it comes from.
fn weld_traced(mesh: &Mesh) -> (Mesh, Vec<u32>, Vec<u32>) {
    let mut index: HashMap<[u64; 3], u32> = HashMap::with_capacity(mesh.len());
    let mut positions = Vec::new();
    let to_welded: Vec<u32> = mesh
        .positions
        .iter()
        .map(|p| {
            *index.entry(p.map(f64::to_bits)).or_insert_with(|| {
                positions.push(*p);
                (positions.len() - 1) as u32
            })
        })
        .collect();
    let mut triangles = Vec::new();
    let mut from = Vec::new();
    for (k, t) in mesh.triangles.iter().enumerate() {
        let t = t.map(|i| to_welded[i as usize]);
        if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
            triangles.push(t);
            from.push(k as u32);
        }
    }
    (
        Mesh {
            positions,
            triangles,
        },
        to_welded,
        from,
    )
}
