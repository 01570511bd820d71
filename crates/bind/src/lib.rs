//! mouthpiece-bind: a character's mesh bound to its mouth points.
//!
//! One joint per mouth point (`P1` …, at the neutral points) under a `mouth` joint placed at
//! the character's mouth frame, under a `root` joint that holds the rest of the head still.
//! Each vertex gets at most four skin weights summing to 1, from one of three binders:
//!
//! - [`network`]: a graph network trained on procedural heads against reference weights;
//! - [`weights::heat_weights`]: heat diffusion over the surface (Baran & Popović 2007);
//! - [`weights::distance_weights`]: a softmax of the negative distance to each point.
//!
//! # Layout
//! - [`mesh`]: the triangle mesh, its checks, normals, cotangent Laplacian, sparse solver.
//! - [`gltf_io`]: reading glTF/GLB meshes, writing the skinned GLB.
//! - [`procedural`]: the family of procedural heads with their analytic mouth motion.
//! - [`mod@reference`]: reference weights (least squares over the probability simplex).
//! - [`eval`]: KL divergence and skinned-deformation error.
//! - [`training`]: data sets of procedural heads, training and the evaluation table.
//! - [`families`]: meshes the generator did not make, scored against the procedural motion
//!   as a function of position (docs/bind.md, "Meshes from outside the generator").

// Numerical code over vertices × joints: index loops read like the formulas they implement.
#![allow(clippy::needless_range_loop)]

pub mod commands;
mod error;
pub mod eval;
pub mod families;
pub mod gltf_io;
mod gltf_read;
mod gltf_skin;
pub mod jaw;
pub mod mesh;
pub mod network;
pub mod procedural;
pub mod reference;
mod select;
pub mod skin_out;
pub mod training;
pub mod weights;

use std::path::Path;

use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};

pub use mouthpiece_export::ModelUp;
use mouthpiece_export::MouthRig;

pub use error::BindError;
pub use mesh::Mesh;
pub use network::Network;
pub use weights::Weights;

/// A mouth point may lie at most this far (mouth widths) from the mesh's surface.
pub const POINT_DISTANCE_LIMIT: f64 = 0.1;

/// The trained network shipped with mouthpiece (`mouthpiece bind train`, see docs/bind.md).
pub const SHIPPED_NETWORK: &[u8] = include_bytes!("../model/network.bin");

/// Separate parts whose node or mesh name holds one of these (any case) follow the jaw; the
/// others the head.
pub const JAW_PARTS: [&str; 4] = ["tongue", "jaw", "lower", "chin"];

/// How to compute the weights.
#[derive(Clone, Copy, Debug)]
pub enum Method<'a> {
    Network(&'a Network),
    Heat,
    Distance,
}

/// Where the mouth frame sits in the mesh file's coordinates: the character's placement,
/// after the model frame's axes are turned into glTF's when the model is Z-up (as the export
/// does: glTF's (x, y, z) = model's (x, z, −y)).
pub fn file_placement(rig: &MouthRig, model_up: ModelUp) -> Isometry3<f64> {
    let conversion = match model_up {
        ModelUp::Y => UnitQuaternion::identity(),
        ModelUp::Z => {
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), -std::f64::consts::FRAC_PI_2)
        }
    };
    Isometry3::from_parts(Default::default(), conversion) * rig.placement()
}

/// A mesh prepared for binding: in the mouth frame, in mouth widths.
#[derive(Clone, Debug)]
pub struct Prepared {
    pub rig: MouthRig,
    /// The welded mesh in the mouth frame, mouth-width units.
    pub mesh: Mesh,
    /// The mouth points in the same frame and units.
    pub points: [[f64; 3]; procedural::POINTS],
}

