//! Reading the avatar of `export --onto` as hostile input: the JSON is kept as a
//! [`serde_json::Value`] (written back unchanged but for what is appended), and every part
//! the animation relies on is checked first: buffers exist and are as long as they say
//! (`data:` URIs, the GLB's binary chunk, or files inside the avatar's folder, which are
//! measured, never read), buffer views and accessors lie inside them, meshes' morph targets
//! agree across primitives, nodes name meshes that exist, images stay inside the folder.

use std::path::{Path, PathBuf};

use serde_json::Value;

use crate::asset::{self, shown};
use crate::onto_rig::parse_glb;

/// Largest avatar file read, and largest total of the buffers it names.
pub const MAX_AVATAR_BYTES: u64 = 256 * 1024 * 1024;

/// Most morph targets one mesh may have (a face rig has tens to a few hundred): each is a
/// weight per frame in the appended animation, so a mesh of hundreds of thousands would make
/// an animation of gigabytes from a take of seconds.
pub const MAX_MORPH_TARGETS: usize = 4096;

/// One mesh's morph targets as the avatar names them.
#[derive(Clone, Debug)]
pub struct AvatarMesh {
    /// `mesh 3 (`Face`)`, for messages.
    pub label: String,
    /// Target names from `extras.targetNames` (empty when the mesh gives none).
    pub target_names: Vec<String>,
    /// How many morph targets each primitive has.
    pub targets: usize,
    /// `mesh.weights` (0 for every target when absent).
    pub default_weights: Vec<f32>,
    /// The nodes that show this mesh: (index, name for messages).
    pub nodes: Vec<(usize, String)>,
}

/// A glTF/GLB avatar, read and checked.
#[derive(Clone, Debug)]
pub struct Avatar {
    pub path: PathBuf,
    /// The file was GLB (else `.gltf` JSON).
    pub glb: bool,
    /// The whole JSON document.
    pub doc: Value,
    /// The GLB's binary chunk (`None` for `.gltf`, or a GLB without one).
    pub bin: Option<Vec<u8>>,
    pub meshes: Vec<AvatarMesh>,
    /// Some buffer or image is a file named by a relative URI (not `data:`, not the GLB chunk).
    pub external_files: bool,
}

impl Avatar {
    /// Reads `path` (at most [`MAX_AVATAR_BYTES`]); errors name the file and the element.
    pub fn read(path: &Path) -> Result<Self, crate::ExportError> {
        let bytes = asset::read_bounded(path, MAX_AVATAR_BYTES).map_err(|cause| {
            if cause.kind() == std::io::ErrorKind::InvalidData {
                super::avatar_error(path, format!("the file is {cause}"))
            } else {
                crate::ExportError::AvatarRead {
                    path: path.to_path_buf(),
                    cause,
                }
            }
        })?;
        Self::from_bytes(&bytes, path).map_err(|problem| super::avatar_error(path, problem))
    }

