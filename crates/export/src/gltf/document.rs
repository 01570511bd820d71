//! The glTF document of a finished take: nodes, meshes, accessors, the animation's
//! samplers and channels, built from the channels' counts and bounds.

use super::*;

impl GltfWriter {
    /// The glTF JSON, the binary buffer's pieces in order, and the buffer's length.
    pub(super) fn document(
        &self,
        bin_path: &Path,
    ) -> Result<(json::Root, Vec<Piece>, u64), ExportError> {
        let mut root = json::Root {
            asset: json::Asset {
                generator: Some(format!("mouthpiece export {}", env!("CARGO_PKG_VERSION"))),
                ..Default::default()
            },
            ..Default::default()
        };
        let mut pieces = Vec::new();
        let mut offset = 0u64;
        let buffer = json::Index::<json::Buffer>::new(0);
        let mut view = |root: &mut json::Root,
                        pieces: &mut Vec<Piece>,
                        piece: Piece,
                        len: u64,
                        target: Option<json::buffer::Target>| {
            pieces.push(piece);
            let index = root.push(json::buffer::View {
                buffer,
                byte_length: USize64(len),
                byte_offset: Some(USize64(offset)),
                byte_stride: None,
                extensions: None,
                extras: Default::default(),
                name: None,
                target: target.map(Valid),
            });
            offset += len;
            index
        };

        let marker_mesh = if self.options.markers {
            let size = marker_size(self.rig.mouth_width());
            let (positions, indices, bounds) = octahedron(size);
            let pos_len = positions.len() as u64;
            let idx_len = indices.len() as u64;
            let pos_view = view(
                &mut root,
                &mut pieces,
                Piece::Bytes(positions),
                pos_len,
                Some(json::buffer::Target::ArrayBuffer),
            );
            let idx_view = view(
                &mut root,
                &mut pieces,
                Piece::Bytes(indices),
                idx_len,
                Some(json::buffer::Target::ElementArrayBuffer),
            );
            let (min, max) = bounds.json();
            let pos = root.push(accessor(
                pos_view,
                6,
                json::accessor::Type::Vec3,
                json::accessor::ComponentType::F32,
                Some((min, max)),
            ));
            let idx = root.push(accessor(
                idx_view,
                24,
                json::accessor::Type::Scalar,
                json::accessor::ComponentType::U16,
                None,
            ));
            Some(root.push(json::Mesh {
                extensions: None,
                extras: Default::default(),
                name: Some("point marker".into()),
                primitives: vec![json::mesh::Primitive {
                    attributes: [(Valid(json::mesh::Semantic::Positions), pos)].into(),
                    extensions: None,
                    extras: Default::default(),
                    indices: Some(idx),
                    material: None,
                    mode: Valid(json::mesh::Mode::Triangles),
                    targets: None,
                }],
                weights: None,
            }))
        } else {
            None
        };

        let node = |root: &mut json::Root, name: String, rest: &[f64; 3]| {
            root.push(json::Node {
                name: Some(name),
                translation: Some(rest.map(|c| c as f32)),
                mesh: marker_mesh,
                ..Default::default()
            })
        };
        let point_nodes: Vec<json::Index<json::Node>> = self
            .rig
            .points()
            .iter()
            .map(|p| node(&mut root, p.name.clone(), &p.rest))
            .collect();
        let mut mouth_children = point_nodes.clone();
        let mut channel_nodes = point_nodes;
        let mut channel_names = self.rig.names();
        if let Some(rest) = &self.curve_rest {
            let curve_nodes: Vec<_> = rest
                .iter()
                .enumerate()
                .map(|(i, p)| node(&mut root, format!("C{i}"), p))
                .collect();
            mouth_children.push(root.push(json::Node {
                name: Some("curve".into()),
                children: Some(curve_nodes.clone()),
                ..Default::default()
            }));
            channel_names.extend((0..rest.len()).map(|i| format!("C{i}")));
            channel_nodes.extend(curve_nodes);
        }
        let rig_nodes = if self.rig_start.is_some() && self.rig_seen {
            let pivot = jaw_pivot(&self.rig);
            let jaw = root.push(json::Node {
                name: Some("jaw".into()),
                translation: Some(pivot.map(|c| c as f32)),
                mesh: marker_mesh,
                ..Default::default()
            });
            let width = meter_width(self.rig.mouth_width());
            let meter = blendshape_meter(width);
            let indices_len = meter.indices.len() as u64;
            let positions_len = meter.positions.len() as u64;
            let pos_view = view(
                &mut root,
                &mut pieces,
                Piece::Bytes(meter.positions),
                positions_len,
                Some(json::buffer::Target::ArrayBuffer),
            );
            let idx_view = view(
                &mut root,
                &mut pieces,
                Piece::Bytes(meter.indices),
                indices_len,
                Some(json::buffer::Target::ElementArrayBuffer),
            );
            let (min, max) = meter.bounds.json();
            let positions = root.push(accessor(
                pos_view,
                meter.vertices,
                json::accessor::Type::Vec3,
                json::accessor::ComponentType::F32,
                Some((min, max)),
            ));
            let indices = root.push(accessor(
                idx_view,
                indices_len / 2,
                json::accessor::Type::Scalar,
                json::accessor::ComponentType::U16,
                None,
            ));
            let mut targets = Vec::with_capacity(CURVES);
            for (bytes, bounds) in meter.targets {
                let len = bytes.len() as u64;
                let target_view = view(
                    &mut root,
                    &mut pieces,
                    Piece::Bytes(bytes),
                    len,
                    Some(json::buffer::Target::ArrayBuffer),
                );
                targets.push(json::mesh::MorphTarget {
                    positions: Some(root.push(accessor(
                        target_view,
                        meter.vertices,
                        json::accessor::Type::Vec3,
                        json::accessor::ComponentType::F32,
                        Some(bounds.json()),
                    ))),
                    normals: None,
                    tangents: None,
                });
            }
            let names = serde_json::json!({ "targetNames": CURVE_NAMES });
            let mesh = root.push(json::Mesh {
                extensions: None,
                extras: Some(
                    serde_json::value::to_raw_value(&names).map_err(ExportError::Serialize)?,
                ),
                name: Some("blendshapes".into()),
                primitives: vec![json::mesh::Primitive {
                    attributes: [(Valid(json::mesh::Semantic::Positions), positions)].into(),
                    extensions: None,
                    extras: Default::default(),
                    indices: Some(indices),
                    material: None,
                    mode: Valid(json::mesh::Mode::Triangles),
                    targets: Some(targets),
                }],
                weights: Some(vec![0.0; CURVES]),
            });
            let shapes = root.push(json::Node {
                name: Some("blendshapes".into()),
                translation: Some([0.0, (-METER_BELOW * width) as f32, 0.0]),
                mesh: Some(mesh),
                ..Default::default()
            });
            // The lips' rigid motions: nodes at the mouth frame's origin, rotation and
            // translation keys (a point of a lip at rest position p goes to R p + t).
            let lip = |root: &mut json::Root, name: &str| {
                root.push(json::Node {
                    name: Some(name.into()),
                    mesh: marker_mesh,
                    ..Default::default()
                })
            };
            let upper = lip(&mut root, "lip_upper");
            let lower = lip(&mut root, "lip_lower");
            mouth_children.extend([jaw, shapes, upper, lower]);
            Some([jaw, jaw, shapes, upper, upper, lower, lower])
        } else {
            None
        };
        let transform = mouth_transform(&self.rig, self.options.model_up);
        let mouth = root.push(json::Node {
            name: Some("mouth".into()),
            translation: transform.translation,
            rotation: transform.rotation,
            scale: transform.scale,
            children: Some(mouth_children),
            ..Default::default()
        });
        let mut scene_nodes = vec![mouth];
        if let (Some(head), Some(_)) = (self.rig.head(), self.head_start) {
            let offset = |p: &[f64; 3]| {
                let d = [0, 1, 2].map(|k| (p[k] - head.pivot[k]) as f32);
                Some(d)
            };
            let eye = |root: &mut json::Root, name: &str, at: &[f64; 3]| {
                root.push(json::Node {
                    name: Some(name.into()),
                    translation: offset(at),
                    mesh: marker_mesh,
                    ..Default::default()
                })
            };
            let eye_left = eye(&mut root, "eye_L", &head.eye_left);
            let eye_right = eye(&mut root, "eye_R", &head.eye_right);
            let place = head_transform(&self.rig, head, self.options.model_up);
            let head_node = root.push(json::Node {
                name: Some("head".into()),
                translation: place.translation,
                rotation: place.rotation,
                scale: place.scale,
                children: Some(vec![eye_left, eye_right]),
                ..Default::default()
            });
            scene_nodes.push(head_node);
            channel_names.extend(["head", "eye_L", "eye_R"].map(String::from));
            channel_nodes.extend([head_node, eye_left, eye_right]);
        }
        if let Some(nodes) = rig_nodes {
            channel_names.extend(
                [
                    "jaw",
                    "jaw",
                    "blendshapes",
                    "lip_upper",
                    "lip_upper",
                    "lip_lower",
                    "lip_lower",
                ]
                .map(String::from),
            );
            channel_nodes.extend(nodes);
        }
        // The rig's channels come last; without a rig in the take they are left out.
        let written = self
            .channels
            .iter()
            .filter(|c| self.rig_seen || !c.kind.is_rig())
            .count();
        debug_assert_eq!(written, channel_nodes.len());
        let scene = root.push(json::Scene {
            extensions: None,
            extras: Default::default(),
            name: Some(self.rig.character().unwrap_or("take").to_owned()),
            nodes: scene_nodes,
        });
        root.scene = Some(scene);

        let time_accessor = |root: &mut json::Root, view, channel: &Channel| {
            let (min, max) = channel.t_bounds.json();
            root.push(accessor(
                view,
                channel.keys,
                json::accessor::Type::Scalar,
                json::accessor::ComponentType::F32,
                Some((min, max)),
            ))
        };
        let shared_input = if self.shared_times {
            let first = &self.channels[0];
            let v = view(
                &mut root,
                &mut pieces,
                Piece::Times { channel: 0 },
                4 * first.keys,
                None,
            );
            Some(time_accessor(&mut root, v, first))
        } else {
            None
        };
        let mut samplers = Vec::new();
        let mut channels = Vec::new();
        for (i, (channel, node)) in self.channels.iter().zip(&channel_nodes).enumerate() {
            if channel.keys == 0 {
                tracing::warn!(point = %channel_names[i], "point never seen in the take: no animation channel");
                continue;
            }
            let input = match shared_input {
                Some(input) => input,
                None => {
                    let v = view(
                        &mut root,
                        &mut pieces,
                        Piece::Times { channel: i },
                        4 * channel.keys,
                        None,
                    );
                    time_accessor(&mut root, v, channel)
                }
            };
            let v = view(
                &mut root,
                &mut pieces,
                Piece::Values { channel: i },
                4 * channel.width as u64 * channel.keys,
                None,
            );
            let (min, max) = channel.v_bounds.json_first(channel.width.min(4));
            let (kind, path, count) = match channel.kind {
                Kind::Head | Kind::JawRotation | Kind::LipRotation => (
                    json::accessor::Type::Vec4,
                    json::animation::Property::Rotation,
                    channel.keys,
                ),
                Kind::Point | Kind::JawTranslation | Kind::LipTranslation => (
                    json::accessor::Type::Vec3,
                    json::animation::Property::Translation,
                    channel.keys,
                ),
                // One SCALAR per target and key, key by key.
                Kind::Weights => (
                    json::accessor::Type::Scalar,
                    json::animation::Property::MorphTargetWeights,
                    channel.keys * CURVES as u64,
                ),
            };
            let (min, max) = if channel.kind == Kind::Weights {
                channel.v_bounds.json_first(1)
            } else {
                (min, max)
            };
            let output = root.push(accessor(
                v,
                count,
                kind,
                json::accessor::ComponentType::F32,
                Some((min, max)),
            ));
            let sampler = json::Index::new(samplers.len() as u32);
            samplers.push(json::animation::Sampler {
                extensions: None,
                extras: Default::default(),
                input,
                interpolation: Valid(json::animation::Interpolation::Linear),
                output,
            });
            channels.push(json::animation::Channel {
                sampler,
                target: json::animation::Target {
                    extensions: None,
                    extras: Default::default(),
                    node: *node,
                    path: Valid(path),
                },
                extensions: None,
                extras: Default::default(),
            });
        }
        if channels.is_empty() {
            tracing::warn!("no point was ever seen: the glTF has no animation");
        } else {
            root.push(json::Animation {
                extensions: None,
                extras: Default::default(),
                channels,
                name: Some("take".into()),
                samplers,
            });
        }
        let uri = match self.options.layout {
            GltfLayout::Glb => None,
            GltfLayout::SeparateBin => Some(uri_escape(
                &bin_path.file_name().unwrap_or_default().to_string_lossy(),
            )),
            GltfLayout::Embedded => Some(DATA_URI_SENTINEL.to_owned()),
        };
        root.push(json::Buffer {
            byte_length: USize64(offset),
            extensions: None,
            extras: Default::default(),
            name: None,
            uri,
        });
        Ok((root, pieces, offset))
    }
}

