//! Reading a glTF's skins, treating the file as hostile as [`crate::gltf_read`] does: joint
//! counts capped, joints checked against the nodes, accessors checked before reading.

use gltf_json as json;
use json::validation::Checked::Valid;
use nalgebra::Matrix4;

use crate::gltf_read::{read_accessor, Use};

/// Most joints a skin may have (what `JOINTS_0` can index with 16 bits, less room for the
/// mouth's joints; a character's whole skeleton is a few hundred).
pub const MAX_SKIN_JOINTS: usize = 4096;

/// A skin's bind (mesh coordinates → the file's frame at rest): its first joint's world
/// transform times that joint's inverse bind matrix (identity when it has none).
pub(crate) fn skin_bind(
    root: &json::Root,
    buffers: &[Vec<u8>],
    skin: usize,
    worlds: &[Matrix4<f64>],
) -> Result<Matrix4<f64>, String> {
    let s = root.skins.get(skin).ok_or("does not exist")?;
    if s.joints.is_empty() {
        return Err("has no joints".into());
    }
    if s.joints.len() > MAX_SKIN_JOINTS {
        return Err(format!(
            "has {} joints, more than the {MAX_SKIN_JOINTS} a skin may have",
            s.joints.len()
        ));
    }
    for (k, j) in s.joints.iter().enumerate() {
        if j.value() >= worlds.len() {
            return Err(format!(
                "joint {k} is node {}, but there are {} nodes",
                j.value(),
                worlds.len()
            ));
        }
    }
    let first = s.joints[0].value();
    let ibm = match s.inverse_bind_matrices {
        Some(a) => {
            let m = inverse_bind_matrices(root, buffers, a.value(), s.joints.len())?;
            m[0]
        }
        None => Matrix4::identity(),
    };
    Ok(worlds[first] * ibm)
}

/// A skin's inverse bind matrices (at least `joints` of them).
pub fn inverse_bind_matrices(
    root: &json::Root,
    buffers: &[Vec<u8>],
    accessor: usize,
    joints: usize,
) -> Result<Vec<Matrix4<f64>>, String> {
    let values = read_accessor(root, buffers, accessor, Use::Matrices, MAX_SKIN_JOINTS)
        .map_err(|e| format!("inverseBindMatrices accessor {accessor}: {e}"))?;
    if values.len() / 16 < joints {
        return Err(format!(
            "inverseBindMatrices accessor {accessor} has {} matrices for {joints} joints",
            values.len() / 16
        ));
    }
    Ok(values
        .chunks_exact(16)
        .map(Matrix4::from_column_slice)
        .collect())
}

/// A primitive's `JOINTS_n`/`WEIGHTS_n` pairs as (joint, weight) lists, one per vertex;
/// `count` vertices are expected.
pub fn read_skin_weights(
    root: &json::Root,
    buffers: &[Vec<u8>],
    primitive: &json::mesh::Primitive,
    count: usize,
) -> Result<Vec<Vec<(u16, f64)>>, String> {
    let mut rows = vec![Vec::new(); count];
    for set in 0..8u32 {
        let (Some(j), Some(w)) = (
            primitive
                .attributes
                .get(&Valid(json::mesh::Semantic::Joints(set))),
            primitive
                .attributes
                .get(&Valid(json::mesh::Semantic::Weights(set))),
        ) else {
            break;
        };
        let joints = read_accessor(root, buffers, j.value(), Use::Joints, count)
            .map_err(|e| format!("JOINTS_{set} accessor {}: {e}", j.value()))?;
        let weights = read_accessor(root, buffers, w.value(), Use::Weights, count)
            .map_err(|e| format!("WEIGHTS_{set} accessor {}: {e}", w.value()))?;
        if joints.len() != 4 * count || weights.len() != 4 * count {
            return Err(format!(
                "JOINTS_{set}/WEIGHTS_{set} do not have one element per vertex ({count})"
            ));
        }
        for v in 0..count {
            for k in 0..4 {
                let w = weights[4 * v + k];
                if w > 0.0 {
                    rows[v].push((joints[4 * v + k] as u16, w));
                }
            }
        }
    }
    Ok(rows)
}