    /// [`Avatar::read`] on the file's bytes; `path` is where relative URIs are resolved.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, String> {
        let glb = bytes.starts_with(b"glTF");
        let (json_bytes, bin) = if glb {
            let chunks = parse_glb(bytes)?;
            let bin = (!chunks.bin.is_empty()).then_some(chunks.bin);
            (chunks.json, bin)
        } else {
            (bytes.to_vec(), None)
        };
        let doc: Value = serde_json::from_slice(&json_bytes).map_err(|e| {
            let what = if glb {
                "GLB JSON chunk"
            } else {
                "not glTF JSON"
            };
            format!("{what}: {e}")
        })?;
        if !doc.is_object() {
            return Err("the glTF JSON is not an object".into());
        }
        match doc.pointer("/asset/version").and_then(Value::as_str) {
            Some(v) if v.starts_with("2.") => {}
            Some(v) => return Err(format!("asset.version is `{}`, not glTF 2.x", shown(v))),
            None => return Err("asset.version is missing: not a glTF 2.0 document".into()),
        }
        // The arrays the animation is appended to must be arrays (or absent).
        for key in ["accessors", "bufferViews", "buffers", "animations"] {
            array(&doc, key)?;
        }
        let folder = crate::output::parent_dir(path);
        let mut external_files = false;
        let buffer_lengths = check_buffers(&doc, bin.as_deref(), folder, &mut external_files)?;
        let view_lengths = check_views(&doc, &buffer_lengths)?;
        let accessors = check_accessors(&doc, &view_lengths)?;
        for (i, image) in array(&doc, "images")?.iter().enumerate() {
            if let Some(uri) = image.get("uri").and_then(Value::as_str) {
                if !uri.starts_with("data:") {
                    external_files = true;
                    asset::check_inside(folder, uri)
                        .map_err(|why| format!("images[{i}]: URI `{}` {why}", shown(uri)))?;
                }
            }
        }
        let mut meshes = read_meshes(&doc, accessors)?;
        for (n, node) in array(&doc, "nodes")?.iter().enumerate() {
            let Some(mesh) = node.get("mesh") else {
                continue;
            };
            let m = index(mesh, meshes.len()).ok_or_else(|| {
                format!(
                    "nodes[{n}].mesh is {mesh}, the file has {} meshes",
                    meshes.len()
                )
            })?;
            let name = node.get("name").and_then(Value::as_str).map_or_else(
                || format!("node {n}"),
                |s| format!("node {n} (`{}`)", shown(s)),
            );
            meshes[m].nodes.push((n, name));
        }
        Ok(Self {
            path: path.to_path_buf(),
            glb,
            doc,
            bin,
            meshes,
            external_files,
        })
    }
}

/// `doc[key]`: an array, or empty when absent.
pub(crate) fn array<'a>(doc: &'a Value, key: &str) -> Result<&'a [Value], String> {
    match doc.get(key) {
        None => Ok(&[]),
        Some(Value::Array(items)) => Ok(items),
        Some(_) => Err(format!("`{key}` is not an array")),
    }
}

/// A JSON integer in `0..len`.
fn index(v: &Value, len: usize) -> Option<usize> {
    v.as_u64()
        .and_then(|i| usize::try_from(i).ok())
        .filter(|&i| i < len)
}

/// An optional non-negative integer property `key` of `item`.
fn uint(item: &Value, key: &str, at: &str) -> Result<Option<u64>, String> {
    match item.get(key) {
        None => Ok(None),
        Some(v) => v.as_u64().map(Some).ok_or_else(|| {
            format!(
                "{at}.{key} is {}, not a non-negative integer",
                shown(&v.to_string())
            )
        }),
    }
}

/// Each buffer's `byteLength`, checked against the bytes there: the GLB chunk, a `data:`
/// URI, or a file inside `folder` (its size only; it is not read).
fn check_buffers(
    doc: &Value,
    bin: Option<&[u8]>,
    folder: &Path,
    external: &mut bool,
) -> Result<Vec<u64>, String> {
    let mut lengths = Vec::new();
    let mut total = 0u64;
    for (i, buffer) in array(doc, "buffers")?.iter().enumerate() {
        let at = format!("buffers[{i}]");
        let length = uint(buffer, "byteLength", &at)?.ok_or(format!("{at} has no byteLength"))?;
        let have = match buffer.get("uri") {
            None if i == 0 && bin.is_some() => bin.map_or(0, |b| b.len() as u64),
            None => return Err(format!("{at} has no URI and is not a GLB's binary chunk")),
            Some(Value::String(uri)) if uri.starts_with("data:") => {
                let (_, b64) = uri
                    .split_once(";base64,")
                    .ok_or_else(|| format!("{at}: data URI `{}` is not base64", shown(uri)))?;
                use base64::Engine as _;
                base64::engine::general_purpose::STANDARD
                    .decode(b64)
                    .map_err(|e| format!("{at}: data URI: base64: {e}"))?
                    .len() as u64
            }
            Some(Value::String(uri)) => {
                *external = true;
                let file = asset::resolve_inside(folder, uri)
                    .map_err(|why| format!("{at}: URI `{}` {why}; nothing was read", shown(uri)))?;
                std::fs::metadata(&file)
                    .map_err(|e| format!("{at}: {}: {e}", file.display()))?
                    .len()
            }
            Some(other) => {
                return Err(format!(
                    "{at}.uri is {}, not a string",
                    shown(&other.to_string())
                ))
            }
        };
        if have < length {
            return Err(format!(
                "{at} has {have} bytes, its byteLength says {length}"
            ));
        }
        total = total.saturating_add(length);
        if total > MAX_AVATAR_BYTES {
            return Err(format!(
                "{at}: the buffers hold more than {MAX_AVATAR_BYTES} bytes in all"
            ));
        }
        lengths.push(length);
    }
    Ok(lengths)
}

