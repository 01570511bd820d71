//! Foxglove channels that Foxglove Studio's built-in panels show without plugins, using its
//! well-known schema names with JSON encoding:
//!
//! | id | topic | schema | from |
//! |---|---|---|---|
//! | 3 | `/camera/image` | `foxglove.CompressedImage` | the preview's JPEG (same rate limits) |
//! | 4 | `/camera/annotations` | `foxglove.ImageAnnotations` | the preview's dots, in the JPEG's pixels |
//! | 5 | `/scene` | `foxglove.SceneUpdate` | the performer's lips and each character's mouth, spheres and lines |
//! | 6 | `/tf` | `foxglove.FrameTransforms` | `camera` → `head` → `mouth` → `character_<name>` |
//!
//! Frames: `camera` is the depth camera (x right, y down, z forward, metres); `head` moves
//! with the performer's head (the head pose: neutral head onto the current one); `mouth` is
//! the performer's neutral mouth frame on the head (x towards the performer's left, y up,
//! z out of the mouth); `character_<name>` sits beside the mouth, 12 cm apart per
//! character, each character's points scaled from its own units to metres.

use base64::Engine as _;
use serde_json::{json, Value};

use crate::hub::{PublishedFrame, StreamInfo};
use crate::preview::{DotState, EncodedPreview};
use mouthpiece_output::RigidPose;

/// Channel id of `/camera/image`.
pub const IMAGE_CHANNEL: u32 = 3;
/// Channel id of `/camera/annotations`.
pub const ANNOTATIONS_CHANNEL: u32 = 4;
/// Channel id of `/scene`.
pub const SCENE_CHANNEL: u32 = 5;
/// Channel id of `/tf`.
pub const TRANSFORMS_CHANNEL: u32 = 6;

/// Distance between the performer's mouth and each character in the 3D scene, metres.
const CHARACTER_SPACING_M: f64 = 0.12;

fn time(ns: u64) -> Value {
    json!({"sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000})
}

fn colour(r: f64, g: f64, b: f64, a: f64) -> Value {
    json!({"r": r, "g": g, "b": b, "a": a})
}

fn state_colour(state: DotState) -> Value {
    match state {
        DotState::Tracked => colour(0.24, 0.86, 0.52, 1.0),
        DotState::Predicted => colour(1.0, 0.82, 0.25, 1.0),
        DotState::Lost => colour(1.0, 0.3, 0.3, 1.0),
    }
}

const IDENTITY_QUATERNION: [f64; 4] = [1.0, 0.0, 0.0, 0.0];

fn pose(position: [f64; 3], rotation_wxyz: [f64; 4]) -> Value {
    let [w, x, y, z] = rotation_wxyz;
    json!({
        "position": {"x": position[0], "y": position[1], "z": position[2]},
        "orientation": {"x": x, "y": y, "z": z, "w": w},
    })
}

/// Frame id of a character's frame.
pub fn character_frame(name: &str) -> String {
    format!("character_{name}")
}

/// Metres per unit of a character's points (`units` of `hello`).
fn metres_per_unit(units: &str) -> f64 {
    match units {
        "mm" => 0.001,
        "cm" => 0.01,
        _ => 1.0,
    }
}

/// `foxglove.CompressedImage` of a preview image.
pub fn compressed_image(p: &EncodedPreview, timestamp_ns: u64) -> Value {
    json!({
        "timestamp": time(timestamp_ns),
        "frame_id": "camera",
        "data": base64::engine::general_purpose::STANDARD.encode(&p.jpeg),
        "format": "jpeg",
    })
}

/// `foxglove.ImageAnnotations` of a preview image: a filled circle and a label per dot,
/// coloured by state, and each search region as a closed outline, in the JPEG's pixels.
pub fn image_annotations(p: &EncodedPreview, timestamp_ns: u64) -> Value {
    let sx = f64::from(p.width) / f64::from(p.source_width.max(1));
    let sy = f64::from(p.height) / f64::from(p.source_height.max(1));
    let at = |x: f32, y: f32| json!({"x": f64::from(x) * sx, "y": f64::from(y) * sy});
    let ts = time(timestamp_ns);
    let circles: Vec<Value> = p
        .overlay
        .dots
        .iter()
        .map(|d| {
            json!({
                "timestamp": ts,
                "position": at(d.x, d.y),
                "diameter": 6.0,
                "thickness": 1.0,
                "fill_color": state_colour(d.state),
                "outline_color": colour(0.0, 0.0, 0.0, 1.0),
            })
        })
        .collect();
    let texts: Vec<Value> = p
        .overlay
        .dots
        .iter()
        .map(|d| {
            json!({
                "timestamp": ts,
                "position": at(d.x + 6.0, d.y - 6.0),
                "text": d.name,
                "font_size": 10.0,
                "text_color": state_colour(d.state),
                "background_color": colour(0.0, 0.0, 0.0, 0.5),
            })
        })
        .collect();
    let points: Vec<Value> = p
        .overlay
        .search
        .iter()
        .map(|s| {
            json!({
                "timestamp": ts,
                "type": 2,
                "points": [
                    at(s.x, s.y), at(s.x + s.width, s.y),
                    at(s.x + s.width, s.y + s.height), at(s.x, s.y + s.height),
                ],
                "outline_color": colour(1.0, 0.62, 0.26, 1.0),
                "outline_colors": [],
                "fill_color": colour(0.0, 0.0, 0.0, 0.0),
                "thickness": 1.0,
            })
        })
        .collect();
    json!({"circles": circles, "points": points, "texts": texts})
}

fn spheres_and_loop(
    points: &[[f32; 3]],
    confidence: &[f32],
    outline: Option<&[[f32; 3]]>,
    scale: f64,
    line: Value,
) -> (Vec<Value>, Value) {
    let p3 = |p: &[f32; 3]| json!({"x": f64::from(p[0]) * scale, "y": f64::from(p[1]) * scale, "z": f64::from(p[2]) * scale});
    let spheres = points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let seen = confidence.get(i).copied().unwrap_or(0.0) > 0.5;
            json!({
                "pose": pose(
                    [f64::from(p[0]) * scale, f64::from(p[1]) * scale, f64::from(p[2]) * scale],
                    IDENTITY_QUATERNION,
                ),
                "size": {"x": 0.003, "y": 0.003, "z": 0.003},
                "color": if seen { colour(0.96, 0.97, 0.98, 1.0) } else { colour(1.0, 0.42, 0.42, 1.0) },
            })
        })
        .collect();
    let outline: Vec<Value> = outline.unwrap_or(points).iter().map(p3).collect();
    let lines = json!({
        "type": 1,
        "pose": pose([0.0; 3], IDENTITY_QUATERNION),
        "thickness": 2.0,
        "scale_invariant": true,
        "points": outline,
        "color": line,
        "colors": [],
        "indices": [],
    });
    (spheres, lines)
}

