//! Which meshes of a file are the face, and which joint the mouth hangs under.

use std::ops::Range;

use nalgebra::{Isometry3, Point3};

use mouthpiece_export::asset::shown;
use mouthpiece_export::MouthRig;

use crate::gltf_read::LoadedMesh;
use crate::mesh::Mesh;

/// The face's instances (indices into [`LoadedMesh::instances`]): those named by
/// `--face-mesh` (node or mesh name), or by default each mesh instance that is the nearest
/// to at least one mouth point.
pub fn face_instances(
    loaded: &LoadedMesh,
    rig: &MouthRig,
    placement: &Isometry3<f64>,
    names: &[String],
) -> Result<Vec<usize>, String> {
    let root = &loaded.document.root;
    let usable: Vec<usize> = (0..loaded.instances.len())
        .filter(|&i| !loaded.instances[i].primitives.is_empty())
        .collect();
    if !names.is_empty() {
        let mut face = Vec::new();
        for name in names {
            let found: Vec<usize> = usable
                .iter()
                .copied()
                .filter(|&i| {
                    let (node, mesh) = loaded.instances[i].names(root);
                    node.as_deref() == Some(name) || mesh.as_deref() == Some(name)
                })
                .collect();
            if found.is_empty() {
                let known: Vec<String> = usable
                    .iter()
                    .take(20)
                    .map(|&i| loaded.instances[i].describe(root))
                    .collect();
                return Err(format!(
                    "--face-mesh {}: no mesh or node of that name has triangles (the meshes: {})",
                    shown(name),
                    known.join(", ")
                ));
            }
            for f in found {
                if !face.contains(&f) {
                    face.push(f);
                }
            }
        }
        face.sort_unstable();
        return Ok(face);
    }
    let mut face = Vec::new();
    for p in rig.points() {
        let q = placement * Point3::from(p.rest);
        let mut best = (f64::INFINITY, None);
        for &i in &usable {
            for &(_, first, count) in &loaded.instances[i].primitives {
                for v in first..first + count {
                    let d = (Point3::from(loaded.original.positions[v as usize]) - q).norm();
                    if d < best.0 {
                        best = (d, Some(i));
                    }
                }
            }
        }
        if let (_, Some(i)) = best {
            if !face.contains(&i) {
                face.push(i);
            }
        }
    }
    face.sort_unstable();
    if face.is_empty() {
        return Err("no mesh with triangles in the scene".into());
    }
    Ok(face)
}

/// The face's surface on its own.
pub struct FaceMesh {
    pub mesh: Mesh,
    /// Its meshes, described.
    pub names: Vec<String>,
    /// For each face instance, each primitive's vertices in `mesh`.
    pub ranges: Vec<Vec<Range<usize>>>,
}

/// The face instances' vertices and triangles as one mesh.
pub fn face_mesh(loaded: &LoadedMesh, face: &[usize]) -> FaceMesh {
    let mut map = vec![u32::MAX; loaded.original.len()];
    let mut positions = Vec::new();
    let mut ranges = Vec::new();
    for &i in face {
        let mut prims = Vec::new();
        for &(_, first, count) in &loaded.instances[i].primitives {
            let start = positions.len();
            for v in first..first + count {
                map[v as usize] = positions.len() as u32;
                positions.push(loaded.original.positions[v as usize]);
            }
            prims.push(start..positions.len());
        }
        ranges.push(prims);
    }
    let triangles = loaded
        .original
        .triangles
        .iter()
        .filter(|t| map[t[0] as usize] != u32::MAX)
        .map(|t| t.map(|v| map[v as usize]))
        .collect();
    FaceMesh {
        mesh: Mesh {
            positions,
            triangles,
        },
        names: face
            .iter()
            .map(|&i| loaded.instances[i].describe(&loaded.document.root))
            .collect(),
        ranges,
    }
}