/// Each buffer view's length, after checking that it lies inside its buffer.
fn check_views(doc: &Value, buffers: &[u64]) -> Result<Vec<(u64, Option<u64>)>, String> {
    let mut out = Vec::new();
    for (i, view) in array(doc, "bufferViews")?.iter().enumerate() {
        let at = format!("bufferViews[{i}]");
        let buffer = view
            .get("buffer")
            .and_then(|b| index(b, buffers.len()))
            .ok_or_else(|| format!("{at}.buffer is not one of the {} buffers", buffers.len()))?;
        let offset = uint(view, "byteOffset", &at)?.unwrap_or(0);
        let length = uint(view, "byteLength", &at)?.ok_or(format!("{at} has no byteLength"))?;
        if offset
            .checked_add(length)
            .is_none_or(|end| end > buffers[buffer])
        {
            return Err(format!(
                "{at} (bytes {offset} + {length}) runs past the end of buffer {buffer} ({} bytes)",
                buffers[buffer]
            ));
        }
        let stride = uint(view, "byteStride", &at)?;
        if stride.is_some_and(|s| !(4..=252).contains(&s) || s % 4 != 0) {
            return Err(format!("{at}.byteStride is not a multiple of 4 in 4..252"));
        }
        out.push((length, stride));
    }
    Ok(out)
}

/// Each accessor's `count`, after checking that its elements lie inside its buffer view.
fn check_accessors(doc: &Value, views: &[(u64, Option<u64>)]) -> Result<Vec<u64>, String> {
    let mut out = Vec::new();
    for (i, accessor) in array(doc, "accessors")?.iter().enumerate() {
        let at = format!("accessors[{i}]");
        let component: u64 = match uint(accessor, "componentType", &at)? {
            Some(5120 | 5121) => 1,
            Some(5122 | 5123) => 2,
            Some(5125 | 5126) => 4,
            _ => return Err(format!("{at}.componentType is not a glTF component type")),
        };
        let components: u64 = match accessor.get("type").and_then(Value::as_str) {
            Some("SCALAR") => 1,
            Some("VEC2") => 2,
            Some("VEC3") => 3,
            Some("VEC4" | "MAT2") => 4,
            Some("MAT3") => 9,
            Some("MAT4") => 16,
            _ => return Err(format!("{at}.type is not a glTF accessor type")),
        };
        let count = uint(accessor, "count", &at)?
            .filter(|&c| c >= 1)
            .ok_or(format!("{at}.count is missing or 0"))?;
        let element = component * components;
        if let Some(view) = accessor.get("bufferView") {
            check_span(views, view, accessor, count, element, None, &at)?;
        }
        if let Some(sparse) = accessor.get("sparse") {
            let at = format!("{at}.sparse");
            let n = uint(sparse, "count", &at)?
                .filter(|&n| (1..=count).contains(&n))
                .ok_or(format!(
                    "{at}.count is missing, 0 or more than the accessor's {count}"
                ))?;
            let indices = sparse
                .get("indices")
                .ok_or(format!("{at} has no indices"))?;
            let index_size = match uint(indices, "componentType", &at)? {
                Some(5121) => 1,
                Some(5123) => 2,
                Some(5125) => 4,
                _ => return Err(format!("{at}.indices.componentType is not an index type")),
            };
            let values = sparse.get("values").ok_or(format!("{at} has no values"))?;
            for (part, item, size) in [
                ("indices", indices, index_size),
                ("values", values, element),
            ] {
                let view = item
                    .get("bufferView")
                    .ok_or(format!("{at}.{part} has no bufferView"))?;
                check_span(
                    views,
                    view,
                    item,
                    n,
                    size,
                    Some(size),
                    &format!("{at}.{part}"),
                )?;
            }
        }
        out.push(count);
    }
    Ok(out)
}