/// Where the `jaw` node sits in the mouth frame (character units): the character's own
/// `[rig] jaw_pivot`, else the rig's default hinge pivot (docs/rig.md), `hinge_up` mouth
/// widths above and `hinge_back` behind the mouth centre, with the character's own mouth
/// width (the performer's `[rig]` hinge describes the performer's head, not the character's).
pub(super) fn jaw_pivot(rig: &MouthRig) -> [f64; 3] {
    rig.jaw_hinge()
}

/// How far below the mouth centre the `blendshapes` meter sits, in mouth widths.
pub(super) const METER_BELOW: f64 = 1.5;

/// The mouth width the meter is drawn with (a take without a character file may have one of
/// 0: then 5 cm).
pub(super) fn meter_width(width: f64) -> f64 {
    if width > 0.0 && width.is_finite() {
        width
    } else {
        0.05
    }
}

/// The `blendshapes` mesh: a row of one bar per curve (a tenth of a mouth width apart, a
/// stub at rest), each morph target raising its own bar's top by half a mouth width, so a
/// viewer playing the weights shows a bar chart of the curves.
pub(super) struct Meter {
    vertices: u64,
    positions: Vec<u8>,
    indices: Vec<u8>,
    bounds: Bounds<3>,
    /// One POSITION displacement buffer per curve, with its bounds.
    targets: Vec<(Vec<u8>, Bounds<3>)>,
}