/// The node the mouth's joints hang under: the one named `wanted` (an error when there is
/// none), else a joint named like a head (`head`, then any name containing `head`, shortest
/// first) among the face's skins' joints, then among all skins' joints; none when the file
/// has no such joint and the face had no skin.
pub fn parent_bone(
    loaded: &LoadedMesh,
    face: &[usize],
    wanted: Option<&str>,
) -> Result<Option<usize>, String> {
    let root = &loaded.document.root;
    let name = |n: usize| root.nodes[n].name.clone().unwrap_or_default();
    if let Some(wanted) = wanted {
        return root
            .nodes
            .iter()
            .position(|n| n.name.as_deref() == Some(wanted))
            .map(Some)
            .ok_or_else(|| {
                let joints: Vec<String> = root
                    .skins
                    .iter()
                    .flat_map(|s| s.joints.iter().map(|j| j.value()))
                    .take(20)
                    .map(|j| shown(&name(j)))
                    .collect();
                format!(
                    "--parent-bone {}: no node of that name (joints: {})",
                    shown(wanted),
                    if joints.is_empty() {
                        "none, the file has no skin".to_owned()
                    } else {
                        joints.join(", ")
                    }
                )
            });
    }
    let face_skins: Vec<usize> = face
        .iter()
        .filter_map(|&i| loaded.instances[i].skin)
        .collect();
    let head_in = |skins: &mut dyn Iterator<Item = usize>| -> Option<usize> {
        let joints: Vec<usize> = skins
            .flat_map(|s| root.skins[s].joints.iter().map(|j| j.value()))
            .filter(|&j| j < root.nodes.len())
            .collect();
        joints
            .iter()
            .copied()
            .find(|&j| name(j).eq_ignore_ascii_case("head"))
            .or_else(|| {
                joints
                    .iter()
                    .copied()
                    .filter(|&j| name(j).to_ascii_lowercase().contains("head"))
                    .min_by_key(|&j| (name(j).len(), j))
            })
    };
    if let Some(h) = head_in(&mut face_skins.iter().copied()) {
        return Ok(Some(h));
    }
    if !face_skins.is_empty() {
        return Err(format!(
            "the face has a skin, but none of its joints is named like `head`: name the joint \
             the mouth should hang under with --parent-bone (joints: {})",
            root.skins[face_skins[0]]
                .joints
                .iter()
                .take(20)
                .map(|j| shown(&name(j.value())))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    Ok(head_in(&mut (0..root.skins.len())))
}

/// The character's rig with its points moved to the file's nodes named like them (`P1` …,
/// empties a rigger placed on the mesh), when the file has all of them: the mouth frame from
/// the corners (the first point and the point halfway round, as the character file has them)
/// and the character's up, the rest in that frame. None when the file lacks one of them.
pub fn rig_from_nodes(
    loaded: &LoadedMesh,
    rig: &MouthRig,
    model_up: crate::ModelUp,
) -> Result<Option<MouthRig>, String> {
    use nalgebra::{Unit, Vector3};
    let root = &loaded.document.root;
    let mut at = Vec::new();
    for p in rig.points() {
        let Some(node) = root
            .nodes
            .iter()
            .position(|n| n.name.as_deref() == Some(&p.name))
        else {
            return Ok(None);
        };
        let w = loaded.document.worlds[node];
        at.push(Vector3::new(w[(0, 3)], w[(1, 3)], w[(2, 3)]));
    }
    // file frame → model frame
    let to_file = crate::file_placement(rig, model_up) * rig.placement().inverse();
    let model: Vec<Vector3<f64>> = at
        .iter()
        .map(|p| to_file.inverse_transform_point(&Point3::from(*p)).coords)
        .collect();
    let (left, right) = (model[0], model[model.len() / 2]);
    let x = left - right;
    if x.norm().is_nan() || x.norm() <= 0.0 {
        return Err(format!(
            "nodes {} and {} (the mouth's corners) are at the same place",
            rig.points()[0].name,
            rig.points()[model.len() / 2].name
        ));
    }
    let x = Unit::new_normalize(x);
    let up = rig.placement().rotation * Vector3::y();
    let y = up - x.into_inner() * x.dot(&up);
    if y.norm().is_nan() || y.norm() <= 1e-6 {
        return Err("the mouth's corners lie along the character's up axis".into());
    }
    let y = y.normalize();
    let z = x.cross(&y);
    let origin = 0.5 * (left + right);
    let placement =
        MouthRig::placement_from_axes(origin.into(), x.into_inner().into(), y.into(), z.into())
            .map_err(|e| e.to_string())?;
    let points = rig
        .points()
        .iter()
        .zip(&model)
        .map(|(p, m)| mouthpiece_export::RigPoint {
            name: p.name.clone(),
            rest: placement
                .inverse_transform_point(&Point3::from(*m))
                .coords
                .into(),
        })
        .collect();
    let mut new = MouthRig::new(rig.character().map(str::to_owned), points, placement)
        .map_err(|e| e.to_string())?;
    if let Some(units) = rig.metres_per_unit() {
        new = new.with_metres_per_unit(units).map_err(|e| e.to_string())?;
    }
    if let Some(head) = rig.head() {
        new = new.with_head(*head).map_err(|e| e.to_string())?;
    }
    if let Some(pivot) = rig.jaw_pivot() {
        let model = rig.placement() * Point3::from(pivot);
        new = new
            .with_jaw_pivot(model.coords.into())
            .map_err(|e| e.to_string())?;
    }
    Ok(Some(new))
}