/// Checks that `count` elements of `element` bytes (`stride` apart: `fixed`, else the
/// view's `byteStride`, else tightly packed) from `item.byteOffset` lie inside buffer view
/// `view`.
fn check_span(
    views: &[(u64, Option<u64>)],
    view: &Value,
    item: &Value,
    count: u64,
    element: u64,
    fixed: Option<u64>,
    at: &str,
) -> Result<(), String> {
    let v = index(view, views.len()).ok_or_else(|| {
        format!(
            "{at}.bufferView is not one of the {} buffer views",
            views.len()
        )
    })?;
    let (length, stride) = views[v];
    let offset = uint(item, "byteOffset", at)?.unwrap_or(0);
    let end = (count - 1)
        .checked_mul(fixed.or(stride).unwrap_or(element))
        .and_then(|b| b.checked_add(element))
        .and_then(|b| b.checked_add(offset));
    if end.is_none_or(|end| end > length) {
        return Err(format!(
            "{at}: {count} elements of {element} bytes from byte {offset} run past the end of \
             buffer view {v} ({length} bytes)"
        ));
    }
    Ok(())
}

/// The meshes' morph targets: the same number on every primitive, naming accessors that
/// exist, with names and default weights (when given) one per target.
fn read_meshes(doc: &Value, accessors: Vec<u64>) -> Result<Vec<AvatarMesh>, String> {
    let mut out = Vec::new();
    for (m, mesh) in array(doc, "meshes")?.iter().enumerate() {
        let label = match mesh.get("name").and_then(Value::as_str) {
            Some(name) => format!("meshes[{m}] (`{}`)", shown(name)),
            None => format!("meshes[{m}]"),
        };
        let primitives = match mesh.get("primitives") {
            Some(Value::Array(p)) if !p.is_empty() => p,
            _ => return Err(format!("{label} has no primitives")),
        };
        let mut targets = None;
        for (p, primitive) in primitives.iter().enumerate() {
            let list =
                array(primitive, "targets").map_err(|e| format!("{label}.primitives[{p}]: {e}"))?;
            for (k, target) in list.iter().enumerate() {
                let Some(attributes) = target.as_object() else {
                    return Err(format!(
                        "{label}.primitives[{p}].targets[{k}] is not an object"
                    ));
                };
                for (attribute, accessor) in attributes {
                    if index(accessor, accessors.len()).is_none() {
                        return Err(format!(
                            "{label}.primitives[{p}].targets[{k}].{} is not one of the {} accessors",
                            shown(attribute),
                            accessors.len()
                        ));
                    }
                }
            }
            match targets {
                None => targets = Some(list.len()),
                Some(n) if n != list.len() => {
                    return Err(format!(
                        "{label}: primitive {p} has {} morph targets, primitive 0 has {n} (glTF \
                         wants the same number on every primitive)",
                        list.len()
                    ))
                }
                Some(_) => {}
            }
        }
        let targets = targets.unwrap_or(0);
        if targets > MAX_MORPH_TARGETS {
            return Err(format!(
                "{label} has {targets} morph targets, more than the {MAX_MORPH_TARGETS} a mesh \
                 may have for --onto"
            ));
        }
        let target_names = match mesh.pointer("/extras/targetNames") {
            None => Vec::new(),
            Some(Value::Array(names)) => {
                let names: Option<Vec<String>> = names
                    .iter()
                    .map(|n| n.as_str().map(str::to_owned))
                    .collect();
                let names = names
                    .ok_or_else(|| format!("{label}.extras.targetNames holds a non-string"))?;
                if names.len() != targets {
                    return Err(format!(
                        "{label}.extras.targetNames has {} names for {targets} morph targets",
                        names.len()
                    ));
                }
                names
            }
            Some(_) => return Err(format!("{label}.extras.targetNames is not an array")),
        };
        let default_weights = match mesh.get("weights") {
            None => vec![0.0; targets],
            Some(Value::Array(w)) if w.len() == targets => w
                .iter()
                // Checked once converted: 1e308 is finite as a double, +inf as a float.
                .map(|v| v.as_f64().map(|x| x as f32).filter(|x| x.is_finite()))
                .collect::<Option<Vec<f32>>>()
                .ok_or_else(|| {
                    format!(
                        "{label}.weights holds something that is not a finite 32-bit number \
                         (glTF weights are floats, at most about 3.4e38)"
                    )
                })?,
            Some(_) => {
                return Err(format!(
                    "{label}.weights is not an array of {targets} numbers (one per morph target)"
                ))
            }
        };
        out.push(AvatarMesh {
            label,
            target_names,
            targets,
            default_weights,
            nodes: Vec::new(),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// A one-mesh document with a 4-vertex position accessor as its one morph target.
    fn doc() -> Value {
        json!({
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": 48, "uri": format!(
                "data:application/octet-stream;base64,{}", "A".repeat(64))}],
            "bufferViews": [{"buffer": 0, "byteLength": 48}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"}],
            "meshes": [{
                "name": "Face",
                "primitives": [{"attributes": {"POSITION": 0}, "targets": [{"POSITION": 0}]}],
                "extras": {"targetNames": ["jawOpen"]},
                "weights": [0.5]
            }],
            "nodes": [{"mesh": 0, "name": "Face"}]
        })
    }

    fn read(doc: &Value) -> Result<Avatar, String> {
        Avatar::from_bytes(&serde_json::to_vec(doc).unwrap(), Path::new("avatar.gltf"))
    }

    #[test]
    fn a_mesh_with_more_morph_targets_than_the_cap_is_refused_with_its_counts() {
        let mut doc = doc();
        let n = MAX_MORPH_TARGETS + 1;
        doc["meshes"][0]["primitives"][0]["targets"] = json!(vec![json!({"POSITION": 0}); n]);
        doc["meshes"][0]["extras"]["targetNames"] = json!(vec!["t"; n]);
        doc["meshes"][0]["weights"] = json!(vec![0.0; n]);
        let err = read(&doc).map(drop).unwrap_err();
        assert!(
            err.contains(&format!(
                "meshes[0] (`Face`) has {n} morph targets, more than the {MAX_MORPH_TARGETS}"
            )),
            "{err}"
        );
        doc["meshes"][0]["primitives"][0]["targets"] =
            json!(vec![json!({"POSITION": 0}); MAX_MORPH_TARGETS]);
        doc["meshes"][0]["extras"]["targetNames"] = json!(vec!["t"; MAX_MORPH_TARGETS]);
        doc["meshes"][0]["weights"] = json!(vec![0.0; MAX_MORPH_TARGETS]);
        assert_eq!(read(&doc).unwrap().meshes[0].targets, MAX_MORPH_TARGETS);
    }

    #[test]
    fn a_sound_document_reads_with_names_weights_and_nodes() {
        let avatar = read(&doc()).unwrap();
        assert!(!avatar.glb && !avatar.external_files);
        let mesh = &avatar.meshes[0];
        assert_eq!(mesh.label, "meshes[0] (`Face`)");
        assert_eq!(mesh.target_names, ["jawOpen"]);
        assert_eq!(mesh.default_weights, [0.5]);
        assert_eq!(mesh.nodes, [(0, "node 0 (`Face`)".to_owned())]);
    }

    #[test]
    fn each_broken_element_is_named() {
        let cases: [(&str, Value, &str); 10] = [
            (
                "/bufferViews/0/byteOffset",
                json!(4),
                "bufferViews[0] (bytes 4 + 48)",
            ),
            ("/bufferViews/0/buffer", json!(1), "bufferViews[0].buffer"),
            (
                "/accessors/0/byteOffset",
                json!(4),
                "accessors[0]: 4 elements",
            ),
            ("/accessors/0/count", json!(0), "accessors[0].count"),
            (
                "/meshes/0/weights",
                json!([0.5, 1]),
                "meshes[0] (`Face`).weights",
            ),
            (
                "/meshes/0/primitives/0/targets/0/POSITION",
                json!(3),
                "targets[0].POSITION",
            ),
            (
                "/meshes/0/extras/targetNames",
                json!([7]),
                "targetNames holds a non-string",
            ),
            ("/nodes/0/mesh", json!(-1), "nodes[0].mesh"),
            (
                "/buffers/0/byteLength",
                json!(49),
                "buffers[0] has 48 bytes",
            ),
            ("/animations", json!(5), "`animations` is not an array"),
        ];
        for (pointer, value, says) in cases {
            let mut doc = doc();
            let (parent, key) = pointer.rsplit_once('/').unwrap();
            match doc.pointer_mut(parent).unwrap() {
                Value::Object(map) => {
                    map.insert(key.to_owned(), value);
                }
                other => other[key.parse::<usize>().unwrap()] = value,
            }
            let err = read(&doc).unwrap_err();
            assert!(err.contains(says), "{pointer}: {err}");
        }
    }

    /// A default weight that is finite as a double but not as the float glTF stores.
    #[test]
    fn a_weight_that_overflows_a_float_is_refused() {
        for weight in [1e308, -1e39] {
            let mut doc = doc();
            doc["meshes"][0]["weights"] = json!([weight]);
            let err = read(&doc).unwrap_err();
            assert!(
                err.contains("meshes[0] (`Face`).weights") && err.contains("32-bit"),
                "{err}"
            );
        }
        let mut doc = doc();
        doc["meshes"][0]["weights"] = json!([3.0e38]);
        read(&doc).unwrap();
    }

    #[test]
    fn sparse_accessors_are_checked_against_their_views() {
        let mut doc = doc();
        doc["bufferViews"]
            .as_array_mut()
            .unwrap()
            .push(json!({"buffer": 0, "byteLength": 8}));
        doc["accessors"][0]["sparse"] = json!({
            "count": 2,
            "indices": {"bufferView": 1, "componentType": 5121},
            "values": {"bufferView": 0, "byteOffset": 24}
        });
        read(&doc).unwrap();
        doc["accessors"][0]["sparse"]["values"]["byteOffset"] = json!(28);
        let err = read(&doc).unwrap_err();
        assert!(
            err.contains("accessors[0].sparse.values: 2 elements"),
            "{err}"
        );
        doc["accessors"][0]["sparse"]["count"] = json!(5);
        let err = read(&doc).unwrap_err();
        assert!(err.contains("accessors[0].sparse.count"), "{err}");
    }

    #[test]
    fn primitives_must_agree_on_their_targets() {
        let mut doc = doc();
        doc["meshes"][0]["primitives"]
            .as_array_mut()
            .unwrap()
            .push(json!({"attributes": {"POSITION": 0}}));
        let err = read(&doc).unwrap_err();
        assert!(err.contains("primitive 1 has 0 morph targets"), "{err}");
    }
}