/// Takes a mesh in the character's model frame into its mouth frame (mouth-width units),
/// and checks that it can be bound: the rig has the twelve points, the mesh is valid, and
/// every point lies near the surface.
pub fn prepare(rig: &MouthRig, model_up: ModelUp, welded: &Mesh) -> Result<Prepared, BindError> {
    if rig.points().len() != procedural::POINTS {
        return Err(BindError::BadArgument(format!(
            "the character has {} mouth points; binding needs the 12 points P1…P12",
            rig.points().len()
        )));
    }
    welded.validate()?;
    let width = rig.mouth_width();
    if !(width.is_finite() && width > 0.0) {
        return Err(BindError::BadArgument(format!(
            "the character's mouth width is {width}: its corners must lie apart along x"
        )));
    }
    let inverse = file_placement(rig, model_up).inverse();
    let mesh = welded.map_positions(|p| {
        let q = inverse * Point3::from(p);
        [q.x / width, q.y / width, q.z / width]
    });
    let points: [[f64; 3]; procedural::POINTS] =
        std::array::from_fn(|k| rig.points()[k].rest.map(|c| c / width));
    for (k, p) in points.iter().enumerate() {
        let p = Vector3::from(*p);
        // the surface, not only its vertices: a rigger places points between vertices
        let nearest = mesh
            .triangles
            .iter()
            .map(|t| mesh::point_triangle_distance(&p, &t.map(|i| mesh.vertex(i as usize))))
            .fold(f64::INFINITY, f64::min);
        if nearest > POINT_DISTANCE_LIMIT {
            return Err(BindError::PointFarFromMesh {
                mesh: None,
                name: rig.points()[k].name.clone(),
                distance: nearest * width,
                limit: POINT_DISTANCE_LIMIT * width,
                fraction: POINT_DISTANCE_LIMIT,
                extent: welded.extent(),
                width,
            });
        }
    }
    Ok(Prepared {
        rig: rig.clone(),
        mesh,
        points,
    })
}

/// Skin weights of a prepared mesh (one row per welded vertex, at most four influences).
pub fn compute_weights(prepared: &Prepared, method: Method) -> Weights {
    let points = prepared.points.map(Vector3::from);
    let mut weights = match method {
        Method::Distance => {
            weights::distance_weights(&weights::joint_distances(&prepared.mesh, &points), 1.0)
        }
        Method::Heat => weights::heat_weights(
            &prepared.mesh,
            &weights::joint_distances(&prepared.mesh, &points),
            1.0,
        ),
        Method::Network(network) => {
            network.predict(&network::Graph::new(&prepared.mesh, &prepared.points))
        }
    };
    weights.limit_influences();
    weights
}

/// What [`bind`] did.
#[derive(Clone, Debug)]
pub struct BindSummary {
    pub vertices: usize,
    pub welded_vertices: usize,
    pub triangles: usize,
    /// Vertices with a weight of at least 1 % on some mouth point.
    pub moving_vertices: usize,
    /// The face's surface: shells, non-manifold edges, holes.
    pub topology: mesh::Topology,
    /// The meshes bound as the face.
    pub face: Vec<String>,
    /// The other meshes and the joint each follows rigidly (`head`, `jaw`), or `kept` (it
    /// had a skin of its own).
    pub parts: Vec<(String, &'static str)>,
    /// The node the mouth's joints hang under (none: a new `root`).
    pub parent: Option<String>,
    /// The mouth points came from the file's nodes named like them.
    pub points_from_nodes: bool,
}

/// How to bind, besides the character and the files.
#[derive(Clone, Debug)]
pub struct BindOptions<'a> {
    pub model_up: ModelUp,
    pub method: Method<'a>,
    /// Names of the meshes (or of their nodes) that are the face; empty: the meshes nearest
    /// to the mouth points.
    pub face_meshes: Vec<String>,
    /// The node the mouth's joints hang under; none: a joint named like `head` when there is
    /// one, else a new `root` node.
    pub parent_bone: Option<String>,
    /// Add a jaw joint (carrying the chin and the lower lip's joints).
    pub jaw: bool,
    /// The jaw's hinge, model frame; none: the character's (`[rig] jaw_pivot`), else read
    /// from the face ([`jaw::hinge_from_mesh`]), else the rig's default behind and above the
    /// mouth; where a take's jaw turns.
    pub jaw_hinge: Option<[f64; 3]>,
}

impl<'a> BindOptions<'a> {
    pub fn new(model_up: ModelUp, method: Method<'a>) -> Self {
        Self {
            model_up,
            method,
            face_meshes: Vec::new(),
            parent_bone: None,
            jaw: true,
            jaw_hinge: None,
        }
    }
}