fn entity(ts: &Value, frame_id: &str, id: &str, spheres: Vec<Value>, lines: Value) -> Value {
    json!({
        "timestamp": ts,
        "frame_id": frame_id,
        "id": id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": true,
        "metadata": [],
        "arrows": [],
        "cubes": [],
        "spheres": spheres,
        "cylinders": [],
        "lines": [lines],
        "triangles": [],
        "texts": [],
        "models": [],
    })
}

/// `foxglove.SceneUpdate` of a frame: the performer's stabilised lips in `mouth` and each
/// character's points with its outline (the smoothed curve) in its own frame.
pub fn scene_update(frame: &PublishedFrame, info: &StreamInfo, timestamp_ns: u64) -> Value {
    let ts = time(timestamp_ns);
    let f = &frame.frame;
    let mut entities = Vec::new();
    if let Some(p) = &f.performer {
        let (spheres, lines) = spheres_and_loop(
            &p.points,
            &p.confidence,
            None,
            1.0,
            colour(1.0, 1.0, 1.0, 1.0),
        );
        entities.push(entity(&ts, "mouth", "performer", spheres, lines));
    }
    let palette = [
        colour(1.0, 0.71, 0.33, 1.0),
        colour(0.78, 0.57, 0.92, 1.0),
        colour(0.48, 0.85, 0.56, 1.0),
        colour(0.42, 0.71, 1.0, 1.0),
    ];
    for (i, c) in f.characters.iter().enumerate() {
        let units = info
            .characters
            .iter()
            .find(|k| k.name == c.name)
            .map_or("", |k| k.units.as_str());
        let (spheres, lines) = spheres_and_loop(
            &c.points,
            &c.confidence,
            c.curve.as_deref(),
            metres_per_unit(units),
            palette[i % palette.len()].clone(),
        );
        entities.push(entity(
            &ts,
            &character_frame(&c.name),
            &format!("character/{}", c.name),
            spheres,
            lines,
        ));
    }
    json!({"deletions": [], "entities": entities})
}