pub(super) fn blendshape_meter(width: f64) -> Meter {
    let w = width as f32;
    let (pitch, bar, stub, rise) = (0.1 * w, 0.08 * w, 0.02 * w, 0.5 * w);
    let mut positions = Vec::with_capacity(CURVES * 4 * 12);
    let mut indices = Vec::with_capacity(CURVES * 6 * 2);
    let mut bounds = Bounds::new();
    for i in 0..CURVES {
        let x0 = (i as f32 - CURVES as f32 / 2.0) * pitch + 0.5 * (pitch - bar);
        let x1 = x0 + bar;
        for v in [
            [x0, 0.0, 0.0],
            [x1, 0.0, 0.0],
            [x1, stub, 0.0],
            [x0, stub, 0.0],
        ] {
            bounds.add(&v);
            for c in v {
                positions.extend_from_slice(&c.to_le_bytes());
            }
        }
        // Counter-clockwise seen from +z (the front).
        let base = (4 * i) as u16;
        for k in [0, 1, 2, 0, 2, 3] {
            indices.extend_from_slice(&(base + k).to_le_bytes());
        }
    }
    let targets = (0..CURVES)
        .map(|i| {
            let mut bytes = Vec::with_capacity(CURVES * 4 * 12);
            let mut b = Bounds::new();
            for v in 0..4 * CURVES {
                // The top two corners of bar i.
                let d = if v / 4 == i && v % 4 >= 2 {
                    [0.0, rise, 0.0]
                } else {
                    [0.0; 3]
                };
                b.add(&d);
                for c in d {
                    bytes.extend_from_slice(&c.to_le_bytes());
                }
            }
            (bytes, b)
        })
        .collect();
    Meter {
        vertices: 4 * CURVES as u64,
        positions,
        indices,
        bounds,
        targets,
    }
}