/// Binds the mesh file to the character's mouth and writes the input with a skin added.
pub fn bind(
    rig: &MouthRig,
    mesh_path: &Path,
    out: &Path,
    options: &BindOptions,
) -> Result<BindSummary, BindError> {
    let loaded = gltf_io::read_mesh(mesh_path)?;
    let bad = |problem: String| BindError::BadMesh {
        path: mesh_path.to_path_buf(),
        problem,
    };
    let from_nodes = select::rig_from_nodes(&loaded, rig, options.model_up)
        .map_err(|e| bad(format!("the mouth points from the file's nodes: {e}")))?;
    let rig = from_nodes.as_ref().unwrap_or(rig);
    let placement = file_placement(rig, options.model_up);
    let face =
        select::face_instances(&loaded, rig, &placement, &options.face_meshes).map_err(bad)?;
    if face.iter().any(|&i| loaded.instances[i].node.is_none()) {
        return Err(bad(
            "the file has no scene: a skin needs the face's mesh on a node of one".into(),
        ));
    }
    let sub = select::face_mesh(&loaded, &face);
    let (welded, to_welded) = gltf_io::weld(&sub.mesh);
    welded.check().map_err(|(_, problem)| {
        bad(format!(
            "the face ({}) cannot be bound: {problem}",
            sub.names.join(", ")
        ))
    })?;
    let topology = welded.topology();
    let prepared = prepare(rig, options.model_up, &welded).map_err(|mut e| {
        if let BindError::PointFarFromMesh { mesh, .. } = &mut e {
            *mesh = Some(mesh_path.to_path_buf());
        }
        e
    })?;
    let welded_weights = compute_weights(&prepared, options.method);
    // the jaw's hinge in the mouth frame (character units), and each welded vertex's share
    let width = rig.mouth_width();
    let hinge = match options.jaw_hinge {
        Some(model) => {
            if !model.iter().all(|c| c.is_finite()) {
                return Err(BindError::BadArgument(format!(
                    "--jaw-hinge {model:?} is not finite"
                )));
            }
            let p = rig
                .placement()
                .inverse_transform_point(&Point3::from(model));
            if p.coords.norm() > 10.0 * width {
                return Err(BindError::BadArgument(format!(
                    "--jaw-hinge {model:?} is {:.4} from the mouth, more than 10 mouth widths \
                     ({:.4}): is it in the character's model frame and units?",
                    p.coords.norm(),
                    10.0 * width
                )));
            }
            [p.x, p.y, p.z]
        }
        // the character's, else read from the face, else the rig's default
        None => rig.jaw_pivot().unwrap_or_else(|| {
            jaw::hinge_from_mesh(&prepared.mesh)
                .map(|h| [h.x * width, h.y * width, h.z * width])
                .unwrap_or_else(|| rig.jaw_hinge())
        }),
    };
    let jaw_shares: Vec<f64> = if options.jaw {
        let positions: Vec<Vector3<f64>> = (0..prepared.mesh.len())
            .map(|v| prepared.mesh.vertex(v))
            .collect();
        jaw::jaw_shares(
            &positions,
            &welded_weights,
            &Vector3::from(hinge.map(|c| c / width)),
        )
    } else {
        vec![0.0; prepared.mesh.len()]
    };
    let parent =
        select::parent_bone(&loaded, &face, options.parent_bone.as_deref()).map_err(bad)?;
    let mut bindings = vec![skin_out::Binding::Keep; loaded.instances.len()];
    let mut parts = Vec::new();
    for (i, instance) in loaded.instances.iter().enumerate() {
        let root = &loaded.document.root;
        if let Some(at) = face.iter().position(|&f| f == i) {
            let rows = sub.ranges[at]
                .iter()
                .map(|range| {
                    range
                        .clone()
                        .map(|v| {
                            let row = &welded_weights.rows[to_welded[v] as usize];
                            let mut out: Vec<(skin_out::Target, f64)> = (0..procedural::POINTS)
                                .filter(|&j| row[j] > 0.0)
                                .map(|j| (skin_out::Target::Point(j), row[j]))
                                .collect();
                            let jaw = jaw_shares[to_welded[v] as usize];
                            if jaw > 0.0 {
                                out.push((skin_out::Target::Jaw, jaw));
                            }
                            out.push((skin_out::Target::Parent, row[weights::ROOT] - jaw));
                            out
                        })
                        .collect()
                })
                .collect();
            bindings[i] = skin_out::Binding::Face(rows);
        } else if let Some(node) = instance.node {
            // a part with a skin of its own, or under the head in the hierarchy, already
            // follows the head
            let under_parent = parent.is_some_and(|p| {
                // bounded: a hostile file's hierarchy may loop outside the scene
                std::iter::successors(Some(node), |&n| loaded.document.parents[n])
                    .take(root.nodes.len())
                    .any(|n| n == p)
            });
            let kept = instance.skin.is_some() || under_parent;
            let (node_name, mesh_name) = instance.names(root);
            let on_jaw = options.jaw
                && [node_name, mesh_name].iter().flatten().any(|n| {
                    let n = n.to_ascii_lowercase();
                    JAW_PARTS.iter().any(|part| n.contains(part))
                });
            let joint = match (kept, on_jaw) {
                (_, true) => {
                    bindings[i] = skin_out::Binding::Rigid(skin_out::Target::Jaw);
                    "jaw"
                }
                (true, false) => "kept",
                (false, false) => {
                    bindings[i] = skin_out::Binding::Rigid(skin_out::Target::Parent);
                    "head"
                }
            };
            parts.push((instance.describe(root), joint));
        }
    }
    let plan = skin_out::RigPlan {
        rig,
        placement,
        parent,
        jaw: options.jaw.then(|| (hinge, jaw::LOWER_LIP.to_vec())),
        generator: format!("mouthpiece bind {}", env!("CARGO_PKG_VERSION")),
    };
    skin_out::write_bound(out, &loaded, &plan, &bindings)?;
    Ok(BindSummary {
        vertices: loaded.original.len(),
        welded_vertices: welded.len(),
        triangles: welded.triangles.len(),
        moving_vertices: welded_weights
            .rows
            .iter()
            .filter(|r| r[..procedural::POINTS].iter().any(|&w| w >= 0.01))
            .count(),
        topology,
        face: sub.names,
        parts,
        points_from_nodes: from_nodes.is_some(),
        parent: parent.map(|p| {
            loaded.document.root.nodes[p]
                .name
                .clone()
                .unwrap_or_else(|| format!("node {p}"))
        }),
    })
}