fn transform(ts: &Value, parent: &str, child: &str, t: [f64; 3], q_wxyz: [f64; 4]) -> Value {
    let [w, x, y, z] = q_wxyz;
    json!({
        "timestamp": ts,
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": {"x": t[0], "y": t[1], "z": t[2]},
        "rotation": {"x": x, "y": y, "z": z, "w": w},
    })
}

/// `foxglove.FrameTransforms` of a frame: `camera` → `head` (the head pose), `head` →
/// `mouth` (the neutral mouth frame, once calibrated), `mouth` → `character_<name>`.
pub fn frame_transforms(frame: &PublishedFrame, info: &StreamInfo, timestamp_ns: u64) -> Value {
    let ts = time(timestamp_ns);
    let head = &frame.frame.head;
    let mut list = vec![transform(
        &ts,
        "camera",
        "head",
        head.pose.translation,
        head.pose.rotation,
    )];
    let mouth = info.mouth_frame.unwrap_or(RigidPose {
        rotation: IDENTITY_QUATERNION,
        translation: [0.0, 0.0, 0.0],
    });
    list.push(transform(
        &ts,
        "head",
        "mouth",
        mouth.translation,
        mouth.rotation,
    ));
    for (i, c) in info.characters.iter().enumerate() {
        // Beside the performer's mouth, towards the performer's right (-x).
        list.push(transform(
            &ts,
            "mouth",
            &character_frame(&c.name),
            [-CHARACTER_SPACING_M * (i as f64 + 1.0), 0.0, 0.0],
            IDENTITY_QUATERNION,
        ));
    }
    json!({"transforms": list})
}

fn object(title: &str, properties: Value) -> Value {
    json!({"title": title, "type": "object", "properties": properties})
}