/// The `mouth` node's TRS, each part left out when it is the identity.
pub(super) struct NodeTransform {
    translation: Option<[f32; 3]>,
    rotation: Option<json::scene::UnitQuaternion>,
    scale: Option<[f32; 3]>,
}

/// C, the rotation from the character's model axes to glTF's.
pub(super) fn model_conversion(model_up: ModelUp) -> nalgebra::UnitQuaternion<f64> {
    use nalgebra::{UnitQuaternion, Vector3};
    match model_up {
        ModelUp::Y => UnitQuaternion::identity(),
        ModelUp::Z => {
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), -std::f64::consts::FRAC_PI_2)
        }
    }
}

/// The `head` node's rest TRS: translation s·C·pivot, rotation C (its keys are C·R_head),
/// scale s; its children (the eyes) are then in the model's axes and units, relative to the
/// pivot.
pub(super) fn head_transform(
    rig: &MouthRig,
    head: &crate::RigHead,
    model_up: ModelUp,
) -> NodeTransform {
    let conversion = model_conversion(model_up);
    let s = rig.metres_per_unit().unwrap_or(1.0);
    let translation = (conversion * nalgebra::Vector3::from(head.pivot) * s).map(|c| c as f32);
    let q = conversion.coords.map(|c| c as f32).normalize();
    NodeTransform {
        translation: (translation.norm() > 0.0).then(|| translation.into()),
        rotation: (q.w.abs() < 1.0).then(|| json::scene::UnitQuaternion([q.x, q.y, q.z, q.w])),
        scale: (s != 1.0).then_some([s as f32; 3]),
    }
}

/// glTF world = C · s · placement · mouth, with C the model-axes conversion and s the units'
/// metres: translation s·C·o, rotation C·R, scale s.
pub(super) fn mouth_transform(rig: &MouthRig, model_up: ModelUp) -> NodeTransform {
    let conversion = model_conversion(model_up);
    let s = rig.metres_per_unit().unwrap_or(1.0);
    let placement = rig.placement();
    let translation = (conversion * placement.translation.vector * s).map(|c| c as f32);
    let q = (conversion * placement.rotation)
        .coords
        .map(|c| c as f32)
        .normalize();
    NodeTransform {
        translation: (translation.norm() > 0.0).then(|| translation.into()),
        rotation: (q.w.abs() < 1.0).then(|| json::scene::UnitQuaternion([q.x, q.y, q.z, q.w])),
        scale: (s != 1.0).then_some([s as f32; 3]),
    }
}