/// Largest `bind head --resolution`: the largest whose head the binder still accepts
/// ([`mesh::MAX_VERTICES`]).
pub const MAX_HEAD_RESOLUTION: usize = 128;

/// Vertices of [`character_head`] at `resolution`: 12·R around each of 5·R + 2 rings.
pub fn head_vertices(resolution: usize) -> usize {
    12 * resolution * (5 * resolution + 2)
}

/// A procedural head around a character's mouth, in the character's model frame and units
/// (the meshes shipped in `config/characters/`), its axes turned into glTF's for a Z-up
/// model. `snout` 0 is a human face, 1 a long muzzle.
pub fn character_head(
    rig: &MouthRig,
    model_up: ModelUp,
    snout: f64,
    resolution: usize,
) -> Result<Mesh, BindError> {
    if rig.points().len() != procedural::POINTS {
        return Err(BindError::BadArgument(format!(
            "the character has {} mouth points; a head needs the 12 points P1…P12",
            rig.points().len()
        )));
    }
    if !(0.0..=1.0).contains(&snout) {
        return Err(BindError::BadArgument(format!(
            "--snout must be in 0…1 (got {snout})"
        )));
    }
    if !(1..=MAX_HEAD_RESOLUTION).contains(&resolution) {
        return Err(BindError::BadArgument(format!(
            "--resolution must be 1…{MAX_HEAD_RESOLUTION} (got {resolution}; {MAX_HEAD_RESOLUTION} \
             makes a head of {} vertices, the binder takes at most {})",
            head_vertices(MAX_HEAD_RESOLUTION),
            mesh::MAX_VERTICES
        )));
    }
    let width = rig.mouth_width();
    if !(width.is_finite() && width > 0.0) {
        return Err(BindError::BadArgument(format!(
            "the character's mouth width is {width}: its corners must lie apart along x"
        )));
    }
    let points = std::array::from_fn(|k| rig.points()[k].rest.map(|c| c / width));
    let head = procedural::HeadParams::around_points(points, snout, resolution).build();
    let placement = file_placement(rig, model_up);
    Ok(head.mesh.map_positions(|p| {
        let q = placement * Point3::new(p[0] * width, p[1] * width, p[2] * width);
        [q.x, q.y, q.z]
    }))
}

/// The shipped network.
pub fn shipped_network() -> Result<Network, BindError> {
    Network::from_bytes(SHIPPED_NETWORK, Path::new("<shipped network>"))
}