fn time_schema() -> Value {
    json!({"type": "object", "title": "time", "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}})
}

fn xyz_schema(title: &str) -> Value {
    object(
        title,
        json!({"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}}),
    )
}

fn quaternion_schema() -> Value {
    object(
        "foxglove.Quaternion",
        json!({"x": {"type": "number"}, "y": {"type": "number"},
               "z": {"type": "number"}, "w": {"type": "number"}}),
    )
}

fn colour_schema() -> Value {
    object(
        "foxglove.Color",
        json!({"r": {"type": "number"}, "g": {"type": "number"},
               "b": {"type": "number"}, "a": {"type": "number"}}),
    )
}

fn point2_schema() -> Value {
    object(
        "foxglove.Point2",
        json!({"x": {"type": "number"}, "y": {"type": "number"}}),
    )
}

fn pose_schema() -> Value {
    object(
        "foxglove.Pose",
        json!({"position": xyz_schema("foxglove.Vector3"), "orientation": quaternion_schema()}),
    )
}

fn array(items: Value) -> Value {
    json!({"type": "array", "items": items})
}

/// The JSON Schema advertised for a channel (the fields of Foxglove's schema of that name
/// that this server sends).
pub fn schema(channel: u32) -> Option<(&'static str, Value)> {
    Some(match channel {
        IMAGE_CHANNEL => (
            "foxglove.CompressedImage",
            object(
                "foxglove.CompressedImage",
                json!({
                    "timestamp": time_schema(),
                    "frame_id": {"type": "string"},
                    "data": {"type": "string", "contentEncoding": "base64"},
                    "format": {"type": "string"},
                }),
            ),
        ),
        ANNOTATIONS_CHANNEL => (
            "foxglove.ImageAnnotations",
            object(
                "foxglove.ImageAnnotations",
                json!({
                    "circles": array(object("foxglove.CircleAnnotation", json!({
                        "timestamp": time_schema(), "position": point2_schema(),
                        "diameter": {"type": "number"}, "thickness": {"type": "number"},
                        "fill_color": colour_schema(), "outline_color": colour_schema(),
                    }))),
                    "points": array(object("foxglove.PointsAnnotation", json!({
                        "timestamp": time_schema(),
                        "type": {"type": "integer", "minimum": 0, "maximum": 4},
                        "points": array(point2_schema()),
                        "outline_color": colour_schema(), "outline_colors": array(colour_schema()),
                        "fill_color": colour_schema(), "thickness": {"type": "number"},
                    }))),
                    "texts": array(object("foxglove.TextAnnotation", json!({
                        "timestamp": time_schema(), "position": point2_schema(),
                        "text": {"type": "string"}, "font_size": {"type": "number"},
                        "text_color": colour_schema(), "background_color": colour_schema(),
                    }))),
                }),
            ),
        ),
        SCENE_CHANNEL => {
            let sphere = object(
                "foxglove.SpherePrimitive",
                json!({"pose": pose_schema(), "size": xyz_schema("foxglove.Vector3"), "color": colour_schema()}),
            );
            let line = object(
                "foxglove.LinePrimitive",
                json!({
                    "type": {"type": "integer", "minimum": 0, "maximum": 2},
                    "pose": pose_schema(), "thickness": {"type": "number"},
                    "scale_invariant": {"type": "boolean"},
                    "points": array(xyz_schema("foxglove.Point3")),
                    "color": colour_schema(), "colors": array(colour_schema()),
                    "indices": array(json!({"type": "integer", "minimum": 0})),
                }),
            );
            let entity = object(
                "foxglove.SceneEntity",
                json!({
                    "timestamp": time_schema(), "frame_id": {"type": "string"},
                    "id": {"type": "string"},
                    "lifetime": {"type": "object", "title": "duration", "properties": {
                        "sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
                    "frame_locked": {"type": "boolean"},
                    "metadata": array(object("foxglove.KeyValuePair",
                        json!({"key": {"type": "string"}, "value": {"type": "string"}}))),
                    "arrows": array(json!({"type": "object"})),
                    "cubes": array(json!({"type": "object"})),
                    "spheres": array(sphere),
                    "cylinders": array(json!({"type": "object"})),
                    "lines": array(line),
                    "triangles": array(json!({"type": "object"})),
                    "texts": array(json!({"type": "object"})),
                    "models": array(json!({"type": "object"})),
                }),
            );
            (
                "foxglove.SceneUpdate",
                object(
                    "foxglove.SceneUpdate",
                    json!({
                        "deletions": array(object("foxglove.SceneEntityDeletion", json!({
                            "timestamp": time_schema(), "type": {"type": "integer"},
                            "id": {"type": "string"}}))),
                        "entities": array(entity),
                    }),
                ),
            )
        }
        TRANSFORMS_CHANNEL => (
            "foxglove.FrameTransforms",
            object(
                "foxglove.FrameTransforms",
                json!({"transforms": array(object("foxglove.FrameTransform", json!({
                    "timestamp": time_schema(),
                    "parent_frame_id": {"type": "string"},
                    "child_frame_id": {"type": "string"},
                    "translation": xyz_schema("foxglove.Vector3"),
                    "rotation": quaternion_schema(),
                })))}),
            ),
        ),
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::preview::{ImageDot, Overlay, PixelBox};

    fn preview() -> EncodedPreview {
        EncodedPreview {
            seq: 7,
            t: 0.5,
            capture_us: 500_000,
            wall_us: Some(1_700_000_000_000_000),
            width: 320,
            height: 240,
            source_width: 640,
            source_height: 480,
            jpeg: vec![0xFF, 0xD8, 0xFF, 0xD9],
            overlay: Overlay {
                dots: vec![ImageDot {
                    name: "D3".into(),
                    x: 100.0,
                    y: 60.0,
                    state: DotState::Predicted,
                }],
                search: vec![PixelBox {
                    x: 80.0,
                    y: 40.0,
                    width: 100.0,
                    height: 50.0,
                }],
            },
            message: Default::default(),
        }
    }

    #[test]
    fn annotations_are_in_the_jpegs_pixels() {
        let a = image_annotations(&preview(), 1_500_000_001);
        assert_eq!(a["circles"][0]["position"], json!({"x": 50.0, "y": 30.0}));
        assert_eq!(a["texts"][0]["text"], "D3");
        assert_eq!(
            a["circles"][0]["timestamp"],
            json!({"sec": 1, "nsec": 500_000_001})
        );
        assert_eq!(a["points"][0]["points"][2], json!({"x": 90.0, "y": 45.0}));
        let image = compressed_image(&preview(), 0);
        assert_eq!(image["data"], "/9j/2Q==");
        assert_eq!(image["format"], "jpeg");
    }

    #[test]
    fn every_channel_has_its_well_known_schema() {
        for (id, name) in [
            (IMAGE_CHANNEL, "foxglove.CompressedImage"),
            (ANNOTATIONS_CHANNEL, "foxglove.ImageAnnotations"),
            (SCENE_CHANNEL, "foxglove.SceneUpdate"),
            (TRANSFORMS_CHANNEL, "foxglove.FrameTransforms"),
        ] {
            let (schema_name, schema) = schema(id).unwrap();
            assert_eq!(schema_name, name);
            assert_eq!(schema["title"], name);
        }
        assert!(schema(1).is_none());
    }
}
